# SPDX-License-Identifier: GPL-3.0-or-later
"""The pipeline's mesh-wise stage, and the results of earlier runs that a rerun takes instead of fitting again.

The stage turns the triangle-wise results into the fitted UV map before packing: the texture's signal stretch
(the targets' blend), which triangles show texture in which plane, the fit's targets and weights, the two fits of
:func:`core.chartfit.iter_fit_charts` and the one loss pass that measures the targets and both fits
(:func:`core.loss_passes.iter_fit_losses`). Its result depends on the triangle-wise stage's inputs and settings,
the loss image, whether stacked islands stay stacked, and the code; the cost, margin, names and image sizes change
only the packing and the bake. So the redo panel and a second CLI run with another cost take it from
:func:`meshwise_results` (in memory and in a folder beside the triangle-wise results) and rerun only the packing
and the bake: on tea_set_01 (40,296 faces) the fit and its loss pass are about a minute.

No bpy here: the stage runs on the arrays the pipeline read.
"""
import dataclasses
import hashlib
import pathlib

import numpy as np

from ..core.progress import StageParts

__all__ = ["MeshwiseStageResult", "meshwise_results", "meshwise_key", "iter_meshwise_stage"]

_MESHWISE_RESULTS = []

#: The parts of the stage and their expected shares of its time: the means over the tuning set's spot, tea_set_01 and
#: WaterBottle at the defaults (the loss pass took 0.46-0.81 of the stage, the fits 0.14-0.47). The run's bar moves
#: through the stage by them.
PART_SHARES = {"signal stretch": 0.043, "textured": 0.004, "targets": 0.0002, "fit": 0.36, "loss pass": 0.593}


@dataclasses.dataclass(frozen=True)
class MeshwiseStageResult:
    """What the mesh-wise stage hands to the packing and the report.

    Attributes
    ----------
    uv : (m, 3, 2) float64 ndarray
        The fitted UVs per face corner, before packing (:attr:`core.chartfit.ChartFit.uv`).
    losses : (m,) float64 ndarray
        E of every triangle under the fit its chart kept; 0 for triangles not optimized.
    restored : (r,) int64 ndarray
        Charts laid out as in the input because the fit folded them.
    flipped : int
        Triangles whose orientation differs from the input's.
    target_losses : (k,) float64 ndarray
        E at the fit's targets, per optimized triangle.
    textured : (p, k) bool ndarray
        Which optimized triangles show texture in which plane of the loss.
    """

    uv: np.ndarray
    losses: np.ndarray
    restored: np.ndarray
    flipped: int
    target_losses: np.ndarray
    textured: np.ndarray


def meshwise_results():
    """Mesh-wise results of recent runs by :func:`meshwise_key`, in memory and in the ``meshwise`` folder of
    ``core.result_cache.default_cache_folder()``. Made on first use, so importing this module stays light."""
    from ..core.result_cache import stage_results

    return stage_results(_MESHWISE_RESULTS, MeshwiseStageResult, "meshwise")


def meshwise_key(triangle_key, texture, *, keep_stacks):
    """The key of a mesh-wise result: the triangle-wise stage's key (mesh, UVs, planes, faces, its settings and
    ``core``'s code), the loss image (signal stretch reads its colour), ``keep_stacks`` and this module's code.

    Parameters
    ----------
    triangle_key : str
        :func:`core.result_cache.result_key` of the triangle-wise stage.
    texture : (h, w) or (h, w, c) ndarray
        The loss image as the pipeline read it.
    keep_stacks : bool

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    from ..core.result_cache import result_key

    stage_code = hashlib.sha256(pathlib.Path(__file__).read_bytes()).hexdigest()
    return result_key(texture, triangle_key=triangle_key, keep_stacks=bool(keep_stacks), stage_code=stage_code)


def iter_meshwise_stage(validated, planes, triangles, topology, stacks, key, settings, run, step, started):
    """Generator: the mesh-wise result for ``key``, from :func:`meshwise_results` or fitted, yielding
    ``step("mesh", ...)``; returns ``(meshwise, notes)``, a :class:`MeshwiseStageResult` and the notes for the
    report on what was reused.

    Parameters
    ----------
    validated : core.validate.ValidatedInput
        The mesh, the loss image (signal stretch reads it, :func:`core.ssp.iter_ssp_targets`) and the optimized
        faces; gives every triangle its target and weights (skipped ones the identity and none).
    planes : sequence of ndarray
        The loss's planes (:func:`core.loss_planes.texture_planes`).
    triangles : core.trianglewise_result.TrianglewiseResult
        Of the optimized faces ``validated.faces``.
    topology : core.charts.UVTopology
        The input's charts; ``stacks`` (or None) the stacks among them that stay stacked.
    key : str
        The stage's result key (:func:`meshwise_key`).
    settings : core.settings.OptimizeSettings
        The views (``screen_pixels``, ``max_screen_pixels``), the workers of the loss pass and whether earlier
        results are reused (``reuse_triangle_results``).
    run : core.progress.RunProgress
        Told when an earlier run's result is taken, so that the run's ETA leaves the stage out.
    step : callable
        ``step(stage, done, total, message)`` of the pipeline.
    started : float
        ``time.perf_counter()`` at the stage's start, for the time left in the stage.
    """
    meshwise = meshwise_results().get(key) if settings.reuse_triangle_results else None
    if meshwise is not None:
        run.skip("mesh", 1, 1)
        yield step("mesh", 1, 1, "Mesh-wise fit: reused from an earlier run")
        return meshwise, ["the mesh-wise fit of an earlier run on the same input and settings was reused (the cost, "
                          "margin, names and sizes change only the packing and the bake)"]
    yield step("mesh", 0, 1, "Starting the mesh-wise fit")  # the islands found: a step apart
    meshwise = yield from _iter_fit(validated, planes, triangles, topology, stacks, settings, step, started)
    meshwise_results().put(key, meshwise)
    return meshwise, []


def _iter_fit(validated, planes, triangles, topology, stacks, settings, step, started):
    """The mesh-wise stage's work (:func:`iter_meshwise_stage`'s arguments); returns a :class:`MeshwiseStageResult`."""
    from ..core.chartfit import iter_fit_charts
    from ..core.loss_passes import iter_fit_losses
    from ..core.ssp import iter_ssp_targets
    from ..core.textured import iter_textured_triangles

    V, F, uv_in = validated.mesh.V, validated.mesh.F, validated.mesh.uv
    texture, faces = validated.texture, validated.faces
    height, width = texture.shape[:2]
    parts = StageParts("mesh", PART_SHARES, step, started=started)
    stage = iter_ssp_targets(V, F, uv_in, texture)
    signal, _, _ = yield from parts.relay(stage, "signal stretch", "Measuring the texture's signal stretch")
    # Which optimized triangles show texture in which plane: the fit's targets and the report's bound use it.
    stage = iter_textured_triangles(uv_in[faces], planes, per_plane=True)
    textured = yield from parts.relay(stage, "textured", "Finding the textured triangles")
    # Skipped triangles (zero area, or not showing the image) follow their chart without pulling on it.
    stage = triangles.iter_fit_targets(uv_in, planes, signal_targets=signal, textured=textured)
    targets = yield from parts.relay(stage, "targets", "Setting the mesh-wise fit's targets")
    params, w_R, w_S = validated.targets(targets, *triangles.fit_weights())
    target_losses = None
    measured = None  # the loss pass's (done, total) faces once it runs

    def measure(fits):  # a generator: the fit hands control back while the workers measure
        # The targets' losses (for the report) and the two fits' in one pass; skipped triangles show 0 in
        # the overlay and the report counts optimized ones only.
        nonlocal target_losses, measured
        passes = iter_fit_losses(
            V, F, uv_in, planes, targets, fits, faces=faces, screen_pixels=settings.screen_pixels,
            max_screen_pixels=settings.max_screen_pixels, workers=settings.workers, scheduler=settings.scheduler)
        while True:
            try:
                measured = next(passes)
            except StopIteration as finished:
                target_losses, losses = finished.value
                return losses
            yield measured

    stage = iter_fit_charts(F, uv_in, params, w_R, w_S, measure=measure, texel_scale=(width, height),
                            stacks=stacks, topology=topology)
    while True:  # the fits' iterations, then the loss pass's faces (the fit's count stands still meanwhile)
        try:
            done, total = next(stage)
        except StopIteration as finished:
            fit = finished.value
            break
        yield (parts.step("fit", done, total, "Mesh-wise fit, with and without rotation targets") if measured is None
               else parts.step("loss pass", *measured, "Measuring the loss of the targets and both fits"))
    return MeshwiseStageResult(uv=fit.uv, losses=fit.losses, restored=fit.restored, flipped=int(fit.flipped),
                               target_losses=target_losses, textured=textured)
