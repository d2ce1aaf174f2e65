"""Bayesian optimization of small box-constrained black-box problems (the engine of Sec. 4.1.2).

The paper minimizes Eq. 14 per triangle with a Gaussian-process Bayesian optimizer [CCAM18] and 100
evaluations. scikit-optimize's ``gp_minimize`` does that exactly but costs ~15 s per 4-D problem here, almost
all of it GP overhead. The default engine below keeps the same ingredients (Matern 5/2 kernel with one length
scale per dimension, expected improvement) and removes the overhead:

- inputs are mapped to the unit cube, where a Gaussian process with incremental Cholesky updates
  (:mod:`.gaussian_process`) models the objective; its hyper-parameters are fitted only at a few points of the
  run (after the initial design, then each time the number of observations doubles) and between fits every new
  observation extends its factor ``L`` by one row;
- the acquisition is maximized over candidates: a fixed pool of uniform points, whose rows of
  ``V = L^-1 K(X, C)`` are appended one per observation (O(n c)) and recomputed only after a fit, plus fresh
  Gaussian perturbations of the incumbents at three scales each round (they stand in for a local
  refinement of the acquisition's maximizer);
- ``batch_size`` points are chosen per round with the kriging believer: a pending point with the posterior
  mean as its fantasy value leaves the mean unchanged and only lowers the variance, so each pick costs one
  O(n c) row update; one numba call selects the whole batch;
- the objective is called once per round with all ``batch_size`` points (batched evaluation);
- acquisition and batch selection are numba kernels, each with a numpy reference used in the tests.

``minimize`` is the unconstrained problem (``backend="skopt"`` runs scikit-optimize's ``gp_minimize`` with the
same budget and start point, the paper's setting). ``minimize_constrained`` solves ``min cost(x)`` subject to
``constraint(x) <= threshold`` for a cheap known cost and an expensive constraint (Gardner et al. 2014,
"Bayesian optimization with inequality constraints"): the acquisition is the exact improvement of the cost
times the GP probability that the constraint holds.

References
----------
Sun et al. 2022, Sec. 4.1.2, Eq. 12-14; [CCAM18] in the paper's bibliography.
"""
import dataclasses
import math

import numpy as np
import scipy.stats.qmc

from ._jit import njit
from .gaussian_process import _GaussianProcess, _append_rows_numba, _leading_dot_numba, _matern52_numpy

__all__ = ["BayesOptResult", "minimize", "minimize_constrained"]

REFIT_ITERATIONS = 20


@dataclasses.dataclass(frozen=True)
class BayesOptResult:
    """Outcome of one optimization.

    Attributes
    ----------
    x : (d,) ndarray
        Best point found (lowest objective; for a constrained run, lowest cost among feasible points, or the
        point with the lowest constraint value when none is feasible).
    fun : float
        Objective (or cost) at ``x``.
    X : (n, d) ndarray
        Every evaluated point, in evaluation order.
    y : (n,) ndarray
        Objective values at ``X`` (constraint values for a constrained run).
    feasible : bool
        Whether ``x`` satisfies the constraint (always True for an unconstrained run).
    evaluations : int
        ``n``, the number of black-box evaluations used.
    """

    x: np.ndarray
    fun: float
    X: np.ndarray
    y: np.ndarray
    feasible: bool
    evaluations: int


# ----------------------------------------------------------------------------------------------------------
# Acquisition functions (vectorized over candidates; log scale so that tiny values still rank).

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


_EI, _LCB, _FEASIBILITY, _FEASIBLE_IMPROVEMENT = 0, 1, 2, 3


@njit
def _log_normal_cdf_numba(z):
    if z > -30.0:
        return math.log(0.5 * math.erfc(-z / math.sqrt(2.0)))
    # Asymptotic series of the Mills ratio: Phi(z) ~ phi(z) / -z * (1 - 1/z^2 + 3/z^4).
    z2 = z * z
    return -0.5 * z2 - _LOG_SQRT_2PI - math.log(-z) + math.log(1.0 - 1.0 / z2 + 3.0 / (z2 * z2))


@njit
def _log_ei_ratio_numba(z):
    """``log(z Phi(z) + phi(z))``, the log expected improvement over a unit-variance normal."""
    if z > -20.0:
        cdf = 0.5 * math.erfc(-z / math.sqrt(2.0))
        pdf = math.exp(-0.5 * z * z - _LOG_SQRT_2PI)
        return math.log(max(z * cdf + pdf, 1e-300))
    # z Phi(z) + phi(z) = phi(z) (1/z^2 - 3/z^4 + 15/z^6 - ...) as z -> -inf.
    z2 = z * z
    return -0.5 * z2 - _LOG_SQRT_2PI + math.log(1.0 / z2 - 3.0 / (z2 * z2) + 15.0 / (z2 * z2 * z2))


@njit
def _scores_numba(mean, squares, signal, kind, best, parameter, cost, best_cost, taken):
    """Acquisition (higher is better) from the standardized mean and ``squares = |L^-1 k(X, c)|^2``.

    ``kind``: log expected improvement below ``best - parameter``; negative lower confidence bound
    ``-(mean - parameter * std)``; log probability that the GP lies below ``best`` (feasibility); or the log
    of the cost improvement ``best_cost - cost`` plus that log probability (expected feasible improvement).
    Taken candidates (already in the batch) score ``-inf``.
    """
    c = mean.shape[0]
    out = np.empty(c)
    for j in range(c):
        if taken[j]:
            out[j] = -np.inf
            continue
        std = math.sqrt(max(1.0 - squares[j], 1e-12) * signal)
        if kind == _EI:
            out[j] = _log_ei_ratio_numba((best - parameter - mean[j]) / std) + math.log(std)
        elif kind == _LCB:
            out[j] = -(mean[j] - parameter * std)
        elif kind == _FEASIBILITY:
            out[j] = _log_normal_cdf_numba((best - mean[j]) / std)
        else:
            improvement = best_cost - cost[j]
            if improvement <= 0.0:
                out[j] = -np.inf
            else:
                out[j] = math.log(improvement) + _log_normal_cdf_numba((best - mean[j]) / std)
    return out


def _scores_numpy(mean, squares, signal, kind, best, parameter, cost, best_cost, taken):
    from scipy.special import log_ndtr

    std = np.sqrt(np.maximum(1.0 - squares, 1e-12) * signal)
    with np.errstate(divide="ignore"):
        if kind == _EI:
            z = (best - parameter - mean) / std
            out = np.log(z * np.exp(log_ndtr(z)) + np.exp(-0.5 * z * z - _LOG_SQRT_2PI)) + np.log(std)
        elif kind == _LCB:
            out = -(mean - parameter * std)
        else:
            out = log_ndtr((best - mean) / std)
            if kind == _FEASIBLE_IMPROVEMENT:
                out = out + np.log(np.maximum(best_cost - cost, 0.0))
    return np.where(taken, -np.inf, out)


@njit
def _select_batch_numba(q, X, L, n, noise, C, V, squares, mean, signal, inv_length, periodic, kind, best,
                        parameter, cost, best_cost):
    """Choose ``q`` candidates by the kriging believer; appends them to ``X``, ``L`` and the rows of ``V``.

    After a pick ``j``, its column ``V[:n, j]`` is the new row of ``L`` (it is ``L^-1 k(X, c_j)``), the
    diagonal is ``sqrt(1 + noise - squares[j])``, and one new row of ``V`` lowers every candidate's variance;
    the mean does not change (the fantasy target is the posterior mean). Returns the chosen indices.
    """
    c = C.shape[0]
    taken = np.zeros(c, np.bool_)
    chosen = np.empty(q, np.int64)
    for pick in range(q):
        scores = _scores_numba(mean, squares, signal, kind, best, parameter, cost, best_cost, taken)
        j = int(np.argmax(scores))
        chosen[pick] = j
        taken[j] = True
        for i in range(n):
            L[n, i] = V[i, j]
        L[n, n] = math.sqrt(max(1.0 + noise - squares[j], 1e-12))
        X[n] = C[j]
        _append_rows_numba(V, squares, L, X, n, n + 1, C, 0, c, inv_length, periodic)
        n += 1
    return chosen


def _select_batch_numpy(q, X, L, n, noise, C, V, squares, mean, signal, inv_length, periodic, kind, best,
                        parameter, cost, best_cost):
    """Reference: refactor the kernel matrix densely after each pick (no incremental updates)."""
    taken = np.zeros(len(C), bool)
    chosen = []
    points = X[:n].copy()
    for _ in range(q):
        K = _matern52_numpy(points, points, inv_length, periodic) + noise * np.eye(len(points))
        Ks = _matern52_numpy(points, C, inv_length, periodic)
        variance_drop = np.einsum("ij,ij->j", Ks, np.linalg.solve(K, Ks))
        scores = _scores_numpy(mean, variance_drop, signal, kind, best, parameter, cost, best_cost, taken)
        j = int(np.argmax(scores))
        chosen.append(j)
        taken[j] = True
        points = np.vstack([points, C[j]])
    return np.array(chosen)


# ----------------------------------------------------------------------------------------------------------
# The optimization loop shared by both problem forms.


def _validate_bounds(bounds):
    bounds = np.asarray(bounds, dtype=np.float64)
    if bounds.ndim != 2 or bounds.shape[1] != 2 or bounds.shape[0] < 1:
        raise ValueError(f"bounds must have shape (d, 2), got {bounds.shape}")
    if not np.all(np.isfinite(bounds)) or np.any(bounds[:, 1] <= bounds[:, 0]):
        raise ValueError(f"every bound needs finite low < high, got {bounds.tolist()}")
    return bounds


def _validate_common(bounds, evaluations, initial_points, batch_size, x0, periodic):
    bounds = _validate_bounds(bounds)
    d = bounds.shape[0]
    if evaluations < 1:
        raise ValueError(f"evaluations must be >= 1, got {evaluations}")
    if initial_points < 1:
        raise ValueError(f"initial_points must be >= 1, got {initial_points}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    x0 = np.empty((0, d)) if x0 is None else np.atleast_2d(np.asarray(x0, dtype=np.float64))
    if x0.shape[1] != d:
        raise ValueError(f"x0 rows must have {d} coordinates, got shape {x0.shape}")
    if np.any(x0 < bounds[:, 0]) or np.any(x0 > bounds[:, 1]):
        raise ValueError("x0 must lie inside the bounds")
    periodic = np.zeros(d, dtype=np.bool_) if periodic is None else np.asarray(periodic, dtype=np.bool_)
    if periodic.shape != (d,):
        raise ValueError(f"periodic must have one flag per dimension ({d}), got shape {periodic.shape}")
    return bounds, x0, periodic


def _call(function, points, name):
    values = np.asarray(function(points), dtype=np.float64).reshape(-1)
    if values.shape[0] != points.shape[0]:
        raise ValueError(f"{name} returned {values.shape[0]} values for {points.shape[0]} points")
    if not np.isfinite(values).all():
        raise ValueError(f"{name} returned a non-finite value; the GP needs finite observations")
    return values


@dataclasses.dataclass
class _Acquisition:
    """What a round maximizes: kind, target level (standardized units), parameter, best feasible cost."""

    kind: int
    best: float
    parameter: float = 0.0
    best_cost: float = np.inf


class _Search:
    """Candidates and batch selection for one run.

    Columns ``0..pool_size-1`` of ``C`` are a fixed uniform pool whose ``V`` rows are kept in step with the GP;
    the remaining columns are redrawn every round around the incumbents at three scales (fractions of the
    length scales) and computed afresh.
    """

    _SCALES = (0.3, 0.1, 0.03)

    def __init__(self, gp, rng, periodic, *, pool_size, local_size, cost=None):
        self.gp = gp
        self.rng = rng
        self.periodic = periodic
        self.pool_size = pool_size
        self.local_size = local_size
        self.cost_function = cost
        total = pool_size + local_size
        self.C = np.empty((total, gp.dims))
        self.C[:pool_size] = rng.random((pool_size, gp.dims))
        # A quarter of the pool lies on faces, edges and corners of the box, where constrained optima often are.
        on_faces = self.C[:pool_size // 4]
        snap = rng.random(on_faces.shape) < 0.3
        on_faces[snap] = np.round(on_faces[snap])
        self.cost = np.zeros(total)
        if cost is not None and pool_size:
            self.cost[:pool_size] = cost(self.C[:pool_size])
        self.V = np.empty((gp.X.shape[0], total))
        self.squares = np.zeros(total)
        self.pool_rows = 0
        self._step_scales = np.repeat(self._SCALES, -(-local_size // len(self._SCALES)))[:local_size, None]
        self._rows = np.arange(local_size)
        self._even = self._rows % 2 == 0

    def hyperparameters_changed(self):
        self.pool_rows = 0
        self.squares[:self.pool_size] = 0.0

    def _local_points(self, incumbents):
        """Gaussian steps from the incumbents; half of them move only a random subset of coordinates.

        Moving few coordinates at a time (as in DYCORS, Regis and Shoemaker 2013) reaches optima on faces and
        edges of the box and along thin axis-aligned ridges, which full-dimensional steps almost never hit.
        """
        count, d = self.local_size, self.gp.dims
        length = np.minimum(np.exp(self.gp.log_length), 1.0)
        # Half of the steps start from the best point, the rest from any incumbent.
        centres = incumbents[np.where(self._even, 0, self.rng.integers(0, len(incumbents), size=count))]
        step = self.rng.standard_normal((count, d)) * self._step_scales * length
        subset = self.rng.random((count, d)) < 1.0 / d
        subset[self._rows, self.rng.integers(0, d, size=count)] = True
        subset[: count // 2] = True
        points = centres + np.where(subset, step, 0.0)
        return np.where(self.periodic, np.mod(points, 1.0), np.minimum(np.maximum(points, 0.0), 1.0))

    def select(self, acquisition, incumbents, batch_size):
        """Append ``batch_size`` pending points to the GP and return them (unit cube)."""
        gp, n, P = self.gp, self.gp.n, self.pool_size
        inv_length = gp.inv_length
        if self.pool_rows < n:
            _append_rows_numba(self.V, self.squares, gp.L, gp.X, self.pool_rows, n, self.C, 0, P, inv_length,
                               self.periodic)
        if self.local_size:
            self.C[P:] = self._local_points(incumbents)
            if self.cost_function is not None:
                self.cost[P:] = self.cost_function(self.C[P:])
            self.squares[P:] = 0.0
            _append_rows_numba(self.V, self.squares, gp.L, gp.X, 0, n, self.C, P, len(self.C), inv_length,
                               self.periodic)
        mean = _leading_dot_numba(self.V, gp.w, len(self.C))
        chosen = _select_batch_numba(batch_size, gp.X, gp.L, n, math.exp(gp.log_noise), self.C, self.V,
                                     self.squares, mean, gp.signal, inv_length, self.periodic, acquisition.kind,
                                     acquisition.best, acquisition.parameter, self.cost, acquisition.best_cost)
        gp.n = self.pool_rows = n + batch_size
        return self.C[chosen].copy()


def _initial_design(rng, dims, count):
    if count <= 0:
        return np.empty((0, dims))
    return scipy.stats.qmc.LatinHypercube(d=dims, seed=rng).random(count)


def _run(evaluate, plan, bounds, *, evaluations, initial_points, batch_size, x0, periodic, seed, candidates,
         local_candidates, fits, unit_cost=None, stop=None):
    """Shared loop: ``evaluate(unit_points) -> targets``; ``plan(gp) -> (_Acquisition, incumbents)``.

    ``x0`` is evaluated first on its own, so ``stop()`` can end the run before the rest of the design.
    """
    d = bounds.shape[0]
    rng = np.random.default_rng(seed)
    low, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    gp = _GaussianProcess(d, evaluations + batch_size, periodic)
    stop = stop or (lambda: False)
    targets = []
    for design in ((x0 - low) / width, _initial_design(rng, d, max(initial_points - len(x0), 0))):
        design = design[:evaluations - gp.n]
        if not len(design) or (gp.n and stop()):
            continue
        targets.extend(evaluate(design))
        for x in design:
            gp.add(x)
    gp.set_targets(np.asarray(targets))
    search = _Search(gp, rng, periodic, pool_size=candidates, local_size=local_candidates, cost=unit_cost)
    next_fit, fits_left = gp.n, fits
    while gp.n < evaluations and not stop():
        if fits_left > 0 and gp.n >= next_fit:
            gp.fit(max_iterations=20 if fits_left == fits else REFIT_ITERATIONS)
            search.hyperparameters_changed()
            next_fit, fits_left = 2 * gp.n, fits_left - 1
        acquisition, incumbents = plan(gp)
        batch = search.select(acquisition, incumbents, min(batch_size, evaluations - gp.n))
        targets.extend(evaluate(batch))
        gp.set_targets(np.asarray(targets))
    return low + width * gp.X[:gp.n], np.asarray(targets)


def minimize(objective, bounds, *, evaluations=100, initial_points=10, batch_size=4, x0=None, periodic=None,
             acquisition="ei", xi=0.01, kappa=1.96, seed=0, backend="fast", candidates=256, local_candidates=64,
             fits=3):
    """Minimize an expensive function over a box by Gaussian-process Bayesian optimization.

    Parameters
    ----------
    objective : callable
        ``objective(points)`` with ``points`` of shape (k, d) returns k finite values; the fast backend calls
        it with ``batch_size`` points at a time (and once with the whole initial design).
    bounds : (d, 2) array_like
        ``(low, high)`` per dimension.
    evaluations : int, optional
        Total number of evaluations (the paper: 100 per triangle).
    initial_points : int, optional
        Size of the initial design, ``x0`` included; the rest is a Latin hypercube.
    batch_size : int, optional
        Points chosen per GP round (fast backend).
    x0 : (k, d) array_like, optional
        Points evaluated first (e.g. a known feasible point).
    periodic : (d,) array_like of bool, optional
        Dimensions whose objective is periodic with the box width as period (fast backend).
    acquisition : {"ei", "lcb"}, optional
        Expected improvement with margin ``xi`` (standardized units) or lower confidence bound
        ``mean - kappa * std``.
    seed : int, optional
        Fixes every random choice.
    backend : {"fast", "skopt"}, optional
        ``"skopt"`` runs ``skopt.gp_minimize`` with the same budget, initial points and ``x0``.
    candidates, local_candidates : int, optional
        Size of the fixed uniform candidate pool and number of incumbent-centred candidates drawn per round
        (fast backend).
    fits : int, optional
        Hyper-parameter fits per run: after the initial design, then each time the observations double.

    Returns
    -------
    BayesOptResult

    References
    ----------
    Sun et al. 2022, Sec. 4.1.2 (Bayesian optimization of Eq. 14).
    """
    if acquisition not in ("ei", "lcb"):
        raise ValueError(f"acquisition must be 'ei' or 'lcb', got {acquisition!r}")
    if backend not in ("fast", "skopt"):
        raise ValueError(f"backend must be 'fast' or 'skopt', got {backend!r}")
    bounds, x0, periodic = _validate_common(bounds, evaluations, initial_points, batch_size, x0, periodic)
    if backend == "skopt":
        return _minimize_skopt(objective, bounds, evaluations=evaluations, initial_points=initial_points, x0=x0,
                               acquisition=acquisition, xi=xi, kappa=kappa, seed=seed)
    low, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]

    def evaluate(unit_points):
        return _call(objective, low + width * unit_points, "objective")

    def plan(gp):
        standardized = (gp.y[:gp.n] - gp.offset) / gp.scale
        incumbents = gp.X[np.argsort(standardized, kind="stable")[:3]]
        if acquisition == "ei":
            return _Acquisition(_EI, float(standardized.min()), xi), incumbents
        return _Acquisition(_LCB, 0.0, kappa), incumbents

    X, y = _run(evaluate, plan, bounds, evaluations=evaluations, initial_points=initial_points,
                batch_size=batch_size, x0=x0, periodic=periodic, seed=seed, candidates=candidates,
                local_candidates=local_candidates, fits=fits)
    best = int(np.argmin(y))
    return BayesOptResult(x=X[best].copy(), fun=float(y[best]), X=X, y=y, feasible=True, evaluations=len(y))


def minimize_constrained(cost, constraint, bounds, *, threshold, evaluations=100, initial_points=10, batch_size=4,
                         x0=None, periodic=None, cost_lower_bound=None, patience=None, min_improvement=0.0, seed=0,
                         candidates=256, local_candidates=64, fits=3):
    """Minimize a cheap known cost subject to an expensive constraint ``constraint(x) <= threshold``.

    The GP models the constraint only; the acquisition is ``max(best_cost - cost(x), 0) * P(g(x) <= t)``, the
    expected feasible improvement (Gardner et al. 2014) with the improvement known exactly. Before any feasible
    point is found the acquisition is the probability of feasibility alone.

    Parameters
    ----------
    cost : callable
        ``cost(points)`` for points (k, d) returns k values; vectorized and cheap (called on candidates).
    constraint : callable
        ``constraint(points)`` for points (k, d) returns k finite values; the expensive black box.
    bounds : (d, 2) array_like
        ``(low, high)`` per dimension.
    threshold : float
        Feasibility bound on the constraint.
    evaluations : int, optional
        Maximum number of constraint evaluations.
    initial_points, batch_size, x0, periodic, seed, candidates, local_candidates, fits
        As in :func:`minimize`.
    cost_lower_bound : float, optional
        Known infimum of the cost over the box; the run stops early once a feasible point reaches it.
    patience : int, optional
        Stop once the last ``patience`` evaluations found no feasible point cheaper than ``1 - min_improvement``
        times the cheapest feasible cost before them (the feasible boundary is settled); until a feasible point
        is found the run goes on. By default the whole budget is used.
    min_improvement : float, optional
        In [0, 1). 0: any cheaper feasible point keeps the run going; above 0, a run whose last ``patience``
        evaluations cut the cheapest cost by less than that fraction has settled too.

    Returns
    -------
    BayesOptResult
        ``y`` holds the constraint values; ``fun`` is the cost at ``x``.

    References
    ----------
    Sun et al. 2022, Eq. 7 (the constrained problem Eq. 12-14 approximate with a barrier).
    """
    bounds, x0, periodic = _validate_common(bounds, evaluations, initial_points, batch_size, x0, periodic)
    threshold = float(threshold)
    low, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    costs = []

    def unit_cost(unit_points):
        return _call(cost, low + width * unit_points, "cost")

    def evaluate(unit_points):
        values = _call(constraint, low + width * unit_points, "constraint")
        costs.extend(unit_cost(unit_points))
        return values

    def best_feasible(gp):
        feasible = np.flatnonzero(gp.y[:gp.n] <= threshold)
        if not len(feasible):
            return None, feasible
        order = feasible[np.argsort(np.asarray(costs)[feasible], kind="stable")]
        return costs[order[0]], order

    def plan(gp):
        t = (threshold - gp.offset) / gp.scale
        best_cost, order = best_feasible(gp)
        if best_cost is None:
            return _Acquisition(_FEASIBILITY, t), gp.X[np.argsort(gp.y[:gp.n], kind="stable")[:3]]
        return _Acquisition(_FEASIBLE_IMPROVEMENT, t, best_cost=best_cost), gp.X[order[:3]]

    if patience is not None and (int(patience) != patience or patience < 1):
        raise ValueError(f"patience must be a positive whole number, got {patience}")
    if not 0.0 <= min_improvement < 1.0:
        raise ValueError(f"min_improvement must be in [0, 1), got {min_improvement}")
    reached = []
    cheapest = [np.inf]  # the cheapest feasible cost after 0, 1, 2, ... evaluations

    def evaluate_and_check(unit_points):
        values = evaluate(unit_points)
        new_costs = np.asarray(costs[-len(values):])
        for value, cost_value in zip(values, new_costs):
            cheapest.append(min(cheapest[-1], cost_value) if value <= threshold else cheapest[-1])
        if cost_lower_bound is not None:
            tolerance = 1e-12 * max(1.0, abs(cost_lower_bound))
            reached.extend(new_costs[values <= threshold] <= cost_lower_bound + tolerance)
        return values

    def stop():
        if any(reached):
            return True
        if patience is None or len(cheapest) <= patience:
            return False
        before = cheapest[-1 - patience]
        return bool(np.isfinite(before) and cheapest[-1] >= (1.0 - min_improvement) * before)

    X, y = _run(evaluate_and_check, plan, bounds, evaluations=evaluations, initial_points=initial_points,
                batch_size=batch_size, x0=x0, periodic=periodic, seed=seed, candidates=candidates,
                local_candidates=local_candidates, fits=fits, unit_cost=unit_cost, stop=stop)
    costs = np.asarray(costs)
    feasible = y <= threshold
    if feasible.any():
        index = int(np.flatnonzero(feasible)[np.argmin(costs[feasible])])
    else:
        index = int(np.argmin(y))
    return BayesOptResult(x=X[index].copy(), fun=float(costs[index]), X=X, y=y, feasible=bool(feasible.any()),
                          evaluations=len(y))


def _minimize_skopt(objective, bounds, *, evaluations, initial_points, x0, acquisition, xi, kappa, seed):
    import skopt

    def scalar(point):
        return float(_call(objective, np.asarray(point, dtype=np.float64)[None, :], "objective")[0])

    found = skopt.gp_minimize(scalar, [tuple(map(float, b)) for b in bounds], n_calls=evaluations,
                              n_initial_points=max(initial_points - len(x0), 0),
                              x0=[list(map(float, row)) for row in x0] or None,
                              acq_func="EI" if acquisition == "ei" else "LCB", xi=xi, kappa=kappa,
                              random_state=seed)
    X = np.asarray(found.x_iters, dtype=np.float64)
    y = np.asarray(found.func_vals, dtype=np.float64)
    best = int(np.argmin(y))
    return BayesOptResult(x=X[best].copy(), fun=float(y[best]), X=X, y=y, feasible=True, evaluations=len(y))
