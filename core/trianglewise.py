"""Triangle-wise stage: per triangle, the smallest texel area whose perceptual loss stays within epsilon.

For triangle ``i`` the deformation ``grad phi_i = R(alpha) V(beta) diag(lambda1, lambda2) V(beta)^T``
(Eq. 13-14) scales the triangle's texel area by ``lambda1 * lambda2``; the loss ``E(alpha, lambda1, lambda2,
beta)`` is the GMSD between the reference render of the faces around it and their render after re-baking the
deformed texels (:mod:`.loss`). The paper solves Eq. 7,

    min lambda1 lambda2 |tri_i^t|   subject to   E <= epsilon,

through the barrier form Eq. 12-14 and Bayesian optimization, then measures the sensitivity weights of Eq. 17
for the mesh-wise stage.

Decisions (the paper leaves them open):

* Box: ``alpha, beta in [0, pi/2)`` (the paper's symmetry argument), ``lambda in [lambda_min, 1]`` with
  ``lambda_min = 0.1``: a triangle may shrink to 1 % of its texel area. The paper's ``(0, 1]`` is open at 0;
  a floor is needed for a box, and below ~0.1 a one-ring of typical size (tens of texels) collapses to a
  handful of texels, where the re-bake is decided by its regularization rather than the texture, and the
  mesh-wise stage has to squeeze triangles towards degeneracy.
* View size: App. A's 64 px, grown to one pixel per input texel across the view, up to
  :data:`.camera.MAX_SCREEN_PIXELS` = 256 (:func:`.camera.texel_matched_pixels`). A 64 px view of a triangle spanning
  hundreds of texels skips texels: on wooden_bookshelf's large panels E stayed 0 (< 5e-5) down to
  ``lambda = 0.3`` at 64 px and was 1e-2 to 4e-2 there at 256 px, and those panels were blurred in every
  whole-mesh view. On models whose triangles span fewer than ~64 texels (spot) nothing changes.
* ``alpha`` is treated as periodic with period ``pi/2`` by the GP kernel: a quarter turn of ``R`` about a
  texel centre maps the texel lattice onto itself, so ``E(alpha + pi/2) = E(alpha)`` exactly (:mod:`.loss`).
* Two formulations. ``"constrained"`` (default) solves Eq. 7 directly: the cost ``lambda1 lambda2`` is
  known, a GP models ``g = log(E + epsilon / 10)`` (the log spreads the values near the bound and tames the
  large losses of strong shrinking), and the acquisition is the exact area improvement times the GP
  probability that ``E <= epsilon`` (:func:`.bayesopt.minimize_constrained`). The identity and the smallest
  box corner ``(0, lambda_min, lambda_min, 0)`` are the first two evaluations: when the corner is feasible it
  is the global optimum and the run stops there. ``"barrier"`` is the paper's Eq. 14, minimized with
  expected improvement (:func:`.bayesopt.minimize`, or scikit-optimize with ``backend="skopt"``). Its area
  term is ``lambda1 lambda2 |tri^t|`` in texels of the input texture (``problem.uv_area``). The GP cannot
  take the infinite barrier, so it sees :func:`finite_barrier`: ``-log(epsilon - E)`` up to
  ``E = epsilon - delta`` with ``delta = epsilon / 100``, then its first-order-matching logarithmic
  continuation ``-log(delta) + log(1 + (E - epsilon + delta) / delta)``: finite, increasing, continuous with
  a continuous slope, and only logarithmically growing, so one very bad sample does not flatten the GP.
  The last ``POLISH_EVALUATIONS = 12`` evaluations of the constrained form bisect ``lambda1`` and ``lambda2``
  one at a time from the best feasible point (:func:`_polish`): aligned high-frequency textures have thin
  feasible sets (stripes: ``alpha ~ 0``, ``beta ~ 0``, ``lambda1 ~ 1``, any ``lambda2``) that a stationary GP
  finds but rarely walks along. The Bayesian optimization hands over to the bisection early once
  ``PATIENCE = 24`` evaluations in a row (six rounds of four) cut the smallest feasible area by less than
  ``PATIENCE_IMPROVEMENT = 0.02`` of it: the feasible boundary is settled, later rounds rarely find a
  smaller area, and the bisection takes the last per cents along ``lambda1`` and ``lambda2`` for fewer
  evaluations than the search spends creeping towards them.
  Both formulations return the best evaluated point that satisfies ``E <= epsilon`` by the exact criterion
  (area, or Eq. 14 with the true barrier); the identity is always evaluated first, so one exists whenever
  the input itself is within the bound (``E(identity) ~ 1e-12``).
* The mesh-wise stage gets the optimum with a texel floor and the signal-stretch blend, and Eq. 17's weights
  with a floor (:mod:`.trianglewise_result`).
* Weights (Eq. 17) are population variances of E over fixed samples, the other parameters at the optimum:
  ``w_R`` over ``alpha`` at the 8 midpoints ``(k + 1/2) pi / 16`` of ``[0, pi/2)`` (E is ``pi/2``-periodic
  in ``alpha`` and the midpoint rule is the exact-for-trigonometric-polynomials rule for periodic
  functions); ``w_S`` over 16 points of a scrambled Sobol sequence (fixed seed, the same for every triangle,
  so weights of different triangles are comparable) in ``[lambda_min, 1]^2 x [0, pi/2)``. These 24
  evaluations are counted in ``evaluations``.
* Constant views (``problem.is_constant``: every texel any allowed deformation can read has the same
  luma, in every plane of a stack, so ``E = 0`` exactly) skip the optimization:
  ``(0, lambda_min, lambda_min, 0)``, ``E = 0``, ``w_R = w_S = 0``, no evaluation.
* Determinism: each triangle's optimizer is seeded by ``(seed, face)``, so results do not depend on the
  number of workers or on how faces are split into chunks.
* Workers are spawned processes that receive the mesh arrays once and face-index chunks afterwards
  (:mod:`.worker_pool`), or the workers of a Dask cluster.

The paper as written (for comparison; every keyword's default is the project's choice): App. A's fixed
64 px views of the one-ring, the barrier form, no texel floor, no blend, Eq. 17's weights unchanged::

    result = optimize_triangles(V, F, uv, luma, screen_pixels=64, max_screen_pixels=64,
                                formulation="barrier", view_faces="one_ring")
    targets = result.fit_targets(uv, luma, min_texels=0)          # no signal_targets: no blend
    w_R, w_S = result.fit_weights(floor=0.0, rotation_scale=1.0)  # Eq. 17 as measured

then one mesh-wise fit, ``solve_meshwise(F, uv, targets, w_R, w_S, texel_scale=(w, h))`` with its default
``w_rs = 1e-5`` (Eq. 19, :func:`.meshwise.solve_meshwise`; ``(h, w)`` the texture's shape, as the targets are
in texels). E stays GMSD over the covered pixels (:func:`.gmsd.covered_gmsd`) in both settings.

References
----------
Sun et al. 2022, Sec. 4.1 (Eq. 6-7, 12-14), Sec. 4.2 (Eq. 17), App. A.
"""
import contextlib
import dataclasses
import functools
import math
import time

import numpy as np

from . import bayesopt
from .camera import MAX_SCREEN_PIXELS
from .loss import _check_view_faces
from .loss_passes import _check_mesh, _iter_state, _prepared
from .progress import report_while_waiting, run_generator
from .trianglewise_result import TrianglewiseResult
from .worker_pool import WorkerDiedError, run_chunks

__all__ = ["WorkerDiedError", "LossNotEvaluableError", "LAMBDA_MIN", "TriangleOptimum", "TrianglewiseResult",
           "finite_barrier", "sensitivity_weights", "optimize_triangle", "iter_optimize_triangles",
           "optimize_triangles"]

LAMBDA_MIN = 0.1
_IDENTITY = np.array([0.0, 1.0, 1.0, 0.0])
_IDENTITY.setflags(write=False)  # shared by every call: a write would change every later triangle's start
# Least time between two calls of the triangle-wise stage's ``checkpoint`` (each writes a few hundred bytes per
# face done): a run cut off loses at most this much work.
CHECKPOINT_SECONDS = 30.0
ROTATION_SAMPLES = 8
STRETCH_SAMPLES = 16
POLISH_EVALUATIONS = 12
PATIENCE = 24
PATIENCE_IMPROVEMENT = 0.02
_QUARTER = 0.5 * math.pi
_FORMULATIONS = ("constrained", "barrier")
_BACKENDS = ("fast", "skopt")


# ---------------------------------------------------------------------------------------------------- objective
def finite_barrier(loss, epsilon):
    """The barrier of Eq. 12 with a finite, increasing continuation for the GP.

    Parameters
    ----------
    loss : (k,) array_like
        Perceptual loss values E.
    epsilon : float
        The bound.

    Returns
    -------
    (k,) ndarray
        ``-log(epsilon - E)`` for ``E <= epsilon - delta`` and ``-log(delta) + log(1 + (E - epsilon + delta) /
        delta)`` above, ``delta = epsilon / 100``: value and slope agree at the joint.

    References
    ----------
    Sun et al. 2022, Eq. 12.
    """
    loss = np.asarray(loss, dtype=np.float64)
    delta = 0.01 * epsilon
    joint = epsilon - delta
    inside = -np.log(np.maximum(epsilon - loss, delta))
    outside = -math.log(delta) + np.log1p(np.maximum(loss - joint, 0.0) / delta)
    return np.where(loss <= joint, inside, outside)


def _barrier_objective(params, loss, area, epsilon):
    """Eq. 14 exactly: infinite outside the bound."""
    with np.errstate(divide="ignore", invalid="ignore"):
        barrier = np.where(loss < epsilon, -np.log(np.maximum(epsilon - loss, 0.0)), np.inf)
    return params[:, 1] * params[:, 2] * area + barrier


def _bounds(lambda_min):
    return np.array([[0.0, _QUARTER], [lambda_min, 1.0], [lambda_min, 1.0], [0.0, _QUARTER]])


@functools.lru_cache(maxsize=8)
def _stretch_samples(lambda_min, count):
    """The same ``(lambda1, lambda2, beta)`` samples for every triangle (made once: a Sobol engine costs about
    half a millisecond, one to two per cent of a face's optimization); read-only, as every caller shares them."""
    import scipy.stats.qmc

    unit = scipy.stats.qmc.Sobol(d=3, scramble=True, seed=0).random(count)
    samples = np.column_stack([lambda_min + (1.0 - lambda_min) * unit[:, 0], lambda_min + (1.0 - lambda_min) *
                               unit[:, 1], _QUARTER * unit[:, 2]])
    samples.setflags(write=False)
    return samples


# ---------------------------------------------------------------------------------------------------- one triangle
@dataclasses.dataclass(frozen=True)
class TriangleOptimum:
    """Result of :func:`optimize_triangle`.

    Attributes
    ----------
    params : (4,) ndarray
        ``(alpha, lambda1, lambda2, beta)`` at the optimum.
    loss : float
        E at ``params``.
    w_R, w_S : float
        Sensitivity weights of Eq. 17.
    evaluations : int
        Loss evaluations used (optimization and weights).
    feasible : bool
        ``loss <= epsilon``.
    """

    params: np.ndarray
    loss: float
    w_R: float
    w_S: float
    evaluations: int
    feasible: bool


def sensitivity_weights(problem, params, *, lambda_min=LAMBDA_MIN, rotation_samples=ROTATION_SAMPLES,
                        stretch_samples=STRETCH_SAMPLES):
    """Rotation and stretch sensitivities of E at an optimum (Eq. 17).

    Parameters
    ----------
    problem : TriangleProblem
        From :func:`.loss.triangle_problem` (anything with ``evaluate((k, 4)) -> (k,)``).
    params : (4,) array_like
        ``(alpha, lambda1, lambda2, beta)`` at the optimum.
    lambda_min : float, optional
        Lower end of the uniform ``lambda`` samples.
    rotation_samples, stretch_samples : int, optional
        Number of ``alpha`` midpoints and of Sobol ``(lambda1, lambda2, beta)`` points.

    Returns
    -------
    w_R : float
        Population variance of ``E(alpha, lambda1*, lambda2*, beta*)`` over ``alpha`` uniform in ``[0, pi/2)``.
    w_S : float
        Population variance of ``E(alpha*, lambda1, lambda2, beta)`` over uniform ``(lambda1, lambda2, beta)``.
    evaluations : int
        ``rotation_samples + stretch_samples``.

    References
    ----------
    Sun et al. 2022, Eq. 17.
    """
    params = np.asarray(params, dtype=np.float64).reshape(4)
    if rotation_samples < 2 or stretch_samples < 2:
        raise ValueError("a variance needs at least 2 samples per weight")
    alpha = (np.arange(rotation_samples) + 0.5) * (_QUARTER / rotation_samples)
    rotations = np.column_stack([alpha, np.tile(params[1:], (rotation_samples, 1))])
    stretches = np.column_stack([np.full(stretch_samples, params[0]), _stretch_samples(lambda_min,
                                                                                       stretch_samples)])
    losses = np.asarray(problem.evaluate(np.vstack([rotations, stretches])), dtype=np.float64)
    return (float(np.var(losses[:rotation_samples])), float(np.var(losses[rotation_samples:])),
            rotation_samples + stretch_samples)


def _check_options(epsilon, evaluations, lambda_min, formulation, backend):
    if not 0 < epsilon < 1:
        raise ValueError(f"epsilon must be in (0, 1), got {epsilon}")
    if int(evaluations) != evaluations or evaluations < 2:
        raise ValueError(f"evaluations must be an integer >= 2, got {evaluations}")
    if not 0 < lambda_min < 1:
        raise ValueError(f"lambda_min must be in (0, 1), got {lambda_min}")
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")
    formulation = formulation or ("constrained" if backend == "fast" else "barrier")
    if formulation not in _FORMULATIONS:
        raise ValueError(f"formulation must be one of {_FORMULATIONS}, got {formulation!r}")
    if backend == "skopt" and formulation != "barrier":
        raise ValueError("the skopt backend runs the paper's barrier formulation only")
    return formulation


def _polish(loss, best, epsilon, lambda_min, evaluations):
    """Bisection on lambda1 and on lambda2 alone from the best feasible point, two evaluations a round.

    Bayesian optimization with a stationary GP finds thin feasible sets (aligned stripes: only
    ``alpha ~ 0``, ``beta ~ 0``, ``lambda1 ~ 1`` pass, any ``lambda2``) but rarely walks along them; shrinking
    one eigenvalue at a time is the walk. Each coordinate keeps a bracket ``[low, high]`` (``high`` feasible)
    and tries the geometric midpoint.
    """
    best = np.array(best, dtype=np.float64)
    low = np.array([lambda_min, lambda_min])
    for _ in range(evaluations // 2):
        high = best[1:3]
        if np.all(high <= low * (1 + 1e-3)):
            break
        trial = np.tile(best, (2, 1))
        middle = np.sqrt(low * high)
        trial[0, 1], trial[1, 2] = middle[0], middle[1]
        within = loss(trial) <= epsilon
        cost = trial[:, 1] * trial[:, 2]
        for k in (0, 1):
            if not within[k]:
                low[k] = middle[k]
        if within.any():
            best = trial[int(np.argmin(np.where(within, cost, np.inf)))]
    return best


def optimize_triangle(problem, *, epsilon=0.01, evaluations=100, lambda_min=LAMBDA_MIN, formulation=None,
                      backend="fast", seed=0, weights=True, polish_evaluations=None, patience=PATIENCE,
                      patience_improvement=PATIENCE_IMPROVEMENT):
    """Optimal deformation of one triangle (Eq. 7 / 12-14) and its sensitivity weights (Eq. 17).

    Parameters
    ----------
    problem : TriangleProblem
        ``problem.evaluate((k, 4)) -> (k,)`` gives E; ``problem.uv_area`` (texels) and ``problem.is_constant``
        are used too.
    epsilon : float, optional
        Loss bound (the paper: 0.01).
    evaluations : int, optional
        Loss evaluations of the optimization (the paper: 100); the weights add
        ``ROTATION_SAMPLES + STRETCH_SAMPLES``. The constrained form may stop earlier (optimal corner, or
        ``patience``).
    polish_evaluations : int, optional
        Evaluations of the constrained form kept for the lambda bisection (default
        ``min(POLISH_EVALUATIONS, evaluations // 5)``).
    patience : int or None, optional
        The constrained form's Bayesian optimization hands over to the bisection once this many evaluations
        in a row cut the smallest feasible area by less than a fraction ``patience_improvement`` (defaults
        :data:`PATIENCE` and :data:`PATIENCE_IMPROVEMENT`; None spends the whole budget).
    patience_improvement : float, optional
        In [0, 1); 0 lets any smaller feasible area keep the search going.
    lambda_min : float, optional
        Lower bound of ``lambda1, lambda2``.
    formulation : {"constrained", "barrier"}, optional
        See the module notes; default "constrained" for the fast backend, "barrier" for skopt.
    backend : {"fast", "skopt"}, optional
        Bayesian optimization engine (:mod:`.bayesopt`).
    seed : int, optional
    weights : bool, optional
        Compute ``w_R, w_S`` (otherwise NaN, no extra evaluations).

    Returns
    -------
    TriangleOptimum

    References
    ----------
    Sun et al. 2022, Eq. 7, 12-14, 17.
    """
    formulation = _check_options(epsilon, evaluations, lambda_min, formulation, backend)
    identity = _IDENTITY
    corner = np.array([0.0, lambda_min, lambda_min, 0.0])
    if problem.is_constant:
        return TriangleOptimum(corner, 0.0, 0.0, 0.0, 0, True)
    seen_params, seen_loss = [], []

    def loss(params):
        values = np.asarray(problem.evaluate(params), dtype=np.float64)
        if not np.isfinite(values).all():
            raise LossNotEvaluableError(f"face {problem.face}: E is not finite at some deformations of the box")
        seen_params.append(np.array(params, dtype=np.float64))
        seen_loss.append(values)
        return values

    bounds = _bounds(lambda_min)
    periodic = [True, False, False, False]
    if formulation == "constrained":
        offset = 0.1 * epsilon
        polish = min(POLISH_EVALUATIONS, evaluations // 5) if polish_evaluations is None else polish_evaluations
        found = bayesopt.minimize_constrained(
            lambda P: P[:, 1] * P[:, 2], lambda P: np.log(loss(P) + offset), bounds,
            threshold=math.log(epsilon + offset), evaluations=evaluations - polish, x0=np.vstack([identity, corner]),
            periodic=periodic, cost_lower_bound=lambda_min * lambda_min, patience=patience,
            min_improvement=patience_improvement, seed=seed)
        if found.feasible and found.fun > lambda_min * lambda_min * (1 + 1e-9):
            _polish(loss, found.x, epsilon, lambda_min, polish)
    else:
        area = float(problem.uv_area)

        def objective(P):
            return P[:, 1] * P[:, 2] * area + finite_barrier(loss(P), epsilon)

        bayesopt.minimize(objective, bounds, evaluations=evaluations, x0=identity[None, :],
                          periodic=periodic if backend == "fast" else None, seed=seed, backend=backend)
    params = np.vstack(seen_params)
    losses = np.concatenate(seen_loss)
    feasible = losses <= epsilon
    if feasible.any():
        criterion = (params[:, 1] * params[:, 2] if formulation == "constrained"
                     else _barrier_objective(params, losses, float(problem.uv_area), epsilon))
        best = int(np.flatnonzero(feasible)[np.argmin(criterion[feasible])])
    else:
        best = int(np.argmin(losses))
    w_R = w_S = math.nan
    used = len(losses)
    if weights:
        w_R, w_S, extra = sensitivity_weights(problem, params[best], lambda_min=lambda_min)
        used += extra
    return TriangleOptimum(params[best].copy(), float(losses[best]), w_R, w_S, used, bool(feasible[best]))


# ---------------------------------------------------------------------------------------------------- many
def _face_seed(seed, face):
    return int(np.random.SeedSequence([int(seed), int(face)]).generate_state(1)[0])


def _optimize_chunk(state, faces):
    """Worker body: prepare the chunk's problems once, optimize each face. Returns plain arrays."""
    options = state["options"]
    rows = []
    for face, problem in zip(faces, _prepared(state, faces)):
        try:
            found = optimize_triangle(problem, epsilon=options["epsilon"], evaluations=options["evaluations"],
                                      lambda_min=options["lambda_min"], formulation=options["formulation"],
                                      backend=options["backend"], seed=_face_seed(options["seed"], face))
        except (ArithmeticError, np.linalg.LinAlgError):
            # One triangle whose loss cannot be evaluated must not end the run: it keeps its input shape and
            # is counted (TrianglewiseResult.unevaluated).
            rows.append((_IDENTITY.copy(), math.nan, 0.0, 0.0, 0, False, False, True))
            continue
        rows.append((found.params, found.loss, found.w_R, found.w_S, found.evaluations, found.feasible,
                     bool(problem.is_constant), False))
    return np.asarray(faces), rows


class LossNotEvaluableError(ArithmeticError):
    """The perceptual loss E of a triangle came out NaN or infinite for a deformation of the box."""


def iter_optimize_triangles(V, F, uv, luma, *, epsilon=0.01, evaluations=100, screen_pixels=64,
                            max_screen_pixels=MAX_SCREEN_PIXELS, lambda_min=LAMBDA_MIN, formulation=None,
                            backend="fast", workers=0, seed=0, faces=None, chunk_size=16, view_faces="window",
                            scheduler=None, known=None, checkpoint=None):
    """Generator form of :func:`optimize_triangles`: yields ``(done, total)`` faces, returns the result.

    Use ``result = yield from iter_optimize_triangles(...)`` in a pipeline generator, or drive it one step per
    timer tick in a modal operator; closing the generator stops the worker processes.
    """
    formulation = _check_options(epsilon, evaluations, lambda_min, formulation, backend)
    _check_view_faces(view_faces)
    if int(workers) != workers or workers < 0:
        raise ValueError(f"workers must be an integer >= 0, got {workers}")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    V, F, uv, luma, faces = _check_mesh(V, F, uv, luma, faces)
    total = len(faces)
    row_of = {int(face): row for row, face in enumerate(faces)}
    params = np.empty((total, 4))
    loss, w_R, w_S = np.empty(total), np.empty(total), np.empty(total)
    used = np.zeros(total, np.int64)
    feasible, constant, unevaluated = np.zeros(total, bool), np.zeros(total, bool), np.zeros(total, bool)
    columns = (params, loss, w_R, w_S, used, feasible, constant, unevaluated)
    finished = np.zeros(total, bool)
    if known is not None:
        _check_known(known, epsilon, lambda_min, formulation, backend)
        rows = np.array([row_of.get(int(face), -1) for face in known.faces], dtype=np.int64)
        kept = rows >= 0
        for column, values in zip(columns, _result_columns(known)):
            column[rows[kept]] = values[kept]
        finished[rows[kept]] = True

    def result(rows=slice(None)):
        return TrianglewiseResult(faces[rows], *(column[rows] for column in columns[:-1]), float(epsilon),
                                  float(lambda_min), formulation, backend, unevaluated[rows])

    remaining = faces[~finished]
    done = total - len(remaining)
    yield done, total
    if not len(remaining):
        return result()
    options = {"epsilon": float(epsilon), "evaluations": int(evaluations), "lambda_min": float(lambda_min),
               "formulation": formulation, "backend": backend, "seed": int(seed)}
    state = yield from report_while_waiting(_iter_state(V, F, uv, luma, remaining, screen_pixels, max_screen_pixels,
                                                        options, view_faces), (done, total))
    saved = time.monotonic()
    with contextlib.closing(run_chunks(_optimize_chunk, state, remaining, workers=int(workers),
                                       chunk_size=int(chunk_size), scheduler=scheduler)) as chunks:
        for item in chunks:
            if item is None:
                yield done, total
                continue
            chunk, rows = item
            for face, row in zip(chunk, rows):
                i = row_of[int(face)]
                for column, value in zip(columns, row):
                    column[i] = value
                finished[i] = True
            done += len(chunk)
            if checkpoint is not None and done < total and time.monotonic() - saved >= CHECKPOINT_SECONDS:
                checkpoint(result(finished.copy()))
                saved = time.monotonic()
            yield done, total
    return result()


def _result_columns(result):
    """The per-face arrays of a :class:`TrianglewiseResult`, in the order a worker returns a face's row."""
    return (result.params, result.loss, result.w_R, result.w_S, result.evaluations, result.feasible,
            result.is_constant, result.unevaluated)


def _check_known(known, epsilon, lambda_min, formulation, backend):
    """Refuse earlier results made under other settings (what the result itself records)."""
    theirs = (float(known.epsilon), float(known.lambda_min), str(known.formulation), str(known.backend))
    ours = (float(epsilon), float(lambda_min), formulation, backend)
    if theirs != ours:
        raise ValueError(f"known results were made with (epsilon, lambda_min, formulation, backend) = {theirs}, "
                         f"not {ours}")


def optimize_triangles(V, F, uv, luma, *, epsilon=0.01, evaluations=100, screen_pixels=64,
                       max_screen_pixels=MAX_SCREEN_PIXELS, lambda_min=LAMBDA_MIN, formulation=None, backend="fast",
                       workers=0, seed=0, faces=None, chunk_size=16, progress=None, view_faces="window",
                       scheduler=None, known=None, checkpoint=None):
    """Triangle-wise stage: optimal deformation and sensitivity weights of every triangle.

    Parameters
    ----------
    V : (n, 3) array_like of float64
    F : (m, 3) array_like of int64
    uv : (m, 3, 2) array_like of float64
        Input per-corner UVs.
    luma : (h, w) or (h, w, c) array_like in [0, 1], or sequence of (h_i, w_i) ndarrays
        Texture, row 0 = bottom; colour is reduced to Rec. 601 luma. A sequence is a stack of planes, each at its
        own resolution (:func:`.loss_planes.loss_planes` builds one from a material's maps): a triangle's E is
        the largest of its planes' (:class:`.loss_planes.StackProblem`), the parameters act in the first
        plane's texel frame, and each view gets one pixel per texel of the densest plane.
    epsilon : float, optional
        Bound on the per-triangle perceptual loss (GMSD), the paper's 0.01.
    evaluations : int, optional
        Loss evaluations of the optimization per triangle (the paper: 100); the weights add 24.
    screen_pixels : int, optional
        Side of the per-triangle view (App. A: 64).
    max_screen_pixels : int, optional
        A triangle spanning more input texels than ``screen_pixels`` across its view gets one pixel per texel,
        up to this side (:func:`.camera.texel_matched_pixels`); ``screen_pixels`` or less keeps App. A's fixed
        size: ``screen_pixels=64, max_screen_pixels=64`` gives every view App. A's 64 x 64 px (the side is
        ``clip(t, 64, max(64, 64)) = 64``), with App. A's window (:func:`.camera.triangle_cameras`).
    lambda_min : float, optional
        Lower bound of the stretch eigenvalues.
    formulation : {"constrained", "barrier"}, optional
        See the module notes.
    backend : {"fast", "skopt"}, optional
        Bayesian optimization engine; "skopt" is the paper's setting (~15 s per triangle).
    workers : int, optional
        Worker processes; 0 = one per core, 1 = in this process.
    seed : int, optional
        Results depend only on the seed, not on ``workers`` or ``chunk_size``.
    faces : (k,) array_like of int, optional
        Optimize only these faces (rows of the result follow this order).
    chunk_size : int, optional
        Faces per task (and per progress step).
    progress : callable, optional
        Called as ``progress(done, total)``.
    view_faces : {"window", "one_ring"}, optional
        Each view (:func:`.loss.prepare_triangles`): ``"window"`` (default) the one-ring and the faces connected
        to it that reach into the window, drawn in the triangle's box and band; ``"one_ring"`` the triangle and
        its one-ring only, in App. A's whole square turned towards the first corner. See the module notes for
        the paper's settings as a whole.
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``): the chunks run as tasks of that cluster, every
        worker of it at once (``workers`` is then unused). The cluster's workers need this package and its
        dependencies; the results are those of a local run with the same seed.
    known : TrianglewiseResult, optional
        Results of some of the faces from an earlier run with the same mesh, texture and settings (a
        ``checkpoint`` of a run cut off): their rows are taken as they are and only the other faces are
        optimized. Since a face's result depends only on the seed, the result is that of one uninterrupted run.
        Its epsilon, lambda_min, formulation and backend must be these.
    checkpoint : callable, optional
        Called as ``checkpoint(partial)`` with the :class:`TrianglewiseResult` of the faces done so far, at most
        every :data:`CHECKPOINT_SECONDS` and never with every face done; pass what it keeps as ``known`` to
        resume.

    Returns
    -------
    TrianglewiseResult

    References
    ----------
    Sun et al. 2022, Sec. 4.1, Eq. 7, 12-14, 17, App. A.
    """
    stage = iter_optimize_triangles(V, F, uv, luma, epsilon=epsilon, evaluations=evaluations,
                                    screen_pixels=screen_pixels, max_screen_pixels=max_screen_pixels,
                                    lambda_min=lambda_min, formulation=formulation,
                                    backend=backend, workers=workers, seed=seed, faces=faces,
                                    chunk_size=chunk_size, view_faces=view_faces, scheduler=scheduler,
                                    known=known, checkpoint=checkpoint)
    return run_generator(stage, progress)
