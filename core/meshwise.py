"""Mesh-wise stage: one conforming, flip-free UV map that fits per-triangle optimal Jacobians (Sec. 4.2, App. B).

The unknown is the map phi from the input UVs to new UVs, piecewise linear on the input triangles, so its
Jacobian ``J_i = grad phi_i`` maps the edge vectors of input triangle i to those of new triangle i, both
measured in texels of the input texture (see "Texel frame" below). The triangle-wise stage gives the optimum
``R_bar_i S_bar_i`` of each triangle up to a quarter turn. We minimize Eq. 19 with a flip barrier,

    sum_i a_i [ w_R |R_i - R(k_i pi/2) R_bar_i|^2 + w_S |S_i - S_bar_i|^2
                + w_rs |J_i - R_i S_i|^2 + w_b B(det J_i; s_i) ],

by the local-global scheme of App. B: the local step picks k_i, R_i = R(theta_i), S_i per triangle
(:mod:`.meshwise_local`), the global step minimizes Eq. 27 over the chart-vertex UVs by damped Newton
(:mod:`.meshwise_global`). This module runs the iterations (:func:`solve_meshwise`) and tells which triangles of a
map lost their input orientation (:func:`flipped_triangles`); the rigid turn of every chart after the fit is
:mod:`.chart_orientation`.

Decisions (the paper leaves them open; those of the local step are in :mod:`.meshwise_local`, the area weights,
the barrier, the gauge and the factorization in :mod:`.meshwise_global`):

* Texel frame: the triangle-wise targets are Jacobians between texel coordinates ``(u w, v h)`` of a ``w x h``
  texture (:mod:`.loss`), and Eq. 16's quarter-turn symmetry holds on the texel grid. So the whole solve
  (targets, quarter turns, area weights, barrier, degenerate test) runs on the UVs scaled by ``texel_scale =
  (w, h)``, and the result is scaled back to UV units. A Jacobian ``A`` met in UV units is ``diag(w, h) A
  diag(w, h)^-1`` in texels, so on a ``w != h`` texture a solve in UV units would meet every rotation and
  every stretch not aligned with the axes in the wrong frame: on a 2:1 texture the conformal target
  ``0.5 R(pi/6)`` would get singular values 0.72 and 0.35 in texels. Eq. 19 does not see a uniform scale of
  the frame (the area weights are normalized, the degenerate test is relative, J and its determinant are
  unchanged), so only ``w / h`` matters: the frame is ``(sqrt(w / h), sqrt(h / w))``, which keeps UV areas,
  and on a square texture it is ``(1, 1)`` exactly, the solve in UV units.
* Orientation: ``det J_i > 0`` says triangle i keeps the orientation it has in the input UVs, whatever the
  orientation of its chart, so mirrored charts (and mirrored triangles inside a chart) need no reflection:
  the barrier and the line search work on det J directly.
* Degenerate input triangles (input-UV area at most ``degenerate_tol`` times the squared longest edge) have
  no Jacobian: they get weight 0 (no fit, no barrier), and they are neither counted as flipped nor allowed to
  stop the line search. Their corners move with their chart: a vertex that only degenerate triangles touch
  has no energy of its own, so after the fit it is carried by the fitted Jacobian of a valid triangle at the
  nearest fitted vertex of its chart (:func:`_carry_loose_vertices`). Left where it was, it kept the chart's
  input extent: WaterBottle's strip of 80 zero-area and 80 thin triangles (a zipper whose loose vertices lie
  on or next to fitted ones) stayed 0.68 long while the rest shrank, its zero-area triangles opened to half
  the chart's input area, and packing left 96 % of the image empty (r = 4478 instead of about 1100 at
  c_r = 0.3). Carried, 78 of the 80 stay exactly flat and two become slivers (height below 1e-7 of their
  longest edge; :func:`.evaluation.symmetric_dirichlet` counts them as degenerate).
* Eq. 28 compares the weighted terms of Eq. 27: ``w_b`` is divided by 20 after an iteration in which
  ``w_b E_barrier > w_rs E_rs``. Lowering ``w_b`` only lowers the objective, so the history stays monotone.
"""
import dataclasses
import threading
from dataclasses import dataclass

import numpy as np

from .charts import UVTopology, uv_topology, validate_faces_and_uv
from .deformation import jacobian, rotation
from .meshwise_global import _edges_and_validity, _NewtonSolver, _Objective, _prepare
from .meshwise_local import _frob2, _local_update_kernel, fit_energy
from .progress import InThread, report_while_waiting, run_generator

__all__ = ["MeshwiseResult", "solve_meshwise", "iter_solve_meshwise", "flipped_triangles"]


@dataclass(frozen=True, eq=False)
class MeshwiseResult:
    """Output of :func:`solve_meshwise`.

    Attributes
    ----------
    uv : (m, 3, 2) float64 ndarray
        New UV per face corner, in the input's UV units; corners sharing a chart vertex share their UV.
    vertex_uv : (k, 2) float64 ndarray
        New UV of every chart vertex of ``topology``.
    topology : UVTopology
        Charts of the input (the output has the same ones).
    iterations : int
        Local-global iterations run.
    energy_history : (iterations + 1,) float64 ndarray
        Objective (Eq. 19 plus ``w_b`` times the barrier) at the start and after every iteration;
        non-increasing.
    fit_energy : float
        Eq. 16 summed with the area weights at the final map, with R, S the polar factors of its Jacobians in
        the texel frame (for ``formulation="common"``: Eq. 15 summed).
    quarter_turns : (m,) int64 ndarray
        The chosen k_i (quarter turns on the texel grid).
    flipped : int
        Non-degenerate triangles whose orientation differs from the input's.
    degenerate : int
        Input triangles treated as degenerate (not fitted, not counted as flipped).
    barrier_weight : float
        Final w_b.
    converged : bool
        Whether the tolerance was met before ``max_iterations``.
    """

    uv: np.ndarray
    vertex_uv: np.ndarray
    topology: UVTopology
    iterations: int
    energy_history: np.ndarray
    fit_energy: float
    quarter_turns: np.ndarray
    flipped: int
    degenerate: int
    barrier_weight: float
    converged: bool


def _parse_targets(targets, m):
    if isinstance(targets, (tuple, list)) and len(targets) == 2:
        R_bar = np.asarray(targets[0], dtype=np.float64)
        S_bar = np.asarray(targets[1], dtype=np.float64)
        if R_bar.shape != (m, 2, 2) or S_bar.shape != (m, 2, 2):
            raise ValueError(f"targets (R_bar, S_bar) must both have shape ({m}, 2, 2), "
                             f"got {R_bar.shape} and {S_bar.shape}")
        if not np.allclose(np.swapaxes(R_bar, 1, 2) @ R_bar, np.eye(2), atol=1e-9) or np.any(
                np.linalg.det(R_bar) < 0):
            raise ValueError("R_bar must hold rotations (orthogonal, determinant +1)")
        if not np.allclose(S_bar, np.swapaxes(S_bar, 1, 2), atol=1e-12):
            raise ValueError("S_bar must hold symmetric matrices")
    else:
        params = np.asarray(targets, dtype=np.float64)
        if params.shape != (m, 4):
            raise ValueError(f"targets must be params of shape ({m}, 4) (alpha, lambda1, lambda2, beta) or a "
                             f"pair (R_bar, S_bar) of (m, 2, 2) arrays, got shape {params.shape}")
        R_bar, S_bar = jacobian(params)
    if not (np.all(np.isfinite(R_bar)) and np.all(np.isfinite(S_bar))):
        raise ValueError("targets hold NaN or infinite values")
    det = S_bar[:, 0, 0] * S_bar[:, 1, 1] - S_bar[:, 0, 1] ** 2
    if np.any(det <= 0) or np.any(S_bar[:, 0, 0] <= 0):
        raise ValueError("S_bar must be positive definite (lambda1, lambda2 > 0)")
    return np.ascontiguousarray(R_bar), np.ascontiguousarray(S_bar)


def _parse_weights(w, m, name):
    w = np.asarray(w, dtype=np.float64)
    if w.shape != (m,):
        raise ValueError(f"{name} must have shape ({m},), got {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"{name} must be finite and non-negative")
    return w


def _texel_frame(texel_scale):
    """Scale of u and v that makes UV steps proportional to texel steps, with unit determinant.

    Parameters
    ----------
    texel_scale : (2,) array_like of float
        Texels per UV unit along u and v, ``(w, h)``.

    Returns
    -------
    (2,) float64 ndarray
        ``(sqrt(w / h), sqrt(h / w))``; exactly ``(1, 1)`` when ``w == h``.
    """
    scale = np.asarray(texel_scale, dtype=np.float64)
    if scale.shape != (2,) or not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"texel_scale must be two positive numbers, got {texel_scale}")
    root = np.sqrt(scale[0] / scale[1])
    return np.array([root, 1.0 / root])


def flipped_triangles(uv_in, uv_new, *, degenerate_tol=1e-10, texel_scale=(1.0, 1.0)):
    """Which triangles of ``uv_new`` lost the orientation they have in ``uv_in`` (``det J <= 0``).

    Parameters
    ----------
    uv_in, uv_new : (m, 3, 2) array_like of float
        UVs per face corner before and after.
    degenerate_tol : float, optional
        As in :func:`solve_meshwise`: degenerate input triangles are never counted.
    texel_scale : (2,) array_like of float, optional
        As in :func:`solve_meshwise`: the degenerate test is made in texels of the input texture.

    Returns
    -------
    (m,) bool ndarray
        Summed, the ``flipped`` count of :class:`MeshwiseResult` for its own ``uv``.
    """
    uv_in = np.asarray(uv_in, dtype=np.float64)
    uv_new = np.asarray(uv_new, dtype=np.float64)
    if uv_in.ndim != 3 or uv_in.shape[1:] != (3, 2) or uv_new.shape != uv_in.shape:
        raise ValueError(f"uv_in and uv_new must both have shape (m, 3, 2), got {uv_in.shape} and {uv_new.shape}")
    frame = _texel_frame(texel_scale)
    _, det_in, valid = _edges_and_validity(uv_in * frame, degenerate_tol)
    _, det_new, _ = _edges_and_validity(uv_new * frame, degenerate_tol)
    return valid & ~(det_new * np.sign(det_in) > 0)


def _carry_loose_vertices(x, problem, topology, J):
    """Places the vertices no valid triangle touches: ``x[n] + J_t (x0[v] - x0[n])``, ``n`` the nearest (in input
    UVs) vertex of the same chart that a valid triangle ``t`` touches. Charts without a valid triangle stay."""
    from scipy.spatial import cKDTree

    x0 = topology.vertex_uv
    touching = np.full(problem.n_vertices, -1, dtype=np.int64)
    touching[problem.corner_vertex[problem.valid].ravel()] = np.repeat(np.flatnonzero(problem.valid), 3)
    loose = touching < 0
    if not loose.any():
        return x
    x = x.copy()
    for chart in np.unique(topology.vertex_chart[loose]):
        in_chart = topology.vertex_chart == chart
        fitted = np.flatnonzero(in_chart & ~loose)
        if fitted.size == 0:
            continue
        moving = np.flatnonzero(in_chart & loose)
        nearest = fitted[cKDTree(x0[fitted]).query(x0[moving])[1]]
        x[moving] = x[nearest] + np.einsum("vij,vj->vi", J[touching[nearest]], x0[moving] - x0[nearest])
    return x


def iter_solve_meshwise(F, uv, targets, w_R=None, w_S=None, *, weights="perceptual", formulation="perceptual",
                        w_rs=1e-5, barrier_weight=1.0, barrier_threshold=0.5, max_iterations=100, tol=1e-7,
                        newton_iterations=1, degenerate_tol=1e-10, topology=None, texel_scale=(1.0, 1.0)):
    """Generator form of :func:`solve_meshwise`: yields ``(done, total)`` after the set-up (``done = 0``) and
    after every iteration.

    The result comes back as the generator's return value, so a pipeline generator writes
    ``result = yield from iter_solve_meshwise(...)``; parameters are those of :func:`solve_meshwise`.
    """
    F, uv = validate_faces_and_uv(F, uv)
    m = F.shape[0]
    R_bar, S_bar = _parse_targets(targets, m)
    if weights == "perceptual":
        if formulation == "perceptual" and (w_R is None or w_S is None):
            raise ValueError("weights='perceptual' needs w_R and w_S (Eq. 17); use weights='identity' without them")
        w_R = _parse_weights(w_R, m, "w_R") if w_R is not None else np.ones(m)
        w_S = _parse_weights(w_S, m, "w_S") if w_S is not None else np.ones(m)
    elif weights == "identity":
        w_R = np.ones(m)
        w_S = np.ones(m)
    else:
        raise ValueError(f"weights must be 'perceptual' or 'identity', got {weights!r}")
    if formulation not in ("perceptual", "common"):
        raise ValueError(f"formulation must be 'perceptual' or 'common', got {formulation!r}")
    for name, value in (("w_rs", w_rs), ("barrier_weight", barrier_weight)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be positive and finite, got {value}")
    if not 0 < barrier_threshold <= 1:
        raise ValueError(f"barrier_threshold must be in (0, 1], got {barrier_threshold}")
    if int(max_iterations) < 1 or int(newton_iterations) < 1:
        raise ValueError("max_iterations and newton_iterations must be at least 1")
    if not tol >= 0:
        raise ValueError(f"tol must be non-negative, got {tol}")
    frame = _texel_frame(texel_scale)
    if topology is None:
        topology = uv_topology(F, uv)
    elif topology.corner_vertex.shape != (m, 3):
        raise ValueError("topology does not belong to these faces")
    # The solve runs in the texel frame (module docstring); the result is mapped back to UV units at the end.
    texel_topology = dataclasses.replace(topology, vertex_uv=topology.vertex_uv * frame)

    problem = _prepare(texel_topology, uv * frame, S_bar, degenerate_tol=degenerate_tol,
                       barrier_threshold=barrier_threshold)
    valid = problem.valid
    common = formulation == "common"
    quad_weight = 1.0 if common else float(w_rs)
    w_b = quad_weight * float(barrier_weight)
    x = texel_topology.vertex_uv.copy()
    J = problem.jacobians(x)
    R = np.tile(np.eye(2), (m, 1, 1))
    S = R.copy()
    k = np.zeros(m, dtype=np.int64)
    a = problem.weight

    def objective_of(J_, k_, R_, S_):
        if common:
            target = rotation(k_ * np.pi / 2) @ R_bar @ S_bar
            return _Objective(problem, target, 1.0, w_b, 0.0)
        fit = w_R * _frob2(R_ - rotation(k_ * np.pi / 2) @ R_bar) + w_S * _frob2(S_ - S_bar)
        return _Objective(problem, R_ @ S_, float(w_rs), w_b, float((a * fit).sum()))

    history = [objective_of(J, k, R, S).value(J)]
    scale = max(history[0], np.finfo(float).tiny)
    # The Hessian's pattern sorts a few million keys (a few tenths of a second on 40,000 faces): numpy's sort lets
    # other threads run, so it runs in a thread while this generator hands control back.
    solver = yield from report_while_waiting(InThread(_NewtonSolver, problem).wait(), (0, int(max_iterations)))
    shift = None
    current = history[0]

    def iterate():
        """One local step and the global step (Eq. 27), in the iterations' thread (below)."""
        nonlocal x, J, k, current, shift, w_b
        # Local step.
        if common:
            _, k_new = fit_energy(J, R_bar, S_bar, w_R, w_S, formulation="common")
            k = k_new
        else:
            _local_update_kernel(J, R_bar, S_bar, w_R, w_S, float(w_rs), k, R, S)
        objective = objective_of(J, k, R, S)
        current = objective.value(J)

        # Global step: damped Newton on Eq. 27.
        for _ in range(int(newton_iterations)):
            grad, blocks = objective.gradient_and_blocks(J)
            if shift is None:
                shift = 1e-12 * np.einsum("tii->t", blocks).sum() / max(problem.n_free, 1)
            step = solver.newton_step(grad, blocks, shift)
            slope = float(grad @ step)
            if not slope < 0:
                break
            direction = np.zeros(2 * problem.n_vertices)
            direction[problem.free_index >= 0] = step[problem.free_index[problem.free_index >= 0]]
            direction = direction.reshape(2, -1).T
            t = min(1.0, 0.9 * objective.max_step(x, direction))
            accepted = False
            for _ in range(40):
                x_trial = x + t * direction
                J_trial = problem.jacobians(x_trial)
                trial = objective.value(J_trial)
                if trial <= current + 1e-4 * t * slope:
                    accepted = True
                    break
                t *= 0.5
            if not accepted:
                break
            x, J, current = x_trial, J_trial, trial

        history.append(current)
        quad, bar = objective.parts(J)
        if w_b * bar > quad_weight * quad:
            w_b /= 20.0
            history[-1] = objective_of(J, k, R, S).value(J)

    iterations = [0]  # done so far, written by the iterations' thread
    stop = threading.Event()

    def iterate_until_converged():
        """Whether the iterations converged; the factorizations are dropped in this thread (scipy issue 15921,
        :meth:`_NewtonSolver.release`)."""
        try:
            for iteration in range(1, int(max_iterations) + 1):
                if stop.is_set():  # the generator was closed
                    return False
                iterate()
                iterations[0] = iteration
                if history[-2] - history[-1] <= tol * max(history[-1], 1e-9 * scale):
                    return True
            return False
        finally:
            solver.release()

    yield 0, int(max_iterations)  # the set-up is a step of its own
    # A factorization alone takes a quarter of a second on tea_set_01's 43,662 unknowns: the iterations run one
    # after the other in a thread of their own (SuperLU and numpy let other threads run), and the generator
    # reports each iteration done and hands control back every 0.1 s meanwhile. Two fits driven in turn
    # (fit_charts) iterate at the same time.
    waiting = InThread(iterate_until_converged).wait()
    reported = 0
    try:
        while True:
            try:
                next(waiting)
                finished = False
            except StopIteration as returned:
                converged, finished = returned.value, True
            if iterations[0] == reported and not finished:
                yield reported, int(max_iterations)  # still in the same iteration
            while reported < iterations[0]:
                reported += 1
                yield reported, int(max_iterations)
            if finished:
                break
    finally:  # also when the generator is closed mid-iteration: the thread finishes it, then lets go
        stop.set()

    x = _carry_loose_vertices(x, problem, texel_topology, J) / frame
    final_fit, k_final = fit_energy(J, R_bar, S_bar, w_R, w_S, formulation=formulation)
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    return MeshwiseResult(
        uv=topology.corner_uv(x),
        vertex_uv=x,
        topology=topology,
        iterations=iterations[0],
        energy_history=np.asarray(history),
        fit_energy=float((a * final_fit)[valid].sum()),
        quarter_turns=k if not common else k_final,
        flipped=int(np.sum(valid & ~(det > 0))),
        degenerate=int(np.sum(~valid)),
        barrier_weight=float(w_b),
        converged=converged,
    )


def solve_meshwise(F, uv, targets, w_R=None, w_S=None, *, weights="perceptual", formulation="perceptual",
                   w_rs=1e-5, barrier_weight=1.0, barrier_threshold=0.5, max_iterations=100, tol=1e-7,
                   newton_iterations=1, degenerate_tol=1e-10, topology=None, texel_scale=(1.0, 1.0),
                   progress=None):
    """Fit one flip-free UV map with the input's charts to per-triangle optimal Jacobians (Eq. 19).

    Parameters
    ----------
    F : (m, 3) array_like of int
        Triangles (3D vertex indices).
    uv : (m, 3, 2) array_like of float
        Input UVs per face corner; the map phi starts as the identity on them.
    targets : (m, 4) array_like, or pair of (m, 2, 2) array_like
        Per-triangle optimum, either as ``(alpha, lambda1, lambda2, beta)`` rows (Eq. 13-14) or as
        ``(R_bar, S_bar)``; ``R_bar S_bar`` maps input edge vectors to new ones, both in texels
        ``(u w, v h)`` of ``texel_scale``.
    w_R, w_S : (m,) array_like of float, optional
        Non-negative rotation and stretch weights of Eq. 17 (needed for ``weights="perceptual"``).
    weights : {"perceptual", "identity"}
        ``"identity"`` sets ``w_R = w_S = 1`` (the "Identity" ablation of Fig. 17).
    formulation : {"perceptual", "common"}
        ``"common"`` minimizes Eq. 15, ``min_k |J - R(k pi/2) R_bar S_bar|^2`` (the "Common" ablation of
        Fig. 17), with the same barrier and solver.
    w_rs : float
        Weight of ``|J - R S|^2`` (Eq. 19); the paper's 1e-5.
    barrier_weight : float
        Initial w_b as a multiple of the quadratic weight (w_rs, or 1 for "common"); Eq. 28 lowers it.
    barrier_threshold : float in (0, 1]
        Barrier threshold s_i as a fraction of ``min(1, det S_bar_i)``.
    max_iterations : int
        Local-global iterations at most.
    tol : float
        Stop when an iteration lowers the objective by at most ``tol`` times its current value (or times
        1e-9 of its initial value once the objective is that small, e.g. when targets are met exactly).
    newton_iterations : int
        Damped Newton steps per global step.
    degenerate_tol : float
        An input triangle with ``|2 area| <= degenerate_tol * (longest edge)^2`` is degenerate (see Notes).
    topology : UVTopology, optional
        Precomputed :func:`~perceptual_uv.core.charts.uv_topology` of ``(F, uv)``.
    texel_scale : (2,) array_like of float, optional
        Texels per UV unit along u and v of the input texture, ``(w, h)``, the frame in which the targets,
        their quarter turns and Eq. 19 are measured (only ``w / h`` matters). The default ``(1, 1)`` is UV
        units, right for a square texture and for targets stated in UV units (e.g. :func:`.ssp.ssp_targets`).
    progress : callable, optional
        Called as ``progress(done, total)`` after the set-up (``done = 0``) and after every iteration.

    Returns
    -------
    MeshwiseResult
        New UVs in the input's UV units.

    Notes
    -----
    Decisions not fixed by the paper are listed in the docstrings of this module, :mod:`.meshwise_local` and
    :mod:`.meshwise_global`: area weights by input-UV area, exact block minimization in the local step (monotone
    objective), SKPS13 barrier with per-triangle threshold, orientation kept per triangle (mirrored charts need no
    special case), degenerate input triangles weighted 0, one fixed vertex per chart as the translation gauge, the
    solve in the texel frame.

    References
    ----------
    Sun et al. 2022, Eq. 15-19, App. B Eq. 25-28; Schueller et al. 2013 (barrier, damped Newton);
    Smith and Schaefer 2015 (largest step before a triangle inverts).
    """
    generator = iter_solve_meshwise(F, uv, targets, w_R, w_S, weights=weights, formulation=formulation,
                                    w_rs=w_rs, barrier_weight=barrier_weight,
                                    barrier_threshold=barrier_threshold, max_iterations=max_iterations, tol=tol,
                                    newton_iterations=newton_iterations, degenerate_tol=degenerate_tol,
                                    topology=topology, texel_scale=texel_scale)
    return run_generator(generator, progress)
