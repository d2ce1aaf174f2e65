"""Gaussian process on the unit cube with incremental Cholesky updates: the surrogate of :mod:`.bayesopt`.

Matern 5/2 kernel with one length scale per dimension; a dimension marked periodic (period 1) uses the chordal
distance. The Bayesian optimizer refits and queries it every few evaluations, so its overhead is kept small:

- the GP works on standardized targets with the signal variance profiled out of the marginal likelihood, so the
  Cholesky factor ``L`` of ``C + eta I`` depends on inputs only;
- hyper-parameters (log length scales, log noise ``eta``) are fitted by L-BFGS-B on the exact gradient of the
  profiled log marginal likelihood, only when the optimizer asks (a few points of a run), with scipy's routine
  driven directly (:func:`_minimize_lbfgsb`: ``scipy.optimize.minimize``'s iterates without its overhead);
- between fits every new observation extends ``L`` by one row (forward substitution, O(n^2));
- the posterior at candidates ``C`` is read off the rows of ``V = L^-1 K(X, C)``, appended one per observation
  (O(n c)): the standardized mean is ``V^T w`` with ``w = L^-1 y``, the variance ``signal (1 - |V[:, j]|^2)``;
- kernel matrix, Cholesky update, candidate rows and the likelihood gradient are numba kernels, each with a
  numpy reference used in the tests.

References
----------
Sun et al. 2022, Sec. 4.1.2; [CCAM18] in the paper's bibliography.
"""
import math

import numpy as np
# The reverse-communication L-BFGS-B routine that scipy.optimize.minimize drives (private; scipy is pinned, and
# tests/test_bayesopt.py checks that _minimize_lbfgsb gives minimize's iterates bit for bit).
from scipy.optimize import _lbfgsb

from ._jit import njit

__all__ = []

_LOG_LENGTH_BOUNDS = (math.log(0.02), math.log(5.0))
_LOG_NOISE_BOUNDS = (math.log(1e-6), math.log(1e-1))


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
    # Both triangles from one: a squared difference is the same either way round (the chordal one too: sin is
    # odd), so every entry is the one the full loop would compute.
    for i in range(n):
        for j in range(i + 1):
            r2 = 0.0
            for k in range(d):
                t = _scaled_difference(X[i, k], X[j, k], inv_length[k], periodic[k])
                scaled[i, j, k] = scaled[j, i, k] = t * t
                r2 += t * t
            r = math.sqrt(5.0 * r2)
            e = math.exp(-r)
            Cm[i, j] = Cm[j, i] = (1.0 + r + r * r / 3.0) * e
            G[i, j] = G[j, i] = 5.0 / 3.0 * (1.0 + r) * e
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
def _append_rows_numba(V, squares, L, X, start, stop, C, first, last, inv_length, periodic):
    """Rows ``start..stop-1`` of ``V = L^-1 K(X, C)`` for columns ``first..last-1``; squares accumulated.

    Row ``p`` needs rows ``0..p-1`` (forward substitution): O(p) per entry. The substitution runs along rows
    of ``V`` (contiguous); each entry's operations keep their order.
    """
    d = C.shape[1]
    for p in range(start, stop):
        row = V[p]
        for j in range(first, last):
            r2 = 0.0
            for k in range(d):
                t = _scaled_difference(X[p, k], C[j, k], inv_length[k], periodic[k])
                r2 += t * t
            r = math.sqrt(5.0 * r2)
            row[j] = (1.0 + r + r * r / 3.0) * math.exp(-r)
        for i in range(p):
            factor = L[p, i]
            earlier = V[i]
            for j in range(first, last):
                row[j] -= factor * earlier[j]
        pivot = L[p, p]
        for j in range(first, last):
            row[j] /= pivot
            squares[j] += row[j] * row[j]


def _append_rows_numpy(V, squares, L, X, start, stop, C, first, last, inv_length, periodic):
    for p in range(start, stop):
        k = _matern52_numpy(X[p:p + 1], C[first:last], inv_length, periodic)[0]
        V[p, first:last] = (k - L[p, :p] @ V[:p, first:last]) / L[p, p]
        squares[first:last] += V[p, first:last] ** 2


@njit
def _leading_dot_numba(V, w, count):
    """``V[:len(w), :count].T @ w`` without BLAS (small and frequent: BLAS threads only add latency)."""
    out = np.zeros(count)
    for i in range(w.shape[0]):
        wi = w[i]
        for j in range(count):
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
# The Gaussian process state.


def _minimize_lbfgsb(function, start, low, high, *, max_iterations, corrections=10, ftol=2.2204460492503131e-09,
                     gtol=1e-5, max_line_steps=20):
    """Minimize ``function(x) -> (value, gradient)`` over the box ``[low, high]`` by L-BFGS-B; returns ``x``.

    The loop of ``scipy.optimize.minimize(function, start, jac=True, method="L-BFGS-B", bounds=...,
    options={"maxiter": max_iterations})`` with scipy's defaults for the other options (``corrections`` is its
    ``maxcor``, ``max_line_steps`` its ``maxls``), driving the same routine, so the iterates are the same bit for
    bit; without the per-iteration bookkeeping of ``minimize`` (its memoized function object and a result object
    per iteration), which outweighs the likelihood itself on the small fits here. The function-evaluation
    cap of ``minimize`` (15000) is left out: ``max_iterations`` iterations of at most ``max_line_steps`` steps
    each stay far below it.

    Parameters
    ----------
    function : callable
        ``function(x)`` for ``x`` of shape (n,) returns the value and the gradient (n,).
    start : (n,) array_like
        Starting point, clipped into the box.
    low, high : (n,) array_like
        Finite bounds.
    max_iterations : int
        Iterations (accepted line searches) at most.

    Returns
    -------
    (n,) ndarray of float64
    """
    low = np.ascontiguousarray(low, dtype=np.float64)
    high = np.ascontiguousarray(high, dtype=np.float64)
    x = np.clip(np.asarray(start, dtype=np.float64).ravel(), low, high)
    n = x.shape[0]
    bounded_both_sides = np.full(n, 2, dtype=np.int32)
    f = np.array(0.0)
    g = np.zeros(n)
    work = np.zeros(2 * corrections * n + 5 * n + 11 * corrections * corrections + 8 * corrections)
    int_work = np.zeros(3 * n, dtype=np.int32)
    task = np.zeros(2, dtype=np.int32)
    line_task = np.zeros(2, dtype=np.int32)
    lsave = np.zeros(4, dtype=np.int32)
    isave = np.zeros(44, dtype=np.int32)
    dsave = np.zeros(29)
    factr = ftol / np.finfo(float).eps
    iterations = 0
    while True:
        g = np.asarray(g, dtype=np.float64).copy()
        _lbfgsb.setulb(corrections, x, low, high, bounded_both_sides, f, g, factr, gtol, work, int_work, task,
                       lsave, isave, dsave, max_line_steps, line_task)
        if task[0] == 3:  # evaluate at x
            value, gradient = function(x.copy())
            f = float(value)
            g = np.atleast_1d(gradient)
        elif task[0] == 1:  # a new iterate
            iterations += 1
            if iterations >= max_iterations:
                task[0], task[1] = 5, 504  # stop: the iteration limit
        else:
            return x


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
        targets = self.y[:n]
        targets[:] = y
        # np.mean and np.std's own reductions (the same sums, bit for bit) without their Python wrappers, which
        # cost more than the rest of this update at the run's sizes.
        offset = np.add.reduce(targets) / n
        centred = targets - offset
        spread = math.sqrt(np.add.reduce(centred * centred) / n)
        self.offset = float(offset)
        self.scale = spread if spread > 0 else 1.0
        self.w = _forward_substitute_numba(self.L, centred / self.scale)  # reads L[:n, :n] only
        self.signal = max(float(self.w @ self.w) / n, 1e-12)

    def refactor(self):
        n = self.n
        C = _matern52_numba(self.X[:n], self.X[:n], self.inv_length, self.periodic)
        C[np.diag_indices(n)] += math.exp(self.log_noise)
        self.L[:n, :n] = np.linalg.cholesky(C)

    def fit(self, *, max_iterations=20):
        """Maximize the profiled log marginal likelihood over log length scales and log noise."""
        n = self.n
        X = np.ascontiguousarray(self.X[:n])
        y = (self.y[:n] - self.offset) / self.scale

        def negative(theta):
            value, gradient = _log_likelihood_numba(X, y, theta[:-1], theta[-1], self.periodic)
            return -value, -gradient

        start = np.append(self.log_length, self.log_noise)
        bounds = np.array([_LOG_LENGTH_BOUNDS] * self.dims + [_LOG_NOISE_BOUNDS])
        try:
            found = _minimize_lbfgsb(negative, start, bounds[:, 0], bounds[:, 1], max_iterations=max_iterations)
            theta = found if np.all(np.isfinite(found)) else start
        except np.linalg.LinAlgError:
            theta = start
        self.log_length = theta[:-1].copy()
        self.log_noise = float(theta[-1])
        self.refactor()
        self.set_targets(self.y[:n])

