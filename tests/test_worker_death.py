"""A worker process that dies ends the triangle-wise stage with a clear error instead of a hang."""
import multiprocessing
import os
import signal

import numpy as np
import pytest

from perceptual_uv.core.trianglewise import WorkerDiedError, iter_optimize_triangles


@pytest.mark.slow
def test_killed_worker_gives_a_clear_error():
    n = 12
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    F = np.array([[a, a + 1, a + n + 1] for i in range(n - 1) for a in range(i * n, i * n + n - 1)]
                 + [[a, a + n + 1, a + n] for i in range(n - 1) for a in range(i * n, i * n + n - 1)])
    luma = np.random.default_rng(0).random((64, 64))
    stage = iter_optimize_triangles(V, F, V[F][:, :, :2], luma, evaluations=20, screen_pixels=32, workers=2,
                                    chunk_size=4)
    done = 0
    while done == 0:  # the pool starts in the background: step until a chunk has come back from it
        done, _ = next(stage)
    workers = multiprocessing.active_children()
    assert workers, "the stage should run in worker processes"
    os.kill(workers[0].pid, signal.SIGKILL)
    with pytest.raises(WorkerDiedError, match="worker process"):
        for _ in stage:
            pass
