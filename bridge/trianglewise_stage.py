# SPDX-License-Identifier: GPL-3.0-or-later
"""The pipeline's triangle-wise stage, and the results of earlier runs that a rerun takes instead of optimizing again.

The stage is :func:`core.trianglewise.iter_optimize_triangles` on the arrays the pipeline read. Its results are kept
by their key (:func:`core.result_cache.result_key`: the mesh, the UV map, the loss's planes, the faces, the
settings that change them and the code) in :func:`triangle_results`, in memory and in a folder the user can clear:
a rerun that changes only the cost, margin or names (the redo panel, a second CLI run) skips the stage, and a run
that was stopped before its end continues from the faces it had done (kept about every half minute).

No bpy here: the stage runs on the arrays the pipeline read.
"""
from ..core.progress import relay_stage

__all__ = ["triangle_results", "iter_trianglewise_stage"]

_TRIANGLE_RESULTS = []


def triangle_results():
    """Triangle-wise results of recent runs, keyed by the stage's inputs, settings and code (in memory and in
    ``core.result_cache.default_cache_folder()``): a rerun that changes only the cost, margin or names (the redo
    panel, a second CLI run) skips the stage. Made on first use, so importing this module stays light."""
    from ..core.result_cache import stage_results
    from ..core.trianglewise_result import TrianglewiseResult

    return stage_results(_TRIANGLE_RESULTS, TrianglewiseResult)


def iter_trianglewise_stage(V, F, uv_in, planes, faces, key, settings, run, step, clock):
    """Generator: the triangle-wise results for ``key``, from :func:`triangle_results` or optimized, yielding
    ``step``'s "triangle" steps; returns ``(triangles, notes)``, the notes for the report on what was reused.

    Parameters
    ----------
    V, F, uv_in, planes, faces
        The mesh, its UVs per face corner, the loss's planes and the faces to optimize, as
        :func:`core.trianglewise.iter_optimize_triangles` takes them.
    key : str
        The stage's result key (:func:`core.result_cache.result_key`).
    settings : core.settings.OptimizeSettings
    run : core.progress.RunProgress
        Told which part of the stage an earlier run did, so that the run's ETA leaves it out.
    step : callable
        ``step(stage, done, total, message)`` makes the pipeline's ``Progress``.
    clock : float
        ``time.perf_counter()`` when the stage started.

    Returns
    -------
    triangles : core.trianglewise_result.TrianglewiseResult
    notes : list of str
    """
    from ..core.trianglewise import iter_optimize_triangles

    notes = []
    triangles = triangle_results().get(key) if settings.reuse_triangle_results else None
    if triangles is None:
        # The faces done by a run of the same key that was cancelled or killed (kept about every half minute).
        partial_key = f"{key}-partial"
        known = triangle_results().get(partial_key) if settings.reuse_triangle_results else None
        if known is not None:
            run.skip("triangle", len(known.faces), len(faces))
        stage = iter_optimize_triangles(V, F, uv_in, planes, epsilon=settings.epsilon,
                                        evaluations=settings.iterations, screen_pixels=settings.screen_pixels,
                                        max_screen_pixels=settings.max_screen_pixels,
                                        workers=settings.workers, seed=settings.seed, faces=faces,
                                        scheduler=settings.scheduler, known=known,
                                        checkpoint=lambda partial: triangle_results().put(partial_key, partial))
        triangles = yield from relay_stage(stage, "triangle", "Triangle-wise optimization", clock, step)
        triangle_results().put(key, triangles)
        triangle_results().discard(partial_key)
        if known is not None:
            notes.append(f"the triangle-wise results of {len(known.faces)} of {len(faces)} triangles were taken "
                         "from an earlier run on the same input that was stopped before its end")
    else:
        notes.append("the triangle-wise results of an earlier run on the same mesh, UV map, texture and settings "
                     "were reused (Clear Cached Results in the sidebar, or --fresh on the command line, "
                     "computes them again)")
        run.skip("triangle", 1, 1)
        yield step("triangle", 1, 1, "Triangle-wise optimization: reused from an earlier run")
    return triangles, notes
