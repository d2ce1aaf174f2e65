"""Bayesian optimization of small box-constrained black-box problems (the engine of Sec. 4.1.2).

The paper minimizes Eq. 14 per triangle with a Gaussian-process Bayesian optimizer [CCAM18] and 100
evaluations. scikit-optimize's ``gp_minimize`` does that exactly but costs ~15 s per 4-D problem here, almost
all of it GP overhead. The default engine below keeps the same ingredients (Matern 5/2 kernel with one length
scale per dimension, expected improvement) and removes the overhead:

- inputs are mapped to the unit cube; the GP works on standardized targets with the signal variance profiled
  out of the marginal likelihood, so the Cholesky factor ``L`` of ``C + eta I`` depends on inputs only;
- hyper-parameters (log length scales, log noise ``eta``) are fitted by L-BFGS-B on the exact gradient of the
  profiled log marginal likelihood, only at a few points of the run (after the initial design, then each time
  the number of observations doubles);
- between fits every new observation extends ``L`` by one row (forward substitution, O(n^2));
- the acquisition is evaluated on a vectorized candidate batch (uniform + Gaussian perturbations around the
  incumbents), the best candidate is refined by two rounds of local perturbations, and ``batch_size`` points
  are chosen per round with the kriging believer: a pending point with the posterior mean as its fantasy
  value leaves the mean unchanged and only lowers the variance, an O(n c) update of the candidates;
- the objective is called once per round with all ``batch_size`` points (batched evaluation);
- kernel matrix, posterior and the likelihood gradient are numba kernels, each with a numpy reference.

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
import scipy.optimize
import scipy.stats.qmc

from ._jit import njit

__all__ = ["BayesOptResult", "minimize", "minimize_constrained"]

_SQRT5 = math.sqrt(5.0)
_LOG_LENGTH_BOUNDS = (math.log(0.02), math.log(5.0))
_LOG_NOISE_BOUNDS = (math.log(1e-6), math.log(1e-1))


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
# Kernels: numba versions and the numpy references they are tested against.


@njit
def _scaled_difference(a, b, inv_length, periodic):
    """Per-dimension difference over length scale; periodic dims (period 1) use the chordal distance."""
    if periodic:
        return math.sin(math.pi * (a - b)) / math.pi * inv_length
    return (a - b) * inv_length


@njit
def _matern52_numba(A, B, inv_length, periodic):
    na, nb, d = A.shape[0], B.shape[0], A.shape[1]
    K = np.empty((na, nb))
    for i in range(na):
        for j in range(nb):
            r2 = 0.0
            for k in range(d):
                t = _scaled_difference(A[i, k], B[j, k], inv_length[k], periodic[k])
                r2 += t * t
            r = math.sqrt(5.0 * r2)
            K[i, j] = (1.0 + r + r * r / 3.0) * math.exp(-r)
    return K


def _matern52_numpy(A, B, inv_length, periodic):
    diff = A[:, None, :] - B[None, :, :]
    diff = np.where(periodic, np.sin(np.pi * diff) / np.pi, diff) * inv_length
    r = np.sqrt(5.0 * np.sum(diff * diff, axis=-1))
    return (1.0 + r + r * r / 3.0) * np.exp(-r)


@njit
def _cholesky_append_numba(L, n, k_new, diagonal):
    """Extend the factor ``L[:n, :n]`` by the row of a new point; returns the new diagonal entry."""
    for i in range(n):
        s = k_new[i]
        for j in range(i):
            s -= L[i, j] * L[n, j]
        L[n, i] = s / L[i, i]
    s = diagonal
    for j in range(n):
        s -= L[n, j] * L[n, j]
    # The noise term keeps the exact value >= eta > 0; the floor only guards rounding.
    L[n, n] = math.sqrt(max(s, 1e-12))
    return L[n, n]


def _cholesky_append_numpy(L, n, k_new, diagonal):
    import scipy.linalg

    row = scipy.linalg.solve_triangular(L[:n, :n], k_new, lower=True) if n else np.empty(0)
    L[n, :n] = row
    L[n, n] = math.sqrt(max(diagonal - row @ row, 1e-12))
    return L[n, n]


@njit
def _log_likelihood_numba(X, y, log_length, log_noise, periodic):
    """Profiled log marginal likelihood and its gradient w.r.t. (log length scales..., log noise)."""
    n, d = X.shape
    inv_length = np.exp(-log_length)
    noise = math.exp(log_noise)
    scaled = np.empty((n, n, d))
    Cm = np.empty((n, n))
    G = np.empty((n, n))  # dk/dr^2-style factor shared by every length-scale derivative
    for i in range(n):
        for j in range(n):
            r2 = 0.0
            for k in range(d):
                t = _scaled_difference(X[i, k], X[j, k], inv_length[k], periodic[k])
                scaled[i, j, k] = t * t
                r2 += t * t
            r = math.sqrt(5.0 * r2)
            e = math.exp(-r)
            Cm[i, j] = (1.0 + r + r * r / 3.0) * e
            G[i, j] = 5.0 / 3.0 * (1.0 + r) * e
        Cm[i, i] += noise
    L = np.linalg.cholesky(Cm)
    Linv = np.linalg.inv(L)
    Cinv = Linv.T @ Linv
    alpha = Cinv @ y
    signal = (y @ alpha) / n
    logdet = 0.0
    for i in range(n):
        logdet += math.log(L[i, i])
    value = -0.5 * n * math.log(signal) - logdet - 0.5 * n * (1.0 + math.log(2.0 * math.pi))
    # d value / d theta = 1/2 tr((alpha alpha^T / s^2 - C^-1) dC/dtheta)
    gradient = np.zeros(d + 1)
    for i in range(n):
        for j in range(n):
            a = alpha[i] * alpha[j] / signal - Cinv[i, j]
            for k in range(d):
                gradient[k] += 0.5 * a * G[i, j] * scaled[i, j, k]
        gradient[d] += 0.5 * noise * (alpha[i] * alpha[i] / signal - Cinv[i, i])
    return value, gradient


def _log_likelihood_numpy(X, y, log_length, log_noise, periodic):
    n, d = X.shape
    inv_length = np.exp(-log_length)
    noise = math.exp(log_noise)
    diff = X[:, None, :] - X[None, :, :]
    diff = np.where(periodic, np.sin(np.pi * diff) / np.pi, diff) * inv_length
    scaled = diff * diff
    r = np.sqrt(5.0 * scaled.sum(-1))
    C = (1.0 + r + r * r / 3.0) * np.exp(-r) + noise * np.eye(n)
    L = np.linalg.cholesky(C)
    Cinv = np.linalg.inv(C)
    alpha = Cinv @ y
    signal = y @ alpha / n
    value = -0.5 * n * np.log(signal) - np.log(np.diag(L)).sum() - 0.5 * n * (1.0 + np.log(2.0 * np.pi))
    A = np.outer(alpha, alpha) / signal - Cinv
    dC = (5.0 / 3.0 * (1.0 + r) * np.exp(-r))[:, :, None] * scaled
    gradient = np.append(0.5 * np.einsum("ij,ijk->k", A, dC), 0.5 * noise * np.trace(A))
    return value, gradient


@njit
def _append_rows_numba(V, squares, L, X, start, stop, C, inv_length, periodic):
    """Rows ``start..stop-1`` of ``V = L^-1 K(X, C)`` and their squares added to ``squares`` (O(n c) a row)."""
    c, d = C.shape
    for p in range(start, stop):
        for j in range(c):
            r2 = 0.0
            for k in range(d):
                t = _scaled_difference(X[p, k], C[j, k], inv_length[k], periodic[k])
                r2 += t * t
            r = math.sqrt(5.0 * r2)
            s = (1.0 + r + r * r / 3.0) * math.exp(-r)
            for i in range(p):
                s -= L[p, i] * V[i, j]
            s /= L[p, p]
            V[p, j] = s
            squares[j] += s * s


def _append_rows_numpy(V, squares, L, X, start, stop, C, inv_length, periodic):
    for p in range(start, stop):
        k = _matern52_numpy(X[p:p + 1], C, inv_length, periodic)[0]
        V[p] = (k - L[p, :p] @ V[:p]) / L[p, p]
        squares += V[p] ** 2


@njit
def _leading_dot_numba(V, w):
    """``V[:len(w)].T @ w`` without BLAS (small, called often; BLAS threads only add latency here)."""
    c = V.shape[1]
    out = np.zeros(c)
    for i in range(w.shape[0]):
        wi = w[i]
        for j in range(c):
            out[j] += V[i, j] * wi
    return out


@njit
def _forward_substitute_numba(L, b):
    n = b.shape[0]
    x = np.empty(n)
    for i in range(n):
        s = b[i]
        for j in range(i):
            s -= L[i, j] * x[j]
        x[i] = s / L[i, i]
    return x


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
def _acquisition_numba(V, squares, w, signal, kind, best, parameter, log_improvement):
    """Scores (higher is better) of candidates from ``V = L^-1 K(X, C)`` and its column sums of squares.

    ``kind``: log expected improvement below ``best - parameter`` (standardized units); negative lower
    confidence bound ``-(mean - parameter * std)``; log probability that the GP lies below ``best``
    (feasibility); or ``log_improvement`` plus that log probability (expected feasible improvement).
    """
    c = V.shape[1]
    n_observed = w.shape[0]
    out = np.empty(c)
    for j in range(c):
        mean = 0.0
        for i in range(n_observed):
            mean += V[i, j] * w[i]
        std = math.sqrt(max(1.0 - squares[j], 1e-12) * signal)
        if kind == _EI:
            out[j] = _log_ei_ratio_numba((best - parameter - mean) / std) + math.log(std)
        elif kind == _LCB:
            out[j] = -(mean - parameter * std)
        elif kind == _FEASIBILITY:
            out[j] = _log_normal_cdf_numba((best - mean) / std)
        else:
            out[j] = log_improvement[j] + _log_normal_cdf_numba((best - mean) / std)
    return out


def _acquisition_numpy(V, squares, w, signal, kind, best, parameter, log_improvement):
    from scipy.special import log_ndtr

    mean = V[:len(w)].T @ w
    std = np.sqrt(np.maximum(1.0 - squares, 1e-12) * signal)
    if kind == _EI:
        z = (best - parameter - mean) / std
        with np.errstate(divide="ignore"):
            return np.log(z * np.exp(log_ndtr(z)) + np.exp(-0.5 * z * z - _LOG_SQRT_2PI)) + np.log(std)
    if kind == _LCB:
        return -(mean - parameter * std)
    log_feasible = log_ndtr((best - mean) / std)
    return log_feasible if kind == _FEASIBILITY else log_improvement + log_feasible


# ----------------------------------------------------------------------------------------------------------
# The Gaussian process state.


class _GaussianProcess:
    """GP on the unit cube with incremental Cholesky updates (see the module docstring)."""

    def __init__(self, dims, capacity, periodic):
        self.dims = dims
        self.periodic = periodic
        self.X = np.empty((capacity, dims))
        self.y = np.empty(capacity)
        self.L = np.zeros((capacity, capacity))
        self.n = 0
        self.log_length = np.full(dims, math.log(0.3))
        self.log_noise = math.log(1e-4)
        self.offset = 0.0
        self.scale = 1.0
        self.w = np.empty(0)
        self.signal = 1.0

    @property
    def inv_length(self):
        return np.exp(-self.log_length)

    def add(self, x, v=None):
        """Append input ``x`` (target set later); ``v = L^-1 k(X, x)`` when already known."""
        n = self.n
        if v is None:
            k = _matern52_numba(self.X[:n], x[None, :], self.inv_length, self.periodic)[:, 0]
            _cholesky_append_numba(self.L, n, k, 1.0 + math.exp(self.log_noise))
        else:
            self.L[n, :n] = v
            self.L[n, n] = math.sqrt(max(1.0 + math.exp(self.log_noise) - v @ v, 1e-12))
        self.X[n] = x
        self.n = n + 1

    def set_targets(self, y):
        n = self.n
        self.y[:n] = y
        self.offset = float(np.mean(y))
        spread = float(np.std(y))
        self.scale = spread if spread > 0 else 1.0
        standardized = (self.y[:n] - self.offset) / self.scale
        self.w = _forward_substitute_numba(self.L[:n, :n], standardized)
        self.signal = max(float(self.w @ self.w) / n, 1e-12)

    def refactor(self):
        n = self.n
        C = _matern52_numba(self.X[:n], self.X[:n], self.inv_length, self.periodic)
        C[np.diag_indices(n)] += math.exp(self.log_noise)
        self.L[:n, :n] = np.linalg.cholesky(C)

    def fit(self, *, max_iterations=30):
        """Maximize the profiled log marginal likelihood over log length scales and log noise."""
        n = self.n
        X = np.ascontiguousarray(self.X[:n])
        y = (self.y[:n] - self.offset) / self.scale

        def negative(theta):
            value, gradient = _log_likelihood_numba(X, y, theta[:-1], theta[-1], self.periodic)
            return -value, -gradient

        start = np.append(self.log_length, self.log_noise)
        bounds = [_LOG_LENGTH_BOUNDS] * self.dims + [_LOG_NOISE_BOUNDS]
        try:
            found = scipy.optimize.minimize(negative, start, jac=True, method="L-BFGS-B", bounds=bounds,
                                            options={"maxiter": max_iterations})
            theta = found.x if np.all(np.isfinite(found.x)) else start
        except np.linalg.LinAlgError:
            theta = start
        self.log_length = theta[:-1].copy()
        self.log_noise = float(theta[-1])
        self.refactor()
        self.set_targets(self.y[:n])


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
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name} returned a non-finite value; the GP needs finite observations")
    return values


class _Candidates:
    """Candidate points with ``V = L^-1 K(X, C)`` kept in step with the GP by appending one row per point."""

    def __init__(self, gp, C, cost=None):
        self.C = np.ascontiguousarray(C)
        self.cost = None if cost is None else cost(self.C)
        self.V = np.empty((gp.X.shape[0], len(C)))
        self.squares = np.zeros(len(C))
        self.rows = 0
        self.sync(gp)

    def sync(self, gp):
        """Append the rows of points added to ``gp`` since the last call (O(n c) each)."""
        if self.rows < gp.n:
            _append_rows_numba(self.V, self.squares, gp.L, gp.X, self.rows, gp.n, self.C, gp.inv_length,
                               gp.periodic)
            self.rows = gp.n

    def recompute(self, gp):
        """Start over after the hyper-parameters (hence ``L``) changed."""
        self.squares[:] = 0.0
        self.rows = 0
        self.sync(gp)


@dataclasses.dataclass
class _Acquisition:
    """What the search maximizes this round: kind, target level in standardized units, parameter."""

    kind: int
    best: float
    parameter: float = 0.0
    best_cost: float = np.inf  # expected feasible improvement: current best feasible cost

    def scores(self, candidates, gp):
        candidates.sync(gp)
        if self.kind == _FEASIBLE_IMPROVEMENT:
            with np.errstate(divide="ignore"):
                log_improvement = np.log(np.maximum(self.best_cost - candidates.cost, 0.0))
        else:
            log_improvement = candidates.squares  # unused by the other kinds
        return _acquisition_numba(candidates.V, candidates.squares, gp.w, gp.signal, self.kind, self.best,
                                  self.parameter, log_improvement)


class _Search:
    """Candidate generation, acquisition maximization and batch selection for one run.

    A fixed pool of uniform points is updated incrementally (one row per new observation) and recomputed only
    after a hyper-parameter fit; each round adds fresh Gaussian perturbations of the incumbents, and the best
    candidate of every pick is refined by rounds of smaller perturbations around it.
    """

    def __init__(self, gp, rng, periodic, *, candidates, local_candidates, cost=None, refinements=(0.1, 0.03),
                 refinement_points=24):
        self.gp = gp
        self.rng = rng
        self.periodic = periodic
        self.cost = cost
        self.pool = _Candidates(gp, rng.random((candidates, gp.dims)), cost)
        self.local_candidates = local_candidates
        self.refinements = refinements
        self.refinement_points = refinement_points

    def hyperparameters_changed(self):
        self.pool.recompute(self.gp)

    def _perturb(self, centres, count, scale):
        picks = centres[self.rng.integers(0, len(centres), size=count)]
        points = picks + self.rng.standard_normal((count, self.gp.dims)) * scale
        return np.where(self.periodic, np.mod(points, 1.0), np.clip(points, 0.0, 1.0))

    def select(self, acquisition, incumbents, batch_size):
        """Pick ``batch_size`` unit-cube points maximizing the acquisition, kriging believer for the batch."""
        gp = self.gp
        length = np.minimum(np.exp(gp.log_length), 1.0)
        local = _Candidates(gp, self._perturb(incumbents, self.local_candidates, 0.25 * length), self.cost)
        chosen = []
        for _ in range(batch_size):
            best_value, best_x = -np.inf, None
            for candidates in (self.pool, local):
                values = acquisition.scores(candidates, gp)
                j = int(np.argmax(values))
                if values[j] > best_value:
                    best_value, best_x = values[j], candidates.C[j]
            if best_x is None:  # no candidate can improve (every score -inf): explore uniformly
                best_x = self.rng.random(gp.dims)
            for radius in self.refinements:
                near = _Candidates(gp, self._perturb(best_x[None, :], self.refinement_points, radius * length),
                                   self.cost)
                values = acquisition.scores(near, gp)
                j = int(np.argmax(values))
                if values[j] > best_value:
                    best_value, best_x = values[j], near.C[j]
            chosen.append(best_x.copy())
            gp.add(best_x)
        return np.array(chosen)


def _initial_design(rng, dims, count):
    if count <= 0:
        return np.empty((0, dims))
    return scipy.stats.qmc.LatinHypercube(d=dims, seed=rng).random(count)


def _run(evaluate, plan, bounds, *, evaluations, initial_points, batch_size, x0, periodic, seed, candidates,
         local_candidates, fits, unit_cost=None, stop=None):
    """Shared loop: ``evaluate(unit_points) -> targets``; ``plan(gp) -> (_Acquisition, incumbents)``."""
    d = bounds.shape[0]
    rng = np.random.default_rng(seed)
    low, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    gp = _GaussianProcess(d, evaluations + batch_size, periodic)
    design = np.vstack([(x0 - low) / width, _initial_design(rng, d, max(initial_points - len(x0), 0))])
    design = design[:evaluations]
    targets = list(evaluate(design))
    for x in design:
        gp.add(x)
    gp.set_targets(np.asarray(targets))
    search = _Search(gp, rng, periodic, candidates=candidates, local_candidates=local_candidates, cost=unit_cost)
    next_fit, fits_left = gp.n, fits
    while gp.n < evaluations and not (stop is not None and stop()):
        if fits_left > 0 and gp.n >= next_fit:
            gp.fit()
            search.hyperparameters_changed()
            next_fit, fits_left = 2 * gp.n, fits_left - 1
        acquisition, incumbents = plan(gp)
        batch = search.select(acquisition, incumbents, min(batch_size, evaluations - gp.n))
        targets.extend(evaluate(batch))
        gp.set_targets(np.asarray(targets))
    return low + width * gp.X[:gp.n], np.asarray(targets)


def minimize(objective, bounds, *, evaluations=100, initial_points=10, batch_size=4, x0=None, periodic=None,
             acquisition="ei", xi=0.01, kappa=1.96, seed=0, backend="fast", candidates=1024, local_candidates=128,
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
                         x0=None, periodic=None, cost_lower_bound=None, seed=0, candidates=1024,
                         local_candidates=128, fits=3):
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

    reached = []

    def evaluate_and_check(unit_points):
        values = evaluate(unit_points)
        if cost_lower_bound is not None:
            tolerance = 1e-12 * max(1.0, abs(cost_lower_bound))
            reached.extend(np.asarray(costs[-len(values):])[values <= threshold] <= cost_lower_bound + tolerance)
        return values

    X, y = _run(evaluate_and_check, plan, bounds, evaluations=evaluations, initial_points=initial_points,
                batch_size=batch_size, x0=x0, periodic=periodic, seed=seed, candidates=candidates,
                local_candidates=local_candidates, fits=fits, unit_cost=unit_cost, stop=lambda: any(reached))
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
