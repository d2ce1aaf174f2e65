# SPDX-License-Identifier: GPL-3.0-or-later
"""Signal-Specialized Parametrization (Sander, Gortler, Snyder, Hoppe 2002), the baseline of Sec. 5.2.2.

Its expected stretch (:func:`ssp_targets`) is also half of our own mesh-wise targets' areas
(:meth:`.trianglewise_result.TrianglewiseResult.fit_targets`).

SSP allocates texels where the signal varies. For piecewise-constant reconstruction with texel spacing
``delta`` the mean squared error at a surface point is ``delta^2 / 12 |grad_t f|^2``, with ``grad_t f`` the
signal gradient with respect to texture coordinates. Triangle T maps to UV by ``x -> A_T x`` (x in an
orthonormal frame of its plane), so ``grad_t f = A_T^-T grad f`` and the error over the surface is

    sum_T  integral_T |A_T^-T grad f|^2 dA  =  sum_T tr(A_T^-T Gamma_T A_T^-1),
    Gamma_T = integral_T (grad f)(grad f)^T dA          (the signal-stretch metric tensor, 2 x 2),

pre-integrated once per triangle (:mod:`.signal_metric`, which also says how). At a fixed texel count
``delta^2`` is proportional to the total UV area, so the energy compared between parameterizations is the
scale-invariant product

    E_SSP = (sum_T |T^t| / sum_T |T|) * sum_T tr(A_T^-T Gamma_T A_T^-1),

which equals ``integral |grad f|^2 dA`` for an isometric map (the L2 signal stretch of SGSH02, squared,
up to the constant ``delta^2 / 12``).

Expected stretch. Without the conforming requirement each triangle can take its own A_T; minimizing
``sum tr(A^-T Gamma A^-1)`` at a fixed ``sum det(A) |T|`` gives, with ``G = Gamma / |T|`` (density,
eigenvalues ``g1 >= g2``) and a Lagrange multiplier common to all triangles,

    A_T = c (g1 g2)^(-1/8) G^(1/2)   up to a rotation,

i.e. stretch ``lambda_i = c sqrt(g_i) (g1 g2)^(-1/8)`` along the eigenvector ``theta`` of ``g_i`` (more
texels across the direction in which the signal changes) and UV area density ``c^2 (g1 g2)^(1/4)``.

Constant signal. Where ``Gamma = 0`` the pure signal stretch lets a triangle collapse (no error at any
size), so some geometric stretch must be blended in (our choice of regularisation); we add
``geometric_weight * g_mean * |T| * I`` to every ``Gamma_T``, with ``g_mean`` the area-weighted mean of
``tr(G) / 2`` over the mesh (so the blend is relative to the signal's strength and unit-free). With the
default 0.01 a constant region gets 1/10 of the UV area density of an isotropic region of average detail.

Decisions (not in SGSH02, whose hierarchical solver and domain boundary we do not reproduce):

* :func:`solve_ssp` minimizes ``log E_SSP`` over the chart-vertex UVs by L-BFGS from the input UVs, keeping
  the input's cuts. Every line search starts below the largest step at which a triangle would flip (roots of
  ``det(U + t dU)``) and backtracks to the Armijo condition; ``E_SSP`` is infinite at a collapse (the
  blended tensor is positive definite), so the map stays flip-free. Triangles the input collapses in UV
  (no texels; WaterBottle has 80, sofa_03 one) are left out of the energy rather than refused. The result
  is scaled to the input's total UV area and each chart keeps its UV centroid (packing moves charts
  afterwards anyway).

References
----------
P. V. Sander, S. J. Gortler, J. Snyder, H. Hoppe, "Signal-Specialized Parametrization", EGWR 2002.
Sun et al. 2022, Sec. 5.2.2 (SSP and SSPOP: SSP's expected stretch ``lambda1, lambda2, theta`` fed to the
mesh-wise stage with ``w_R = 0``).
"""
from dataclasses import dataclass

import numpy as np

from .charts import uv_topology
from .deformation import inverse_2x2
from .evaluation import _triangle_frames
from .progress import run_generator
from .signal_metric import _check_mesh, _det, _uv_edges, iter_signal_metric_tensors

__all__ = ["expected_stretch", "ssp_energy", "SSPResult", "solve_ssp", "ssp_targets", "iter_ssp_targets"]

def _iter_checked_problem(V, F, uv, texture, metric, geometric_weight, channels, caller):
    """Checked mesh, its surface frames and the blended metric (``caller`` names the function in errors).

    A generator: yields ``(done, total)`` faces while it integrates the tensors
    (:func:`.signal_metric.iter_signal_metric_tensors`; nothing when ``metric`` is given) and returns the tuple below.

    Returns
    -------
    V, F, uv
        As from :func:`.signal_metric._check_mesh`.
    X : (m, 2, 2) float64 ndarray
    area : (m,) float64 ndarray
        Surface edge matrices in each triangle's plane, and areas (:func:`.evaluation._triangle_frames`).
    metric : (m, 2, 2) float64 ndarray
        ``metric`` (or :func:`.signal_metric.signal_metric_tensors` of ``texture``) blended by :func:`_regularized`.
    """
    V, F, uv = _check_mesh(V, F, uv)
    X, area = _triangle_frames(V, F)
    if metric is None:
        if texture is None:
            raise ValueError(f"{caller} needs a texture or a precomputed metric")
        metric = yield from iter_signal_metric_tensors(V, F, uv, texture, channels=channels)
    metric = _regularized(_check_metric(metric, F.shape[0]), area, geometric_weight)
    return V, F, uv, X, area, metric


def _regularized(gamma, area, geometric_weight):
    if not (np.isfinite(geometric_weight) and geometric_weight >= 0):
        raise ValueError(f"geometric_weight must be non-negative and finite, got {geometric_weight}")
    total = area.sum()
    trace_density = 0.5 * np.trace(gamma, axis1=1, axis2=2).sum() / total if total > 0 else 0.0
    # A signal-free mesh has no scale to be relative to: it gets pure geometric stretch (any positive
    # multiple gives the same minimizer).
    floor = geometric_weight * trace_density if trace_density > 0 else 1.0
    return gamma + floor * area[:, None, None] * np.eye(2)


def _check_metric(metric, m):
    metric = np.asarray(metric, dtype=np.float64)
    if metric.shape != (m, 2, 2):
        raise ValueError(f"metric must have shape ({m}, 2, 2), got {metric.shape}")
    if not np.all(np.isfinite(metric)):
        raise ValueError("metric holds NaN or infinite values")
    return 0.5 * (metric + np.swapaxes(metric, 1, 2))


def expected_stretch(metric, area):
    """SSP's per-triangle optimal stretch from the signal-stretch tensors (``lambda1, lambda2, theta``).

    Parameters
    ----------
    metric : (m, 2, 2) array_like of float
        Positive semi-definite tensors ``Gamma_T`` (e.g. from :func:`.signal_metric.signal_metric_tensors`, blended with
        geometric stretch so none is singular).
    area : (m,) array_like of float
        Surface areas ``|T|`` (positive).

    Returns
    -------
    lambda1, lambda2 : (m,) float64 ndarrays
        Stretches of the surface-to-UV map along the eigenvectors, ``lambda1 >= lambda2 > 0``, normalised so
        the total UV area equals the surface area: ``sum lambda1 lambda2 |T| = sum |T|``.
    theta : (m,) float64 ndarray
        Angle in ``[0, pi)`` of the direction stretched by ``lambda1`` (the direction of strongest signal
        change) in the triangle's frame (see :func:`.signal_metric.signal_metric_tensors`).

    Raises
    ------
    ValueError
        If a tensor is singular (a triangle would collapse); blend in geometric stretch first.

    Notes
    -----
    ``lambda_i = c sqrt(g_i) (g1 g2)^(-1/8)`` with ``g_i`` the eigenvalues of ``Gamma_T / |T|``: the
    per-triangle minimizer of the L2 signal stretch at a fixed texel budget (module docstring).

    References
    ----------
    Sander et al. 2002; Sun et al. 2022, Sec. 5.2.2 ("their expected stretch lambda1, lambda2, theta").
    """
    area = np.asarray(area, dtype=np.float64)
    if area.ndim != 1 or not np.all(area > 0):
        raise ValueError("area must be a 1-D array of positive triangle areas")
    metric = _check_metric(metric, area.size)
    density = metric / area[:, None, None]
    eigval, eigvec = np.linalg.eigh(density)  # ascending
    g2, g1 = eigval[:, 0], eigval[:, 1]
    if not np.all(g2 > 0):
        raise ValueError(f"{int(np.sum(~(g2 > 0)))} metric tensors are singular: blend in geometric stretch")
    shape = (g1 * g2) ** -0.125
    lambda1 = np.sqrt(g1) * shape
    lambda2 = np.sqrt(g2) * shape
    c = np.sqrt(area.sum() / (lambda1 * lambda2 * area).sum())
    theta = np.mod(np.arctan2(eigvec[:, 1, 1], eigvec[:, 0, 1]), np.pi)
    return c * lambda1, c * lambda2, theta


def _energy_parts(U, orientation, edge_metric):
    """Total signed-to-orientation UV area, signal stretch sum and their gradients in U (per triangle)."""
    det = _det(U)
    B = inverse_2x2(U)
    BBt = B @ np.swapaxes(B, 1, 2)
    stretch = np.einsum("tij,tji->t", edge_metric, BBt)
    # d tr(M B B^T) / dU = -2 B^T M B B^T;  d det / dU = det U^-T.
    d_stretch = -2.0 * np.swapaxes(B, 1, 2) @ edge_metric @ BBt
    d_area = 0.5 * orientation[:, None, None] * det[:, None, None] * np.swapaxes(B, 1, 2)
    return 0.5 * orientation * det, stretch, d_area, d_stretch


def ssp_energy(V, F, uv, metric):
    """The scale-invariant L2 signal-stretch energy ``E_SSP`` of a UV map (module docstring).

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
    uv : (m, 3, 2) array_like of float
        The UV map to measure.
    metric : (m, 2, 2) array_like of float
        ``Gamma_T`` in each triangle's frame (:func:`.signal_metric.signal_metric_tensors`, usually blended).

    Returns
    -------
    float
        ``(sum |T^t| / sum |T|) * sum tr(A_T^-T Gamma_T A_T^-1)``; ``inf`` if a triangle with a positive
        definite tensor has zero UV area. Triangles with no surface area are ignored.

    References
    ----------
    Sander et al. 2002 (L2 signal stretch, normalised by the domain area).
    """
    V, F, uv = _check_mesh(V, F, uv)
    metric = _check_metric(metric, F.shape[0])
    X, area = _triangle_frames(V, F)
    valid = area > 0
    U = _uv_edges(uv)[valid]
    det = _det(U)
    with np.errstate(divide="ignore", invalid="ignore"):
        B = inverse_2x2(U)
        edge_metric = np.swapaxes(X[valid], 1, 2) @ metric[valid] @ X[valid]
        stretch = np.einsum("tij,tji->t", edge_metric, B @ np.swapaxes(B, 1, 2))
    if np.any(det == 0):
        return float("inf")
    return float(0.5 * np.abs(det).sum() / area[valid].sum() * stretch.sum())


@dataclass(frozen=True, eq=False)
class SSPResult:
    """Output of :func:`solve_ssp`.

    Attributes
    ----------
    uv : (m, 3, 2) float64 ndarray
        The SSP UV map per face corner, same charts and cuts as the input, total UV area equal to the input's.
    energy_history : (iterations + 1,) float64 ndarray
        ``E_SSP`` at the start and after every iteration (non-increasing).
    iterations : int
    converged : bool
        Whether the relative decrease fell below ``tol`` before ``max_iterations``.
    flipped : int
        Fitted triangles (surface area and input UV area) whose UV orientation differs from the input's (the
        line search keeps it 0).
    metric : (m, 2, 2) float64 ndarray
        The blended tensors that were minimized.
    """

    uv: np.ndarray
    energy_history: np.ndarray
    iterations: int
    converged: bool
    flipped: int
    metric: np.ndarray


def _largest_safe_step(U, dU, orientation):
    """Largest t such that orientation * det(U + s dU) > 0 for all s in [0, t) and all triangles."""
    c0 = orientation * _det(U)
    c1 = orientation * (U[:, 0, 0] * dU[:, 1, 1] + dU[:, 0, 0] * U[:, 1, 1]
                        - U[:, 0, 1] * dU[:, 1, 0] - dU[:, 0, 1] * U[:, 1, 0])
    c2 = orientation * _det(dU)
    t_max = np.inf
    # Roots of c2 t^2 + c1 t + c0 with c0 > 0: the first positive one bounds the step.
    linear = np.abs(c2) <= 1e-14 * (np.abs(c1) + np.abs(c0) / 1e6 + 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lin = np.where(linear & (c1 < 0), -c0 / c1, np.inf)
        disc = c1 * c1 - 4 * c2 * c0
        sq = np.sqrt(np.where(disc >= 0, disc, 0.0))
        q = -0.5 * (c1 + np.copysign(sq, c1))
        r1 = np.where(~linear & (disc >= 0), q / c2, np.inf)
        r2 = np.where(~linear & (disc >= 0), c0 / q, np.inf)
    for roots in (t_lin, r1, r2):
        positive = roots[np.isfinite(roots) & (roots > 0)]
        if positive.size:
            t_max = min(t_max, float(positive.min()))
    return t_max


def _has_uv_area(uv):
    """(m,) bool: the UV triangle's area exceeds 1e-10 of its longest edge squared (else it counts as collapsed)."""
    longest2 = np.max([((uv[:, (j + 1) % 3] - uv[:, j]) ** 2).sum(axis=1) for j in range(3)], axis=0)
    return np.abs(_det(_uv_edges(uv))) > 1e-10 * longest2


def solve_ssp(V, F, uv, texture=None, *, metric=None, geometric_weight=0.01, channels="all", max_iterations=1000,
              tol=1e-9, history_size=10, progress=None):
    """Signal-specialized UV map: minimize the L2 signal stretch from the input UVs, keeping its cuts.

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
    uv : (m, 3, 2) array_like of float
        Input UVs per face corner (start point; their charts and cuts are kept, each triangle keeps its
        orientation).
    texture : (h, w) or (h, w, c) array_like of float, optional
        The signal, mapped through ``uv``; needed unless ``metric`` is given.
    metric : (m, 2, 2) array_like of float, optional
        Precomputed :func:`.signal_metric.signal_metric_tensors` (unblended); ``geometric_weight`` is still applied.
    geometric_weight : float, optional
        Geometric-stretch blend relative to the mean signal density (module docstring); 0 is pure SSP,
        which lets constant-signal triangles collapse.
    channels : {"all", "luma"}, optional
        See :func:`.signal_metric.signal_metric_tensors`.
    max_iterations : int, optional
        L-BFGS iterations at most.
    tol : float, optional
        Stop when an iteration lowers ``log E_SSP`` by less than ``tol``.
    history_size : int, optional
        L-BFGS memory.
    progress : callable, optional
        Called as ``progress(done, total)`` after every iteration.

    Returns
    -------
    SSPResult

    Raises
    ------
    ValueError
        On bad input, or if no triangle has both surface area and UV area.

    Notes
    -----
    Triangles with no surface area or no input UV area (at most 1e-10 of the longest UV edge squared, as in
    :func:`ssp_targets`) are left out of the energy (the signal stretch of a collapsed UV triangle is unbounded,
    so the input would be an infinite start, and such a triangle holds no texels of the input anyway); their
    corners still move with their chart, and ``energy_history`` is the energy of the other triangles.

    References
    ----------
    Sander et al. 2002 (energy); Liu and Nocedal 1989 (L-BFGS); Smith and Schaefer 2015 (flip-free step
    bound).
    """
    V, F, uv, X, area, metric = run_generator(_iter_checked_problem(V, F, uv, texture, metric, geometric_weight,
                                                                    channels, "solve_ssp"))
    if int(max_iterations) < 1 or int(history_size) < 1:
        raise ValueError("max_iterations and history_size must be at least 1")
    if not tol >= 0:
        raise ValueError(f"tol must be non-negative, got {tol}")

    topology = uv_topology(F, uv)
    U_in = _uv_edges(uv)
    orientation = np.sign(_det(U_in))
    # A triangle the input gives no UV area has no texels to redistribute and an infinite energy at the start:
    # like a degenerate triangle of the mesh-wise stage it is left out, and its corners move with its chart.
    valid = (area > 0) & _has_uv_area(uv)
    if not valid.any():
        raise ValueError("no triangle has both surface area and UV area")
    corners = topology.corner_vertex[valid]
    orient = orientation[valid]
    edge_metric = np.swapaxes(X[valid], 1, 2) @ metric[valid] @ X[valid]
    total_area = area[valid].sum()
    n = topology.n_vertices

    def edges_of(x):
        p = x[corners]
        return np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)

    def value(x):
        U = edges_of(x)
        if np.any(orient * _det(U) <= 0):
            return np.inf
        uv_area, stretch, _, _ = _energy_parts(U, orient, edge_metric)
        return float(np.log(uv_area.sum() / total_area) + np.log(stretch.sum()))

    def value_and_gradient(x):
        U = edges_of(x)
        uv_area, stretch, d_area, d_stretch = _energy_parts(U, orient, edge_metric)
        dU = d_area / uv_area.sum() + d_stretch / stretch.sum()  # (t, 2, 2), columns: edges 1 and 2
        grad = np.zeros((n, 2))
        np.add.at(grad, corners[:, 1], dU[:, :, 0])
        np.add.at(grad, corners[:, 2], dU[:, :, 1])
        np.add.at(grad, corners[:, 0], -dU[:, :, 0] - dU[:, :, 1])
        return float(np.log(uv_area.sum() / total_area) + np.log(stretch.sum())), grad.ravel()

    x = topology.vertex_uv.copy()
    f, g = value_and_gradient(x)
    history = [f]
    s_list, y_list = [], []
    edge_scale = np.sqrt(0.5 * np.abs(_det(U_in[valid])).mean())
    converged = False
    iteration = 0
    for iteration in range(1, int(max_iterations) + 1):
        # Two-loop recursion for the L-BFGS direction.
        q = -g
        alphas = []
        for s, y in reversed(list(zip(s_list, y_list))):
            a = (s @ q) / (y @ s)
            alphas.append(a)
            q = q - a * y
        if s_list:
            q *= (s_list[-1] @ y_list[-1]) / (y_list[-1] @ y_list[-1])
        else:
            q *= edge_scale / max(np.abs(g).max(), np.finfo(float).tiny) * 0.1
        for (s, y), a in zip(zip(s_list, y_list), reversed(alphas)):
            b = (y @ q) / (y @ s)
            q = q + (a - b) * s
        direction = q
        slope = float(g @ direction)
        if not slope < 0:  # not a descent direction: restart from steepest descent
            s_list.clear()
            y_list.clear()
            direction = -g * edge_scale / max(np.abs(g).max(), np.finfo(float).tiny) * 0.1
            slope = float(g @ direction)
            if not slope < 0:
                converged = True
                break
        t_max = _largest_safe_step(edges_of(x), edges_of(direction.reshape(n, 2)), orient)
        t = min(1.0, 0.9 * t_max)
        accepted = False
        for _ in range(50):
            trial = x.ravel() + t * direction
            f_trial = value(trial.reshape(n, 2))
            if f_trial <= f + 1e-4 * t * slope:
                accepted = True
                break
            t *= 0.5
        if not accepted:
            converged = True  # no decrease possible at round-off level
            break
        x_new = trial.reshape(n, 2)
        f_new, g_new = value_and_gradient(x_new)
        s, y = x_new.ravel() - x.ravel(), g_new - g
        if s @ y > 1e-12 * np.sqrt((s @ s) * (y @ y)):
            s_list.append(s)
            y_list.append(y)
            if len(s_list) > int(history_size):
                s_list.pop(0)
                y_list.pop(0)
        decrease = f - f_new
        x, f, g = x_new, f_new, g_new
        history.append(f)
        if progress is not None:
            progress(iteration, int(max_iterations))
        if decrease < tol:
            converged = True
            break

    # Gauge: the energy ignores translation and scale; give back the input's total UV area and keep every
    # chart's UV centroid.
    new_uv = topology.corner_uv(x)
    scale = np.sqrt(np.abs(_det(U_in)).sum() / np.abs(_det(_uv_edges(new_uv))).sum())
    face_chart = topology.face_chart
    counts = np.bincount(face_chart, minlength=topology.n_charts).astype(np.float64)
    centre_in = np.stack([np.bincount(face_chart, uv[:, :, d].mean(axis=1), topology.n_charts) for d in (0, 1)], 1)
    centre_new = np.stack([np.bincount(face_chart, new_uv[:, :, d].mean(axis=1), topology.n_charts)
                           for d in (0, 1)], 1)
    centre_in /= counts[:, None]
    centre_new /= counts[:, None]
    new_uv = (new_uv - centre_new[face_chart][:, None]) * scale + centre_in[face_chart][:, None]

    flipped = int(np.sum(valid & (np.sign(_det(_uv_edges(new_uv))) != orientation)))
    # history holds log((sum |T^t| / sum |T|) * sum tr), so its exponential is E_SSP itself.
    return SSPResult(uv=new_uv, energy_history=np.exp(np.asarray(history)), iterations=iteration,
                     converged=converged, flipped=flipped, metric=metric)


def ssp_targets(V, F, uv, texture=None, *, metric=None, geometric_weight=0.01, channels="all"):
    """SSP's expected stretch as targets of the mesh-wise stage with ``w_R = 0`` (SSPOP, Sec. 5.2.2).

    :func:`iter_ssp_targets` is the same computation as a generator that hands control back while it runs.

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
    uv : (m, 3, 2) array_like of float
        Input UVs; the mesh-wise map phi acts on them.
    texture : (h, w) or (h, w, c) array_like of float, optional
        Needed unless ``metric`` is given.
    metric : (m, 2, 2) array_like of float, optional
        Precomputed :func:`.signal_metric.signal_metric_tensors` (unblended).
    geometric_weight : float, optional
        Blend of geometric stretch (module docstring).
    channels : {"all", "luma"}, optional

    Returns
    -------
    params : (m, 4) float64 ndarray
        ``(alpha, lambda1, lambda2, beta)`` rows for ``core.meshwise.solve_meshwise``: ``R(alpha) S`` with
        ``S = V(beta) diag(lambda1, lambda2) V(beta)^T`` the stretch of ``phi = A_T A_in^-1``, where ``A_T``
        is SSP's optimal surface-to-UV map of triangle T and ``A_in`` the input's. ``alpha = 0``: the
        rotation is free (``w_R = 0``). Scaled into Eq. 14's box: the largest ``lambda1`` is 1 (see Notes).
        Triangles degenerate in 3D or in the input UVs get ``(0, 1, 1, 0)`` (the mesh-wise stage does not
        fit them).
    w_R : (m,) float64 ndarray
        Zeros.
    w_S : (m,) float64 ndarray
        Ones.

    Notes
    -----
    Since ``A_T = c (g1 g2)^(-1/8) G^(1/2)`` is symmetric, the stretch of ``A_T A_in^-1`` is
    ``c (g1 g2)^(-1/8) (A_in^-T G A_in^-1)^(1/2)``: the signal tensor seen in input-UV coordinates, square
    rooted. The common factor ``c`` does not change SSP's optimum (the texture resolution is set by the cost
    afterwards) but the mesh-wise solver is not scale-free (its flip barrier acts below
    ``0.5 min(1, det S_bar)``), so the targets are scaled like the triangle-wise stage's, ``lambda <= 1``
    (Eq. 14); with targets that keep the input's UV area the barrier dominates and SSPOP's signal stretch
    ``E_SSP`` comes out far above the input's (docs/DECISIONS.md).

    References
    ----------
    Sun et al. 2022, Sec. 5.2.2 (SSPOP), Eq. 16-19; Sander et al. 2002.
    """
    return run_generator(iter_ssp_targets(V, F, uv, texture, metric=metric, geometric_weight=geometric_weight,
                                          channels=channels))


def iter_ssp_targets(V, F, uv, texture=None, *, metric=None, geometric_weight=0.01, channels="all"):
    """Generator form of :func:`ssp_targets`: yields ``(done, total)`` and returns ``(params, w_R, w_S)``.

    The yields are those of :func:`.signal_metric.iter_signal_metric_tensors` (none when ``metric`` is given);
    :func:`ssp_targets` is this generator driven to the end. Use ``params, w_R, w_S = yield from
    iter_ssp_targets(...)`` in a pipeline generator, or drive it one step per timer tick.
    """
    V, F, uv, X, area, metric = yield from _iter_checked_problem(V, F, uv, texture, metric, geometric_weight,
                                                                 channels, "ssp_targets")
    m = F.shape[0]
    U_in = _uv_edges(uv)
    valid = (area > 0) & _has_uv_area(uv)

    params = np.zeros((m, 4))
    params[:, 1:3] = 1.0
    if valid.any():
        density = metric[valid] / area[valid, None, None]
        g = np.linalg.eigvalsh(density)
        if not np.all(g[:, 0] > 0):
            raise ValueError("singular metric tensors: use geometric_weight > 0")
        shape = (g[:, 0] * g[:, 1]) ** -0.125
        # A_in^-1 = X U_in^-1, so H = A_in^-T G A_in^-1 = U_in^-T (X^T G X) U_in^-1.
        U_inv = inverse_2x2(U_in[valid])
        Xv = X[valid]
        H = np.swapaxes(U_inv, 1, 2) @ np.swapaxes(Xv, 1, 2) @ density @ Xv @ U_inv
        H = 0.5 * (H + np.swapaxes(H, 1, 2))
        eigval, eigvec = np.linalg.eigh(H)
        lam1 = np.sqrt(eigval[:, 1]) * shape
        lam2 = np.sqrt(eigval[:, 0]) * shape
        params[valid, 1] = lam1 / lam1.max()
        params[valid, 2] = lam2 / lam1.max()
        params[valid, 3] = np.mod(np.arctan2(eigvec[:, 1, 1], eigvec[:, 0, 1]), np.pi)
    return params, np.zeros(m), np.ones(m)
