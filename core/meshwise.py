"""Mesh-wise stage: one conforming, flip-free UV map that fits per-triangle optimal Jacobians (Sec. 4.2, App. B).

The unknown is the map phi from the input UVs to new UVs, piecewise linear on the input triangles, so its
Jacobian ``J_i = grad phi_i`` maps the edge vectors of input triangle i to those of new triangle i, both
measured in texels of the input texture (see "Texel frame" below). The triangle-wise stage gives the optimum
``R_bar_i S_bar_i`` of each triangle up to a quarter turn. We minimize Eq. 19 with a flip barrier,

    sum_i a_i [ w_R |R_i - R(k_i pi/2) R_bar_i|^2 + w_S |S_i - S_bar_i|^2
                + w_rs |J_i - R_i S_i|^2 + w_b B(det J_i; s_i) ],

by the local-global scheme of App. B: the local step picks k_i, R_i = R(theta_i), S_i per triangle, the global
step minimizes Eq. 27 over the chart-vertex UVs by damped Newton.

Decisions (the paper leaves them open):

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
* Area weights ``a_i``: the input-UV area of triangle i divided by the mean input-UV area, so the sum is the
  integral of the per-point energy over the input UV domain (small triangles do not dominate) and the
  paper's balance ``w_rs = 1e-5`` keeps its meaning (a_i averages to 1). The local step does not depend on a_i.
* Local step: for each of the four quarter turns k, theta in closed form and then S from Eq. 26; the k with the
  lowest per-triangle energy wins, and a triangle keeps its previous (k, R, S) if that is lower still, so the
  objective never increases. theta minimizes the exact block of Eq. 19, ``w_R |R - R_k R_bar|^2 +
  w_rs |J - R S|^2``, whose maximizer of ``tr(R^T M)`` is ``M = w_R R_k R_bar + w_rs J S``; Eq. 25 writes
  the second term as ``w_rs |R - J S^-1|^2``, which agrees when S is a multiple of the identity and needs no
  inverse of S here. Eq. 26 is solved exactly over symmetric S: ``S = (w_S S_bar + w_rs sym(R^T J)) /
  (w_S + w_rs)`` (the linear system is diagonal in (s11, s12, s22)).
* Barrier: the spline barrier of Schueller et al. 2013, ``B(d) = 1/g(d/s) - 1`` for ``0 < d < s`` with
  ``g(t) = 1 - (1 - t)^3``, 0 above s, infinite at and below 0, on ``d = det J_i``; the per-triangle
  threshold is ``s_i = barrier_threshold * min(1, det S_bar_i)`` (the input has det J = 1). Its Hessian is
  projected to positive semi-definite per triangle.
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
* Gauge: the objective is invariant to translating a chart; the first chart vertex of every chart is held
  fixed, and a tiny diagonal shift (1e-12 of the mean diagonal) keeps vertices that only touch degenerate
  triangles solvable.
* Eq. 28 compares the weighted terms of Eq. 27: ``w_b`` is divided by 20 after an iteration in which
  ``w_b E_barrier > w_rs E_rs``. Lowering ``w_b`` only lowers the objective, so the history stays monotone.
* Factorization: the Hessian's sparsity pattern is fixed (one 6x6 block per triangle), so the COO to CSC map
  is computed once and assembly only refills values; while no barrier is active the Hessian is constant and
  its sparse LU is reused (SuperLU, minimum degree on the symmetric structure; scipy offers no symbolic
  reuse, and feeding back SuperLU's own permutation was measured slower than reordering, see
  ``_NewtonSolver``).
* Hot loops (local step, per-triangle gradient and Hessian blocks) are numba kernels; each keeps a plain
  numpy reference (``_local_update_reference``, ``_Objective.gradient_and_blocks_reference``) that the tests
  compare against.
"""
import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ._jit import njit
from .charts import UVTopology, uv_topology, validate_faces_and_uv
from .deformation import inverse_2x2, jacobian, rotation
from .progress import InThread, report_while_waiting, run_generator

__all__ = [
    "MeshwiseResult",
    "solve_meshwise",
    "iter_solve_meshwise",
    "barrier",
    "local_step",
    "fit_energy",
    "orient_charts",
    "flipped_triangles",
]

_GRAD = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
_DET_HESSIAN = np.array([[0.0, 0, 0, 1], [0, 0, -1, 0], [0, -1, 0, 0], [1, 0, 0, 0]])


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


def _frob2(A):
    return np.einsum("...ij,...ij->...", A, A)


def _sym(A):
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def _angle_of(M):
    return np.arctan2(M[..., 1, 0] - M[..., 0, 1], M[..., 0, 0] + M[..., 1, 1])


def local_step(J, R_bar, S_bar, w_R, w_S, w_rs, S_previous):
    """Local step of App. B: quarter turn k, rotation R = R(theta) and stretch S for every triangle.

    Parameters
    ----------
    J : (m, 2, 2) float64 array
        Current Jacobians.
    R_bar, S_bar : (m, 2, 2) float64 arrays
        Target rotations and symmetric stretches.
    w_R, w_S : (m,) float64 arrays
        Non-negative weights of Eq. 16-17.
    w_rs : float
        Weight of ``|J - R S|^2`` (Eq. 19).
    S_previous : (m, 2, 2) float64 array
        Stretch of the previous iteration (used in the theta update).

    Returns
    -------
    k : (m,) int64 ndarray
    R, S : (m, 2, 2) float64 ndarrays
    energy : (m,) float64 ndarray
        ``w_R |R - R(k pi/2) R_bar|^2 + w_S |S - S_bar|^2 + w_rs |J - R S|^2`` per triangle.

    Notes
    -----
    For each k in {0, 1, 2, 3}: theta maximizes ``tr(R(theta)^T M)`` with ``M = w_R R(k pi/2) R_bar + w_rs J
    S_previous`` (the exact minimizer of Eq. 19 over R with S fixed; Eq. 25 of the paper approximates its
    second term), then S solves Eq. 26 over symmetric matrices. The k of lowest energy is returned.

    References
    ----------
    Sun et al. 2022, App. B, Eq. 25-26.
    """
    w_R = w_R[:, None, None]
    w_S = w_S[:, None, None]
    best_energy = np.full(J.shape[0], np.inf)
    best_k = np.zeros(J.shape[0], dtype=np.int64)
    best_R = np.empty_like(J)
    best_S = np.empty_like(J)
    JS = J @ S_previous
    for k in range(4):
        target_R = rotation(np.full(J.shape[0], k * np.pi / 2)) @ R_bar
        R = rotation(_angle_of(w_R * target_R + w_rs * JS))
        S = (w_S * S_bar + w_rs * _sym(np.swapaxes(R, 1, 2) @ J)) / np.maximum(w_S + w_rs, np.finfo(float).tiny)
        energy = (w_R[:, 0, 0] * _frob2(R - target_R) + w_S[:, 0, 0] * _frob2(S - S_bar)
                  + w_rs * _frob2(J - R @ S))
        better = energy < best_energy
        best_energy[better] = energy[better]
        best_k[better] = k
        best_R[better] = R[better]
        best_S[better] = S[better]
    return best_k, best_R, best_S, best_energy


def _polar(J):
    """Rotation and symmetric factor of 2x2 matrices with positive determinant (closed form)."""
    R = rotation(_angle_of(J))
    return R, np.swapaxes(R, 1, 2) @ J


def fit_energy(J, R_bar, S_bar, w_R, w_S, *, formulation="perceptual"):
    """Per-triangle fit of Jacobians to their targets (Eq. 16, or Eq. 15 for ``formulation="common"``).

    Parameters
    ----------
    J : (m, 2, 2) array_like of float
        Jacobians with positive determinant.
    R_bar, S_bar : (m, 2, 2) array_like of float
        Targets.
    w_R, w_S : (m,) array_like of float
        Weights (ignored for ``"common"``).
    formulation : {"perceptual", "common"}

    Returns
    -------
    energy : (m,) float64 ndarray
        Minimum over the four quarter turns k.
    k : (m,) int64 ndarray
        The minimizing k.
    """
    J = np.asarray(J, dtype=np.float64)
    R_bar = np.asarray(R_bar, dtype=np.float64)
    S_bar = np.asarray(S_bar, dtype=np.float64)
    m = J.shape[0]
    if formulation == "perceptual":
        R, S = _polar(J)
        stretch_term = np.asarray(w_S, dtype=np.float64) * _frob2(S - S_bar)
    elif formulation != "common":
        raise ValueError(f"formulation must be 'perceptual' or 'common', got {formulation!r}")
    energies = []
    for k in range(4):
        turned = rotation(np.full(m, k * np.pi / 2)) @ R_bar
        if formulation == "perceptual":
            energies.append(np.asarray(w_R, dtype=np.float64) * _frob2(R - turned) + stretch_term)
        else:
            energies.append(_frob2(J - turned @ S_bar))
    energies = np.stack(energies)
    k = np.argmin(energies, axis=0)
    return energies[k, np.arange(m)], k


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


def _edges_and_validity(uv, degenerate_tol):
    """Edge matrices (columns e1, e2), their determinants, and which triangles are not degenerate."""
    edges = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)
    det = edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]
    longest2 = np.max(np.stack([_frob2(uv[:, 1] - uv[:, 0]), _frob2(uv[:, 2] - uv[:, 1]),
                                _frob2(uv[:, 0] - uv[:, 2])]), axis=0)
    return edges, det, np.abs(det) > degenerate_tol * longest2


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


_QUARTER_TURNS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])  # (cos, sin) of k pi/2


@njit
def _local_update_kernel(J, R_bar, S_bar, w_R, w_S, w_rs, k, R, S):
    """In place: numba form of :func:`local_step` plus keeping (k, R, S) where they are lower still."""
    m = J.shape[0]
    energy = np.empty(m)
    for t in range(m):
        j00, j01, j10, j11 = J[t, 0, 0], J[t, 0, 1], J[t, 1, 0], J[t, 1, 1]
        sb00, sb01, sb11 = S_bar[t, 0, 0], S_bar[t, 0, 1], S_bar[t, 1, 1]
        rb00, rb10 = R_bar[t, 0, 0], R_bar[t, 1, 0]
        wr, ws = w_R[t], w_S[t]
        # Energy of the previous state.
        c, s = _QUARTER_TURNS[k[t], 0], _QUARTER_TURNS[k[t], 1]
        tr00, tr10 = c * rb00 - s * rb10, s * rb00 + c * rb10
        r00, r10 = R[t, 0, 0], R[t, 1, 0]
        p00, p01, p11 = S[t, 0, 0], S[t, 0, 1], S[t, 1, 1]
        best = (wr * 2.0 * ((r00 - tr00) ** 2 + (r10 - tr10) ** 2)
                + ws * ((p00 - sb00) ** 2 + 2.0 * (p01 - sb01) ** 2 + (p11 - sb11) ** 2)
                + w_rs * ((j00 - (r00 * p00 - r10 * p01)) ** 2 + (j01 - (r00 * p01 - r10 * p11)) ** 2
                          + (j10 - (r10 * p00 + r00 * p01)) ** 2 + (j11 - (r10 * p01 + r00 * p11)) ** 2))
        # J S_previous, for the theta update.
        js00 = j00 * p00 + j01 * p01
        js01 = j00 * p01 + j01 * p11
        js10 = j10 * p00 + j11 * p01
        js11 = j10 * p01 + j11 * p11
        best_k, best_c, best_s = k[t], r00, r10
        best_s00, best_s01, best_s11 = p00, p01, p11
        for kk in range(4):
            c, s = _QUARTER_TURNS[kk, 0], _QUARTER_TURNS[kk, 1]
            tr00, tr10 = c * rb00 - s * rb10, s * rb00 + c * rb10  # R(k pi/2) R_bar = [[tr00, -tr10], [tr10, tr00]]
            m00 = wr * tr00 + w_rs * js00
            m01 = -wr * tr10 + w_rs * js01
            m10 = wr * tr10 + w_rs * js10
            m11 = wr * tr00 + w_rs * js11
            theta = np.arctan2(m10 - m01, m00 + m11)
            rc, rs = np.cos(theta), np.sin(theta)
            # R^T J, symmetrized.
            a00 = rc * j00 + rs * j10
            a01 = rc * j01 + rs * j11
            a10 = -rs * j00 + rc * j10
            a11 = -rs * j01 + rc * j11
            denominator = max(ws + w_rs, 1e-300)
            q00 = (ws * sb00 + w_rs * a00) / denominator
            q01 = (ws * sb01 + w_rs * 0.5 * (a01 + a10)) / denominator
            q11 = (ws * sb11 + w_rs * a11) / denominator
            e = (wr * 2.0 * ((rc - tr00) ** 2 + (rs - tr10) ** 2)
                 + ws * ((q00 - sb00) ** 2 + 2.0 * (q01 - sb01) ** 2 + (q11 - sb11) ** 2)
                 + w_rs * ((j00 - (rc * q00 - rs * q01)) ** 2 + (j01 - (rc * q01 - rs * q11)) ** 2
                           + (j10 - (rs * q00 + rc * q01)) ** 2 + (j11 - (rs * q01 + rc * q11)) ** 2))
            if e < best:
                best, best_k, best_c, best_s = e, kk, rc, rs
                best_s00, best_s01, best_s11 = q00, q01, q11
        k[t] = best_k
        R[t, 0, 0], R[t, 0, 1], R[t, 1, 0], R[t, 1, 1] = best_c, -best_s, best_s, best_c
        S[t, 0, 0], S[t, 0, 1], S[t, 1, 0], S[t, 1, 1] = best_s00, best_s01, best_s01, best_s11
        energy[t] = best
    return energy


def _local_update_reference(J, R_bar, S_bar, w_R, w_S, w_rs, k, R, S):
    """Plain numpy reference of :func:`_local_update_kernel` (returns new arrays)."""
    k_new, R_new, S_new, e_new = local_step(J, R_bar, S_bar, w_R, w_S, w_rs, S)
    turned = rotation(k * np.pi / 2) @ R_bar
    e_old = w_R * _frob2(R - turned) + w_S * _frob2(S - S_bar) + w_rs * _frob2(J - R @ S)
    keep = e_old <= e_new
    return (np.where(keep, k, k_new), np.where(keep[:, None, None], R, R_new),
            np.where(keep[:, None, None], S, S_new), np.where(keep, e_old, e_new))


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
    converged = False
    iteration = 0
    yield 0, int(max_iterations)  # the set-up is a step of its own
    for iteration in range(1, int(max_iterations) + 1):
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
        yield iteration, int(max_iterations)
        if history[-2] - history[-1] <= tol * max(history[-1], 1e-9 * scale):
            converged = True
            break

    x = _carry_loose_vertices(x, problem, texel_topology, J) / frame
    final_fit, k_final = fit_energy(J, R_bar, S_bar, w_R, w_S, formulation=formulation)
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    return MeshwiseResult(
        uv=topology.corner_uv(x),
        vertex_uv=x,
        topology=topology,
        iterations=iteration,
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
    Decisions not fixed by the paper are listed in this module's docstring: area weights by input-UV area,
    exact block minimization in the local step (monotone objective), SKPS13 barrier with per-triangle
    threshold, orientation kept per triangle (mirrored charts need no special case), degenerate input
    triangles weighted 0, one fixed vertex per chart as the translation gauge, the solve in the texel frame.

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


def orient_charts(uv_in, uv_new, face_chart, alpha, w_R, *, texel_scale=(1.0, 1.0), samples=90):
    """Turn every chart of ``uv_new`` rigidly to the angle that best meets its triangles' rotation targets.

    Minimizes Eq. 16's rotation term, ``sum_i a_i w_R,i min_k |R_i - R(k pi/2) R(alpha_i)|^2`` over one
    rotation per chart, where ``R_i`` is the rotation factor of triangle i's Jacobian from ``uv_in`` to
    ``uv_new`` and ``a_i`` its input-UV area. A rigid turn leaves every stretch ``S_i``, every determinant and
    every other term of Eq. 19 as it was.

    Parameters
    ----------
    uv_in : (m, 3, 2) array_like of float
        Input UVs per face corner (the frame of ``alpha``).
    uv_new : (m, 3, 2) array_like of float
        The same charts after the mesh-wise fit.
    face_chart : (m,) array_like of int
        Chart of every face, numbered from 0.
    alpha : (m,) array_like of float
        Target rotation angle of every triangle (the triangle-wise optimum's first parameter).
    w_R : (m,) array_like of float
        Non-negative rotation weights (Eq. 17).
    texel_scale : (2,) array_like of float, optional
        Texels per UV unit along u and v of the input texture: the angles are measured on the texel grid, as
        the triangle-wise stage measured ``alpha``.
    samples : int, optional
        Angles tried per quarter turn before the local refinement.

    Returns
    -------
    uv : (m, 3, 2) float64 ndarray
        ``uv_new`` with every chart turned about its corners' mean.
    angles : (n_charts,) float64 ndarray
        The turn of every chart, in ``[0, pi/2)`` (with the packer's quarter turns that is every angle).

    Notes
    -----
    With the 90-degree symmetry the energy of a chart turned by ``theta`` is
    ``4 sum_i a_i w_R,i (1 - cos((theta + d_i) mod* pi/2))`` with ``d_i = angle(R_i) - alpha_i`` and ``mod*``
    the residue in ``[-pi/4, pi/4)``. It is tried at ``samples`` angles, then refined from the best by
    alternating the quarter turns ``k_i`` and the closed-form ``theta = -arg sum_i a_i w_R,i
    exp(j (d_i - k_i pi/2))``, both of which only lower it. A chart keeps its angle unless turning it lowers
    the energy. Fitting the rotation terms inside Eq. 19 instead bends charts whose triangles want different
    rotations, and the bending pulls the triangles off their stretch targets (see
    :meth:`~.trianglewise_result.TrianglewiseResult.fit_weights`); a rigid turn cannot.

    References
    ----------
    Sun et al. 2022, Eq. 16 (rotation targets with 90-degree symmetry), Eq. 17 (``w_R``), Eq. 19.
    """
    uv_in = np.asarray(uv_in, dtype=np.float64)
    uv_new = np.asarray(uv_new, dtype=np.float64)
    face_chart = np.asarray(face_chart)
    alpha = np.asarray(alpha, dtype=np.float64)
    m = uv_in.shape[0]
    if uv_in.shape != (m, 3, 2) or uv_new.shape != uv_in.shape:
        raise ValueError(f"uv_in and uv_new must both have shape (m, 3, 2), got {uv_in.shape} and {uv_new.shape}")
    if (face_chart.shape != (m,) or alpha.shape != (m,) or not np.issubdtype(face_chart.dtype, np.integer)
            or (m and face_chart.min() < 0)):
        raise ValueError(f"face_chart and alpha must have shape ({m},), face_chart integers numbered from 0")
    if not np.all(np.isfinite(alpha)):
        raise ValueError("alpha must be finite")
    w_R = _parse_weights(w_R, m, "w_R")
    scale = np.asarray(texel_scale, dtype=np.float64)
    if scale.shape != (2,) or not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"texel_scale must be two positive numbers, got {texel_scale}")
    if int(samples) < 1:
        raise ValueError(f"samples must be at least 1, got {samples}")
    n_charts = int(face_chart.max()) + 1 if m else 0
    quarter = np.pi / 2

    def edges(corners):
        return np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=-1) * scale[:, None]

    old, new = edges(uv_in), edges(uv_new)
    old_det, new_det = np.linalg.det(old), np.linalg.det(new)
    weight = w_R * 0.5 * np.abs(old_det)
    weight[(old_det == 0) | (new_det * old_det <= 0)] = 0.0
    fitted = weight > 0
    d = np.zeros(m)
    J = new[fitted] @ inverse_2x2(old[fitted])
    d[fitted] = _angle_of(J) - alpha[fitted]

    def energies(theta):
        residue = np.mod(theta[face_chart] + d + quarter / 2, quarter) - quarter / 2
        return np.bincount(face_chart, weights=weight * (1 - np.cos(residue)), minlength=n_charts)

    grid = np.arange(int(samples)) * (quarter / int(samples))
    table = np.stack([energies(np.full(n_charts, t)) for t in grid])
    theta = grid[np.argmin(table, axis=0)]
    best = table.min(axis=0)
    for _ in range(8):
        k = np.round((theta[face_chart] + d) / quarter)
        phasor = np.bincount(face_chart, weights=weight * np.cos(d - k * quarter), minlength=n_charts) + 1j * \
            np.bincount(face_chart, weights=weight * np.sin(d - k * quarter), minlength=n_charts)
        candidate = np.mod(-np.angle(phasor), quarter)
        energy = energies(candidate)
        better = energy < best
        theta[better], best[better] = candidate[better], energy[better]
    theta[~(best < energies(np.zeros(n_charts)))] = 0.0

    uv = uv_new.copy()
    for chart in np.flatnonzero(theta):
        faces = face_chart == chart
        texels = uv_new[faces] * scale
        centre = texels.reshape(-1, 2).mean(axis=0)
        uv[faces] = ((texels - centre) @ rotation(theta[chart]).T + centre) / scale
    return uv, theta
