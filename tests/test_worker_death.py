"""A worker process that dies ends the triangle-wise stage with a clear error instead of a hang."""
import multiprocessing
import os
import signal
import threading

import numpy as np
import pytest

from perceptual_uv.core import worker_pool
from perceptual_uv.core.trianglewise import WorkerDiedError, iter_optimize_triangles


def _stage_with_a_chunk_done():
    """The triangle-wise stage on a 12 x 12 grid in two workers, stepped until a chunk has come back."""
    n = 12
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    F = np.array([[a, a + 1, a + n + 1] for i in range(n - 1) for a in range(i * n, i * n + n - 1)]
                 + [[a, a + n + 1, a + n] for i in range(n - 1) for a in range(i * n, i * n + n - 1)])
    luma = np.random.default_rng(0).random((64, 64))
    stage = iter_optimize_triangles(V, F, V[F][:, :, :2], luma, evaluations=20, screen_pixels=32, workers=2,
                                    chunk_size=4)
    done = 0
    while done == 0:  # the pool starts in the background
        done, _ = next(stage)
    return stage


@pytest.mark.slow
def test_killed_worker_gives_a_clear_error():
    stage = _stage_with_a_chunk_done()
    workers = multiprocessing.active_children()
    assert workers, "the stage should run in worker processes"
    os.kill(workers[0].pid, signal.SIGKILL)
    with pytest.raises(WorkerDiedError, match="worker process"):
        for _ in stage:
            pass


@pytest.mark.slow
def test_a_worker_that_died_holding_the_task_queue_lock_does_not_hang_the_stage(monkeypatch):
    """A worker waiting for a task holds the task queue's lock; killed then, it leaves the lock taken, and
    ``Pool.terminate`` would wait for it forever. Here the test takes that lock itself (a holder that never
    lets go) before killing a worker: the stage must still end with the error, and every worker with it."""
    pools = []
    make_pool = worker_pool._make_pool
    monkeypatch.setattr(worker_pool, "_make_pool", lambda *args: pools.append(make_pool(*args)) or pools[-1])
    stage = _stage_with_a_chunk_done()
    [pool] = pools
    workers = list(pool._pool)
    assert pool._inqueue._rlock.acquire(timeout=30)  # from now on, as if a dead worker held it
    os.kill(workers[0].pid, signal.SIGKILL)
    raised = []

    def run_to_end():
        try:
            for _ in stage:
                pass
        except WorkerDiedError as error:
            raised.append(str(error))

    runner = threading.Thread(target=run_to_end, daemon=True)
    runner.start()
    runner.join(timeout=30)
    assert not runner.is_alive(), "the stage hung after a worker died"
    assert len(raised) == 1 and "worker process" in raised[0]
    for process in workers[1:] + list(pool._pool):
        process.join(timeout=10)
        assert not process.is_alive()
