"""Tasks run in this process get the workers' one BLAS thread, and only while they run."""
import numpy as np
import pytest

from perceptual_uv.core import worker_pool

threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads():
    return [pool["num_threads"] for pool in threadpoolctl.threadpool_info() if pool["user_api"] == "blas"]


def _blas_threads_task(state, chunk):
    np.dot(np.ones(4), np.ones(4))  # BLAS loaded and called, as the optimizer's tasks do
    return _blas_threads()


def test_tasks_in_this_process_run_with_one_blas_thread_and_the_caller_keeps_its_own():
    np.dot(np.ones(4), np.ones(4))
    before = _blas_threads()
    assert before, "numpy's BLAS is not visible to threadpoolctl"
    with threadpoolctl.threadpool_limits(2):  # the caller's setting, whatever the machine's default
        caller = _blas_threads()
        seen = []
        for output in worker_pool.run_chunks(_blas_threads_task, {}, np.arange(6), workers=1, chunk_size=2):
            seen.append(output)
            assert _blas_threads() == caller  # between tasks (the caller's turn) its threads are back
    assert len(seen) == 3
    assert all(threads == [1] * len(caller) for threads in seen)
    assert _blas_threads() == before
