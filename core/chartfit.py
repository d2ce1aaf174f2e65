# SPDX-License-Identifier: GPL-3.0-or-later
"""The mesh-wise stage as the pipeline runs it: two fits of Eq. 19, and every chart keeps the better one.

Eq. 16's rotation terms pull each triangle towards its own best angle to the texel grid. Where the triangles
of a chart want different angles, the terms bend the chart, and the bending pulls triangles off their stretch
targets; where they agree, the terms keep the texture's lines on the grid. Which matters more differs between
models and between the charts of one model. So the stage fits twice, without rotation terms (``w_R = 0``) and
with Eq. 17's ``w_R``; folded charts get their input layout back (:func:`.overlap.restore_folded_charts`);
every chart of both fits is turned rigidly to the angle that best meets its rotation targets
(:func:`.chart_orientation.orient_charts`, which changes no stretch); the loss E of Sec. 4.1 is measured for every
triangle of both; and each chart keeps the fit whose triangles' losses sum lower, unless that fit folds the
chart over itself more than the other does. The fits and the turns measure Jacobians in texels of the input
texture, the frame of the triangle-wise targets, so a texture that is not square keeps the shape of its texels.
"""
from dataclasses import dataclass

import inspect

import numpy as np

from .chart_orientation import orient_charts
from .charts import UVTopology, uv_topology
from .meshwise import flipped_triangles, iter_solve_meshwise
from .overlap import FOLD_TOLERANCE, iter_restore_folded_charts, shared_area_fractions
from .progress import report_while_waiting, run_generator
from .stacks import restack_charts

__all__ = ["ChartFit", "finish_charts", "iter_fit_charts", "fit_charts"]


@dataclass(frozen=True, eq=False)
class ChartFit:
    """Output of :func:`fit_charts`.

    Attributes
    ----------
    uv : (m, 3, 2) float64 ndarray
        New UV per face corner, before packing.
    losses : (m,) float64 ndarray
        ``measure`` of the fit each triangle's chart kept.
    rotation_fit : (n_charts,) bool ndarray
        Charts that kept the fit with Eq. 16's rotation terms.
    angles : (n_charts,) float64 ndarray
        The rigid turn of every chart in the fit it kept (:func:`.chart_orientation.orient_charts`).
    restored : (k,) int64 ndarray
        Charts laid out as in the input because the fit they kept folded them.
    flipped : int
        Triangles whose orientation differs from the input's in ``uv``.
    topology : UVTopology
        Charts of the input (the output has the same ones).
    fits : tuple of two .meshwise.MeshwiseResult
        The fits without and with the rotation terms, as the solver returned them.
    """

    uv: np.ndarray
    losses: np.ndarray
    rotation_fit: np.ndarray
    angles: np.ndarray
    restored: np.ndarray
    flipped: int
    topology: UVTopology
    fits: tuple


def finish_charts(uv_in, uv_new, face_chart, *, alpha=None, w_R=None, texel_scale=(1.0, 1.0),
                  fold_tolerance=FOLD_TOLERANCE, stacks=None):
    """The post-processing of every method's charts before packing: the fold restore, the stacks, the chart turn.

    Folded charts get their input layout back at their new size (:func:`.overlap.restore_folded_charts`);
    charts that share texels in the input get their input layout back together, at their new size
    (:func:`.stacks.restack_charts`); then every chart, and every stack as one, is turned rigidly to the angle
    that best meets its rotation targets (:func:`.chart_orientation.orient_charts`, which changes no stretch and no
    fold). These are the steps :func:`fit_charts` applies to each of its fits.

    Parameters
    ----------
    uv_in : (m, 3, 2) array_like of float
        Input UVs per face corner.
    uv_new : (m, 3, 2) array_like of float
        The method's UVs of the same charts, before packing.
    face_chart : (m,) array_like of int
        Chart of every face in the input (``uv_topology(F, uv_in).face_chart``).
    alpha, w_R : (m,) array_like of float, optional
        The method's own rotation targets (angles to the input's texel grid) and their weights. Without them,
        ``alpha = 0`` and ``w_R = 1``: every chart is turned back to the input's texel grid, weighing its
        triangles by their input area.
    texel_scale : (2,) array_like of float, optional
        Texels per UV unit of the input texture along u and v.
    fold_tolerance : float, optional
        Of :func:`.overlap.restore_folded_charts`.
    stacks : (n_charts,) array_like of int, optional
        Stack of every chart (:func:`.stacks.stacked_charts` of ``uv_in``); without it no chart is stacked.

    Returns
    -------
    uv : (m, 3, 2) float64 ndarray
    restored : (k,) int64 ndarray
        Charts given their input layout because they folded.
    angles : (n_charts,) float64 ndarray
        The turn of every chart (the same for the charts of a stack).

    Notes
    -----
    Each method is turned towards its own targets. Ours has them: the triangle-wise optimum's rotation
    ``alpha`` with Eq. 17's ``w_R``. SSP, SSPOP (``w_R = 0``, paper Sec. 5.2.2) and Blender's unwraps carry
    no rotation target: their energies do not change when a chart turns, so the angle each chart ends at is
    whatever the solver drifted to (the unwraps start each island at an arbitrary angle). The only
    orientation information they have is the input's, on which the texture's lines were painted along the
    texel grid; keeping it (``alpha = 0``) is Eq. 16's rotation term with the identity as every target, and
    ``w_R = 1`` weighs every triangle by its area only, as no method among them measures which triangles care.
    With the packer's quarter turns (DESIGN decision 7), a chart at any multiple of 90 degrees to the input is
    on the grid, which is the symmetry ``orient_charts`` minimizes over.
    """
    return run_generator(_iter_finish_charts(uv_in, uv_new, face_chart, alpha=alpha, w_R=w_R,
                                             texel_scale=texel_scale, fold_tolerance=fold_tolerance, stacks=stacks))


def _iter_finish_charts(uv_in, uv_new, face_chart, *, alpha, w_R, texel_scale, fold_tolerance, stacks):
    """:func:`finish_charts` as a generator that yields None between its whole-mesh parts (each a few tenths of a
    second on 40,000 faces), so that :func:`iter_fit_charts` hands control back between them."""
    uv_in = np.asarray(uv_in, dtype=np.float64)
    face_chart = np.asarray(face_chart)
    uv, restored = yield from iter_restore_folded_charts(uv_in, uv_new, face_chart, tolerance=fold_tolerance)
    m = len(uv_in)
    alpha = np.zeros(m) if alpha is None else alpha
    w_R = np.ones(m) if w_R is None else w_R
    if stacks is None:
        uv, angles = orient_charts(uv_in, uv, face_chart, alpha, w_R, texel_scale=texel_scale)
        return uv, restored, angles
    stacks = np.asarray(stacks, dtype=np.int64)
    uv = restack_charts(uv_in, uv, face_chart, stacks)
    yield
    uv, angles = orient_charts(uv_in, uv, stacks[face_chart], alpha, w_R, texel_scale=texel_scale)
    return uv, restored, angles[stacks]


def iter_fit_charts(F, uv, targets, w_R, w_S, *, measure, texel_scale=(1.0, 1.0), max_iterations=100,
                    fold_tolerance=FOLD_TOLERANCE, stacks=None, topology=None):
    """Generator form of :func:`fit_charts`: yields ``(done, total)`` and returns the :class:`ChartFit`.

    It yields once the charts are found; for the two fits, which iterate at the same time, after either's solver
    set-up and every iteration; per fit before, between and after the parts of the post-processing
    (:func:`finish_charts`: the fold restore's two shared areas, the stacks, the chart turns; whole-mesh work
    that would otherwise share a step with the solver's last iteration and what follows it), while ``measure``
    (of both fits at once) runs if it is a generator, and when the losses are in; then once between the two
    fits' shared areas that the choice compares. A modal operator that calls ``next`` once per timer tick thus
    never waits for more than one of these parts at a time.
    """
    F = np.asarray(F)
    uv = np.asarray(uv, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    if targets.ndim != 2 or targets.shape[1] != 4:
        raise ValueError(f"targets must be (alpha, lambda1, lambda2, beta) rows of shape (m, 4), got "
                         f"{targets.shape}")
    if topology is None:
        topology = uv_topology(F, uv)
    elif topology.face_chart.shape != (len(uv),):
        raise ValueError("topology does not belong to these faces")
    chart = topology.face_chart
    steps = max_iterations + 1
    yield 0, 2 * steps  # the charts' topology is a step of its own
    candidates = []
    # The two fits are independent: driven in turn, each iterates in a thread of its own (SuperLU and numpy let
    # the other run), so on two cores they overlap.
    stages = [iter_solve_meshwise(F, uv, targets, rotation_weights, w_S, topology=topology,
                                  max_iterations=max_iterations, texel_scale=texel_scale)
              for rotation_weights in (np.zeros_like(np.asarray(w_R, dtype=np.float64)), w_R)]
    done, fits = [0, 0], [None, None]
    try:
        while fits[0] is None or fits[1] is None:
            for index, stage in enumerate(stages):
                if fits[index] is not None:
                    continue
                try:
                    done[index], _ = next(stage)
                except StopIteration as finished:
                    fits[index], done[index] = finished.value, max_iterations
                yield sum(done), 2 * steps
    finally:  # closed early (Esc): each fit's thread finishes its iteration and lets go
        for stage in stages:
            stage.close()
    finishes = (2 * max_iterations, 2 * steps)
    for fit in fits:
        yield finishes  # the fold restore, the stacks and the turns are steps of their own
        finishing = _iter_finish_charts(uv, fit.uv, chart, alpha=targets[:, 0], w_R=w_R, texel_scale=texel_scale,
                                        fold_tolerance=fold_tolerance, stacks=stacks)
        fitted, restored, angles = yield from report_while_waiting(finishing, finishes)
        candidates.append((fit, fitted, restored, angles))
        yield finishes  # and so is the start of what follows (the next finish, the measurement)
    # Both fits in one measurement: a loss pass prepares each triangle's views once for the two.
    measured = measure(tuple(fitted for _, fitted, _, _ in candidates))
    if inspect.isgenerator(measured):  # a long measurement that hands control back while it runs
        while True:
            try:
                next(measured)
            except StopIteration as finished:
                measured = finished.value
                break
            yield 2 * steps - 1, 2 * steps
    losses = np.asarray(measured, dtype=np.float64)
    if losses.shape != (2, len(uv)):
        raise ValueError(f"measure must return one loss per face for each of the two fits, shape (2, {len(uv)}), "
                         f"got {losses.shape}")
    candidates = [candidate + (fit_losses,) for candidate, fit_losses in zip(candidates, losses)]
    yield 2 * steps - 1, 2 * steps

    (plain, plain_uv, plain_restored, plain_angles, plain_losses), \
        (turned, turned_uv, turned_restored, turned_angles, turned_losses) = candidates
    # A stack chooses as one: its charts share texels, so they must keep the same layout.
    unit = np.arange(topology.n_charts) if stacks is None else np.asarray(stacks, dtype=np.int64)
    group, n = unit[chart], int(unit.max()) + 1
    turned_shared = shared_area_fractions(turned_uv, group, n)
    yield 2 * steps, 2 * steps  # the two fits' shared areas are a step each
    rotation_fit = ((np.bincount(group, turned_losses, n) < np.bincount(group, plain_losses, n))
                    & (turned_shared <= shared_area_fractions(plain_uv, group, n)))[unit]
    take = rotation_fit[chart]
    fitted = np.where(take[:, None, None], turned_uv, plain_uv)
    restored = np.union1d(plain_restored[~rotation_fit[plain_restored]],
                          turned_restored[rotation_fit[turned_restored]]).astype(np.int64)
    return ChartFit(uv=fitted, losses=np.where(take, turned_losses, plain_losses), rotation_fit=rotation_fit,
                    angles=np.where(rotation_fit, turned_angles, plain_angles), restored=restored,
                    flipped=int(flipped_triangles(uv, fitted, texel_scale=texel_scale).sum()), topology=topology,
                    fits=(plain, turned))


def fit_charts(F, uv, targets, w_R, w_S, *, measure, texel_scale=(1.0, 1.0), max_iterations=100,
               fold_tolerance=FOLD_TOLERANCE, stacks=None, topology=None, progress=None):
    """Fit the mesh-wise stage with and without Eq. 16's rotation terms; each chart keeps the better fit.

    Parameters
    ----------
    F : (m, 3) array_like of int
    uv : (m, 3, 2) array_like of float
        Input UVs per face corner.
    targets : (m, 4) array_like of float
        ``(alpha, lambda1, lambda2, beta)`` per face, as :func:`.meshwise.solve_meshwise` takes them: Jacobians
        between texels of the input texture (``texel_scale``).
    w_R, w_S : (m,) array_like of float
        Eq. 17's weights (``w_S`` as the fit uses it, e.g. with its floor). ``w_R`` weighs the rotation terms
        of the second fit and the chart turns of both.
    measure : callable
        ``measure(new_uvs) -> (2, m)``: the loss of every triangle under each of the two fits' new UVs
        (``new_uvs`` a tuple of two (m, 3, 2) arrays; e.g. :func:`.loss_passes.losses_at` of their stack; 0 for
        triangles it need not judge). Called once, after both fits, so that a loss pass prepares each triangle's
        views once for both. It may return a generator instead (e.g. :func:`.loss_passes.iter_losses_at`),
        whose return value is the losses: the fit yields while it runs, so a long measurement does not hold up
        a modal operator.
    texel_scale : (2,) array_like of float, optional
        Texels per UV unit of the input texture along u and v, ``(w, h)``: both fits
        (:func:`.meshwise.solve_meshwise`) and the chart turns (:func:`.chart_orientation.orient_charts`) meet the
        targets on the texel grid, so a ``w != h`` texture keeps its texels' shape and turns charts by texel
        angles. ``(1, 1)``: UV units.
    max_iterations : int, optional
        Local-global iterations per fit at most.
    fold_tolerance : float, optional
        Of :func:`.overlap.restore_folded_charts`: the growth of a chart's self-shared area fraction above
        which it gets its input layout back.
    stacks : (n_charts,) array_like of int, optional
        Stack of every chart of the input (:func:`.stacks.stacked_charts`): the charts of a stack get their
        input layout back together in both fits (:func:`finish_charts`) and keep the same fit. Without it no
        chart is stacked.
    topology : .charts.UVTopology, optional
        ``uv_topology(F, uv)`` when the caller has it already (it numbers the charts ``stacks`` refers to).
    progress : callable, optional
        Called as ``progress(done, total)``.

    Returns
    -------
    ChartFit

    Notes
    -----
    Neither fit is better on every model: rotation terms help where a chart's triangles agree on an angle and
    cost where they disagree, so each chart chooses (figures in docs/DECISIONS.md). A chart that folds keeps its
    input layout in either fit, and a fit that folds a chart over itself more than the other fit, below the
    restore tolerance, still shares texels there, which E (one triangle at a time) cannot see; the check keeps
    the other fit for such a chart.

    References
    ----------
    Sun et al. 2022, Eq. 16-19 (the fit), Sec. 4.1 (E), Eq. 17 (``w_R``), Sec. 4.2 ("Bijectivity").
    """
    return run_generator(iter_fit_charts(F, uv, targets, w_R, w_S, measure=measure, texel_scale=texel_scale,
                                         max_iterations=max_iterations, fold_tolerance=fold_tolerance, stacks=stacks,
                                         topology=topology),
                         progress)
