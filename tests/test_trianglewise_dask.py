"""The triangle-wise stage's chunks as tasks of a Dask cluster: the same results as a local run."""
import numpy as np
import pytest

from perceptual_uv.core import loss_passes as lp
from perceptual_uv.core import trianglewise as tw
from perceptual_uv.core import worker_pool
from perceptual_uv.core.progress import run_generator

distributed = pytest.importorskip("distributed")

from test_stage_generators import grid_mesh, texture  # noqa: E402  (tests/ is on sys.path under pytest)


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as local:
        yield local.scheduler_address


def test_chunks_on_a_cluster_give_the_local_results(cluster):
    V, F, uv = grid_mesh(cells=3)
    local = tw.optimize_triangles(V, F, uv, texture(), evaluations=10, workers=1, seed=4)
    progress = []
    remote = run_generator(tw.iter_optimize_triangles(V, F, uv, texture(), evaluations=10, seed=4, chunk_size=3,
                                                      scheduler=cluster), lambda *step: progress.append(step))
    for field in ("params", "loss", "w_R", "w_S", "evaluations", "feasible", "is_constant"):
        np.testing.assert_array_equal(getattr(remote, field), getattr(local, field))
    assert progress[0] == (0, 18) and progress[-1] == (18, 18)
    new_uv = 0.5 + 0.7 * (uv - 0.5)
    losses = run_generator(lp.iter_losses_at(V, F, uv, texture(), new_uv, chunk_size=4, scheduler=cluster))
    np.testing.assert_array_equal(losses, lp.losses_at(V, F, uv, texture(), new_uv))


def test_an_unreachable_scheduler_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(worker_pool, "DASK_CONNECT_SECONDS", 1)
    V, F, uv = grid_mesh()
    with pytest.raises(ValueError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        tw.optimize_triangles(V, F, uv, texture(), evaluations=10, scheduler="tcp://127.0.0.1:9")
