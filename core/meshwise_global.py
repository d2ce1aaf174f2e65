"""Global step of the mesh-wise stage: Eq. 27 over the chart-vertex UVs, with the flip barrier, by damped Newton.

With the local variables ``(k_i, R_i, S_i)`` held fixed (:mod:`.meshwise_local`), Eq. 19 with the flip barrier is
a function of the chart-vertex UVs alone (Eq. 27, App. B),

    sum_i a_i [ w_rs |J_i - R_i S_i|^2 + w_b B(det J_i; s_i) ] + const,

``J_i`` linear in the corners of triangle i (for ``formulation="common"`` the target is ``R(k_i pi/2) R_bar_i
S_bar_i`` with weight 1 in place of ``w_rs``). ``_prepare`` gathers the constant data of one solve (``_Problem``:
the gradient operator of every input triangle, the area weights, the barrier thresholds, the free unknowns);
``_Objective`` gives the value, the gradient and positive semi-definite Hessian blocks, and the largest step
before a triangle inverts; ``_NewtonSolver`` solves for the Newton step. :mod:`.meshwise` runs the iterations and
the line search.

Decisions (the paper leaves them open):

* Area weights ``a_i``: the input-UV area of triangle i divided by the mean input-UV area, so the sum is the
  integral of the per-point energy over the input UV domain (small triangles do not dominate) and the
  paper's balance ``w_rs = 1e-5`` keeps its meaning (a_i averages to 1). The local step does not depend on a_i.
* Barrier: the spline barrier of Schueller et al. 2013, ``B(d) = 1/g(d/s) - 1`` for ``0 < d < s`` with
  ``g(t) = 1 - (1 - t)^3``, 0 above s, infinite at and below 0, on ``d = det J_i``; the per-triangle
  threshold is ``s_i = barrier_threshold * min(1, det S_bar_i)`` (the input has det J = 1). Its Hessian is
  projected to positive semi-definite per triangle.
* Gauge: the objective is invariant to translating a chart; the first chart vertex of every chart is held
  fixed, and a tiny diagonal shift (1e-12 of the mean diagonal) keeps vertices that only touch degenerate
  triangles solvable.
* Factorization: the Hessian's sparsity pattern is fixed (one 6x6 block per triangle), so the COO to CSC map
  is computed once and assembly only refills values; while no barrier is active the Hessian is constant and
  its sparse LU is reused (SuperLU, minimum degree on the symmetric structure; scipy offers no symbolic
  reuse, and feeding back SuperLU's own permutation was measured slower than reordering, see
  ``_NewtonSolver``).
* Hot loop: the per-triangle gradient and Hessian blocks are a numba kernel (``_hessian_blocks_kernel``); it keeps
  a plain numpy reference (``_Objective.gradient_and_blocks_reference``) that the tests compare against.

References
----------
Sun et al. 2022, App. B, Eq. 27; Schueller et al. 2013 (barrier, damped Newton); Smith and Schaefer 2015 (largest
step before a triangle inverts).
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ._jit import njit
from .meshwise_local import _frob2

__all__ = ["barrier"]

_GRAD = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
_DET_HESSIAN = np.array([[0.0, 0, 0, 1], [0, 0, -1, 0], [0, -1, 0, 0], [1, 0, 0, 0]])


def barrier(d, s):
    """Spline barrier of Schueller et al. 2013 on Jacobian determinants, with first and second derivatives.

    Parameters
    ----------
    d : (m,) array_like of float
        Determinants.
    s : (m,) array_like of float
        Positive thresholds; the barrier is 0 for ``d >= s``.

    Returns
    -------
    value, first, second : (m,) float64 ndarrays
        ``B(d) = 1/g(d/s) - 1`` with ``g(t) = t^3 - 3t^2 + 3t = 1 - (1-t)^3`` on ``0 < d < s``, its first and
        second derivatives in d; ``inf`` (and nan derivatives) for ``d <= 0``. B is C2 at ``d = s``.

    References
    ----------
    Schueller, Kavan, Panozzo, Sorkine-Hornung 2013, "Locally injective mappings", Eq. 4-5; Sun et al. 2022,
    Eq. 27.
    """
    d = np.asarray(d, dtype=np.float64)
    s = np.broadcast_to(np.asarray(s, dtype=np.float64), d.shape)
    value = np.zeros(d.shape)
    first = np.zeros(d.shape)
    second = np.zeros(d.shape)
    active = (d < s) & (d > 0)
    t = d[active] / s[active]
    one_minus = 1.0 - t
    g = 1.0 - one_minus ** 3
    dg = 3.0 * one_minus ** 2 / s[active]
    ddg = -6.0 * one_minus / s[active] ** 2
    value[active] = 1.0 / g - 1.0
    first[active] = -dg / g ** 2
    second[active] = (2.0 * dg ** 2 - g * ddg) / g ** 3
    dead = d <= 0
    value[dead] = np.inf
    first[dead] = np.nan
    second[dead] = np.nan
    return value, first, second


@dataclass(eq=False)
class _Problem:
    """Constant data of one solve: geometry of the input triangles and the reduced DOF numbering."""

    corner_vertex: np.ndarray  # (m, 3)
    gradient: np.ndarray  # (m, 3, 2): J = X^T gradient for corner positions X (3, 2)
    weight: np.ndarray  # (m,) area weights, 0 for degenerate
    valid: np.ndarray  # (m,) non-degenerate
    threshold: np.ndarray  # (m,) barrier threshold s_i
    n_vertices: int
    free_index: np.ndarray  # (2k,) reduced index of each DOF, -1 if fixed
    n_free: int
    block_rows: np.ndarray  # (m, 6) reduced DOF of local (a, j), -1 if fixed

    def jacobians(self, vertex_uv):
        X = vertex_uv[self.corner_vertex]  # (m, 3, 2)
        return np.swapaxes(X, 1, 2) @ self.gradient


def _edges_and_validity(uv, degenerate_tol):
    """Edge matrices (columns e1, e2), their determinants, and which triangles are not degenerate."""
    edges = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)
    det = edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]
    longest2 = np.max(np.stack([_frob2(uv[:, 1] - uv[:, 0]), _frob2(uv[:, 2] - uv[:, 1]),
                                _frob2(uv[:, 0] - uv[:, 2])]), axis=0)
    return edges, det, np.abs(det) > degenerate_tol * longest2


def _prepare(topology, uv, S_bar, *, degenerate_tol, barrier_threshold):
    edges, det, valid = _edges_and_validity(uv, degenerate_tol)
    if not valid.any():
        raise ValueError("every input UV triangle is degenerate (zero area); nothing to fit")
    inverse = np.zeros_like(edges)
    e = edges[valid]
    d = det[valid][:, None, None]
    inverse[valid] = np.stack([np.stack([e[:, 1, 1], -e[:, 0, 1]], -1),
                               np.stack([-e[:, 1, 0], e[:, 0, 0]], -1)], -2) / d
    gradient = _GRAD[None] @ inverse
    area = 0.5 * np.abs(det)
    weight = np.where(valid, area / area[valid].mean(), 0.0)
    target_det = S_bar[:, 0, 0] * S_bar[:, 1, 1] - S_bar[:, 0, 1] ** 2
    threshold = barrier_threshold * np.minimum(1.0, target_det)

    k = topology.n_vertices
    fixed = np.zeros(k, dtype=bool)
    _, first_vertex = np.unique(topology.vertex_chart, return_index=True)
    fixed[first_vertex] = True
    fixed_dof = np.concatenate([fixed, fixed])
    free_index = np.full(2 * k, -1, dtype=np.int64)
    free_index[~fixed_dof] = np.arange(int((~fixed_dof).sum()))
    cv = topology.corner_vertex
    block_rows = free_index[np.concatenate([cv, cv + k], axis=1)]  # local order (u0,u1,u2,v0,v1,v2)
    return _Problem(corner_vertex=cv, gradient=gradient, weight=weight, valid=valid, threshold=threshold,
                    n_vertices=k, free_index=free_index, n_free=int((~fixed_dof).sum()), block_rows=block_rows)


def _build_pattern(problem):
    """CSC structure of the reduced Hessian and the map from per-triangle 6x6 entries to CSC values."""
    n = problem.n_free
    rows = np.repeat(problem.block_rows[:, :, None], 6, axis=2)  # (m, 6, 6): [t, i, j] -> row of i
    cols = np.repeat(problem.block_rows[:, None, :], 6, axis=1)
    keep = (rows >= 0) & (cols >= 0)
    diagonal = np.arange(n)
    key = np.concatenate([cols[keep] * n + rows[keep], diagonal * n + diagonal])
    unique, entry = np.unique(key, return_inverse=True)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(unique // n, minlength=n))]).astype(np.int64)
    return {"keep": keep, "entry": entry, "nnz": unique.size, "indices": unique % n, "indptr": indptr, "n": n}


def _assemble(pattern, blocks, shift):
    values = np.concatenate([blocks[pattern["keep"]], np.full(pattern["n"], shift)])
    data = np.bincount(pattern["entry"], weights=values, minlength=pattern["nnz"])
    return sp.csc_matrix((data, pattern["indices"], pattern["indptr"]), shape=(pattern["n"], pattern["n"]))


class _NewtonSolver:
    """Solves ``H d = -g`` for the reduced Hessian, refactoring only when the Hessian's values changed.

    The sparsity pattern is fixed (one 6x6 block per triangle), so the COO to CSC map is computed once and
    every assembly is a single ``bincount``. While no barrier term is active the Hessian is the constant
    fit part and its factorization is reused. SuperLU runs with a minimum-degree ordering on the symmetric
    structure and diagonal pivots; reusing its first permutation with ``permc_spec="NATURAL"`` was measured
    slower than reordering (tea_set, 43,662 unknowns: 0.83-1.09 s against 0.62-0.65 s per factorization).
    """

    def __init__(self, problem):
        self.pattern = _build_pattern(problem)
        self.data = None
        self.solve = None
        self.factorizations = 0

    def newton_step(self, grad, blocks, shift):
        """Step d (reduced) with ``H d = -grad``."""
        H = _assemble(self.pattern, blocks, shift)
        if self.solve is None or not np.array_equal(H.data, self.data):
            lu = sla.splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            self.solve = lu.solve
            self.data = H.data
            self.factorizations += 1
        return self.solve(-grad)

    def release(self):
        """Drop the factorization. Call it in the thread that made it: scipy's SuperLU keeps the memory of a
        factor freed in another thread than its own (scipy issue 15921; a process grew by a factor's size per
        factorization)."""
        self.solve = None
        self.data = None


@njit
def _hessian_blocks_kernel(J, target, gradient, weight, first, second, quad_weight, w_b):
    """Per-triangle gradient (m, 6) and PSD Hessian blocks (m, 6, 6) of Eq. 27 in local DOF order.

    Local DOFs are (u0, u1, u2, v0, v1, v2); vec(J) = (J00, J01, J10, J11) with J[a, b] = sum_j X[j, a] G[j, b].
    """
    m = J.shape[0]
    grad = np.zeros((m, 6))
    blocks = np.zeros((m, 6, 6))
    HJ = np.empty((4, 4))
    D = np.zeros((4, 6))
    hess_det = np.zeros((4, 4))
    hess_det[0, 3] = hess_det[3, 0] = 1.0
    hess_det[1, 2] = hess_det[2, 1] = -1.0
    for t in range(m):
        a = weight[t]
        if a == 0.0:
            continue
        for b in range(2):
            for j in range(3):
                D[b, j] = gradient[t, j, b]
                D[2 + b, 3 + j] = gradient[t, j, b]
        cof = np.array([J[t, 1, 1], -J[t, 1, 0], -J[t, 0, 1], J[t, 0, 0]])
        residual = np.array([J[t, 0, 0] - target[t, 0, 0], J[t, 0, 1] - target[t, 0, 1],
                             J[t, 1, 0] - target[t, 1, 0], J[t, 1, 1] - target[t, 1, 1]])
        gJ = 2.0 * quad_weight * a * residual + w_b * a * first[t] * cof
        for p in range(4):
            for q in range(4):
                HJ[p, q] = 0.0
        if first[t] != 0.0:
            for p in range(4):
                for q in range(4):
                    HJ[p, q] = w_b * a * (second[t] * cof[p] * cof[q] + first[t] * hess_det[p, q])
            values, vectors = np.linalg.eigh(HJ)
            for p in range(4):
                for q in range(4):
                    acc = 0.0
                    for r in range(4):
                        if values[r] > 0.0:
                            acc += vectors[p, r] * values[r] * vectors[q, r]
                    HJ[p, q] = acc
        for p in range(4):
            HJ[p, p] += 2.0 * quad_weight * a
        for i in range(6):
            acc = 0.0
            for p in range(4):
                acc += D[p, i] * gJ[p]
            grad[t, i] = acc
        for i in range(6):
            for j in range(6):
                acc = 0.0
                for p in range(4):
                    if D[p, i] == 0.0:
                        continue
                    for q in range(4):
                        acc += D[p, i] * HJ[p, q] * D[q, j]
                blocks[t, i, j] = acc
    return grad, blocks


class _Objective:
    """Eq. 27 (plus the constant fit part) as a function of the chart-vertex UVs."""

    def __init__(self, problem, target, quad_weight, w_b, constant):
        self.problem = problem
        self.target = target  # (m, 2, 2): R S (or R_k R_bar S_bar for "common")
        self.quad_weight = quad_weight  # w_rs (or 1 for "common")
        self.w_b = w_b
        self.constant = constant  # area-weighted fit energy of the current local variables

    def parts(self, J):
        p = self.problem
        quad = p.weight * _frob2(J - self.target)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        b, _, _ = barrier(np.where(p.valid, det, 1.0), np.where(p.valid, p.threshold, 0.5))
        return quad.sum(), (p.weight * b).sum()

    def value(self, J):
        quad, bar = self.parts(J)
        return self.constant + self.quad_weight * quad + self.w_b * bar

    def gradient_and_blocks(self, J):
        """Reduced gradient (n_free,) and per-triangle PSD Hessian blocks (m, 6, 6) in local DOF order."""
        p = self.problem
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        _, db, ddb = barrier(np.where(p.valid, det, 1.0), np.where(p.valid, p.threshold, 0.5))
        grad_local, blocks = _hessian_blocks_kernel(np.ascontiguousarray(J), np.ascontiguousarray(self.target),
                                                    p.gradient, p.weight, db, ddb, float(self.quad_weight),
                                                    float(self.w_b))
        grad = np.bincount(np.where(p.block_rows >= 0, p.block_rows, p.n_free).ravel(), weights=grad_local.ravel(),
                           minlength=p.n_free + 1)
        return grad[:-1], blocks

    def gradient_and_blocks_reference(self, J):
        """Plain numpy reference of :meth:`gradient_and_blocks`."""
        p = self.problem
        m = J.shape[0]
        a = p.weight
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        _, db, ddb = barrier(np.where(p.valid, det, 1.0), np.where(p.valid, p.threshold, 0.5))
        cof = np.stack([J[:, 1, 1], -J[:, 1, 0], -J[:, 0, 1], J[:, 0, 0]], axis=1)  # d det / d vec(J)
        grad_J = 2.0 * self.quad_weight * a[:, None] * (J - self.target).reshape(m, 4) \
            + (self.w_b * a * db)[:, None] * cof
        # D maps local DOFs (u0,u1,u2,v0,v1,v2) to vec(J) = (J00, J01, J10, J11).
        D = np.zeros((m, 4, 6))
        Gt = np.swapaxes(p.gradient, 1, 2)
        D[:, 0:2, 0:3] = Gt
        D[:, 2:4, 3:6] = Gt
        grad_local = np.einsum("tij,ti->tj", D, grad_J)
        H_J = np.zeros((m, 4, 4))
        H_J[:] = np.eye(4) * (2.0 * self.quad_weight * a)[:, None, None]
        active = db != 0
        if active.any():
            c = cof[active]
            hb = (ddb[active][:, None, None] * c[:, :, None] * c[:, None, :]
                  + db[active][:, None, None] * _DET_HESSIAN[None])
            hb *= (self.w_b * a[active])[:, None, None]
            eigval, eigvec = np.linalg.eigh(hb)
            hb = (eigvec * np.maximum(eigval, 0.0)[:, None, :]) @ np.swapaxes(eigvec, 1, 2)
            H_J[active] += hb
        blocks = np.swapaxes(D, 1, 2) @ H_J @ D
        grad = np.zeros(p.n_free + 1)
        np.add.at(grad, np.where(p.block_rows >= 0, p.block_rows, p.n_free).ravel(), grad_local.ravel())
        return grad[:-1], blocks

    def max_step(self, vertex_uv, direction):
        """Largest t in (0, inf] such that det J(x + t d) > 0 on (0, t) for every valid triangle."""
        p = self.problem
        J0 = p.jacobians(vertex_uv)[p.valid]
        dJ = p.jacobians(direction)[p.valid]
        c0 = J0[:, 0, 0] * J0[:, 1, 1] - J0[:, 0, 1] * J0[:, 1, 0]
        c1 = J0[:, 0, 0] * dJ[:, 1, 1] + dJ[:, 0, 0] * J0[:, 1, 1] - J0[:, 0, 1] * dJ[:, 1, 0] \
            - dJ[:, 0, 1] * J0[:, 1, 0]
        c2 = dJ[:, 0, 0] * dJ[:, 1, 1] - dJ[:, 0, 1] * dJ[:, 1, 0]
        return _smallest_positive_root(c2, c1, c0)


def _smallest_positive_root(a, b, c):
    """min over rows of the smallest t > 0 with a t^2 + b t + c = 0 (inf if none); assumes c > 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = np.full((a.size, 2), np.inf)
        linear = np.abs(a) <= 1e-300
        t_lin = -c / b
        roots[linear, 0] = np.where(t_lin[linear] > 0, t_lin[linear], np.inf)
        quad = ~linear
        disc = b * b - 4 * a * c
        real = quad & (disc >= 0)
        sq = np.sqrt(np.where(real, disc, 0.0))
        # Numerically stable pair: q = -(b + sign(b) sqrt(disc)) / 2, roots q/a and c/q.
        q = -0.5 * (b + np.copysign(sq, b))
        r1 = q / a
        r2 = c / q
        for col, r in enumerate((r1, r2)):
            ok = real & (r > 0) & np.isfinite(r)
            roots[ok, col] = r[ok]
    return float(roots.min()) if roots.size else np.inf
