# SPDX-License-Identifier: GPL-3.0-or-later
"""Signal-stretch metric tensors of Signal-Specialized Parametrization (Sander, Gortler, Snyder, Hoppe 2002).

For every triangle T, in an orthonormal frame of its plane,

    Gamma_T = integral_T (grad f)(grad f)^T dA          (2 x 2, symmetric positive semi-definite),

with ``f`` the texture mapped onto the surface through the input UVs. Pre-integrated once, it gives the L2
signal stretch of any map ``x -> A_T x`` of T to UV as ``tr(A_T^-T Gamma_T A_T^-1)``: the energy SSP minimizes
and the expected stretch it derives (:mod:`.ssp`), towards which our own mesh-wise targets' areas are drawn
too (:meth:`.trianglewise_result.TrianglewiseResult.fit_targets`).

Decision (not in SGSH02): ``Gamma_T`` is integrated by the midpoint rule on a regular subdivision of T into
``k^2`` equal triangles, ``k`` chosen so a sub-triangle covers at most a quarter texel of the input texture
(capped by ``max_level``); the gradient is that of the bilinear interpolant the renderer sees (Eq. 9), exact
inside each cell between texel centres. Colour textures sum the tensors of R, G and B (SGSH02's treatment of
multi-channel signals) unless ``channels="luma"``. :func:`iter_signal_metric_tensors` is the same computation
as a generator that hands control back while it runs; the tensors do not depend on its slicing.

References
----------
P. V. Sander, S. J. Gortler, J. Snyder, H. Hoppe, "Signal-Specialized Parametrization", EGWR 2002, Sec. 3-4.
Sun et al. 2022, Eq. 9 (bilinear lookup), Sec. 5.2.2 (SSP).
"""
import numpy as np

from .charts import validate_faces_and_uv
from .deformation import inverse_2x2
from .evaluation import _triangle_frames
from .gmsd import luma
from .mesh import check_mesh
from .progress import run_generator

__all__ = ["signal_metric_tensors", "iter_signal_metric_tensors"]

# The generator forms hand control back after each slice of work, so a modal operator driving them keeps the
# interface responsive: a slice of faces holds at most this many integration points (a few tens of ms and tens
# of MB), a band of texture rows at most this many texels (its check and float64 copy, a few ms).
_POINTS_PER_SLICE = 1 << 16
_TEXELS_PER_SLICE = 1 << 20


def _check_mesh(V, F, uv):
    """:func:`.mesh.check_mesh` (shapes, index range), finite ``V``, and :func:`.charts.validate_faces_and_uv`."""
    V, F = check_mesh(V, F)
    if not np.all(np.isfinite(V)):
        raise ValueError("V holds NaN or infinite coordinates")
    F, uv = validate_faces_and_uv(F, uv)
    return V, F, uv


def _checked_texture(texture, channels):
    """``texture`` as an array, its shape and ``channels`` checked; and the empty signal array for it.

    Returns
    -------
    texture : ndarray
    signal : (h, w, 1) or (h, w, 3) float64 ndarray
        Uninitialized; :func:`_fill_signal` fills it band by band. One contiguous float64 array:
        :func:`_bilinear_gradient` gathers from its flat rows once per slice.
    """
    texture = np.asarray(texture)
    if texture.ndim not in (2, 3) or texture.shape[0] < 2 or texture.shape[1] < 2:
        raise ValueError(f"texture must have shape (h, w) or (h, w, c) with h, w >= 2, got {texture.shape}")
    if channels not in ("all", "luma"):
        raise ValueError(f"channels must be 'all' or 'luma', got {channels!r}")
    c = 1 if texture.ndim == 2 else texture.shape[2]
    if c not in (1, 3, 4):
        raise ValueError(f"expected 1, 3 or 4 texture channels, got {c}")
    signal_channels = 3 if c > 1 and channels == "all" else 1
    return texture, np.empty(texture.shape[:2] + (signal_channels,), dtype=np.float64)


def _fill_signal(texture, channels, signal, rows):
    """Check that the texture ``rows`` (a slice) are finite and write their signal into ``signal[rows]``: the
    channels as float64 (alpha dropped), or their Rec. 601 luma with ``channels="luma"``."""
    band = texture[rows]
    if not np.all(np.isfinite(band)):
        raise ValueError("texture holds NaN or infinite values")
    if band.ndim == 2:
        signal[rows, :, 0] = band
    elif band.shape[2] == 1:
        signal[rows] = band
    elif channels == "luma":
        signal[rows, :, 0] = luma(band)
    else:
        signal[rows] = band[..., :3]


def _subdivision_barycentrics(k):
    """Centroids of the k^2 equal sub-triangles of a k-subdivided triangle, as barycentrics (k^2, 3)."""
    points = []
    for i in range(k):
        for j in range(k - i):
            points.append(((i + 1 / 3) / k, (j + 1 / 3) / k))
            if i + j <= k - 2:
                points.append(((i + 2 / 3) / k, (j + 2 / 3) / k))
    st = np.array(points)
    return np.column_stack([1.0 - st.sum(axis=1), st])


def _bilinear_gradient(texture, points):
    """Gradient of the bilinear interpolant (Eq. 9, REPEAT) at texel-space points, per channel.

    Returns (p, c, 2): derivatives with respect to texel coordinates x = u w, y = v h.
    """
    h, w = texture.shape[:2]
    x = points[:, 0] - 0.5
    y = points[:, 1] - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    ix0 = x0.astype(np.int64) % w
    row0 = (y0.astype(np.int64) % h) * w
    ix1 = (ix0 + 1) % w
    row1 = (row0 + w) % (h * w)
    flat = texture.reshape(h * w, -1)  # flat rows are much faster to gather than 2-D fancy indices
    t00 = flat[row0 + ix0]
    t10 = flat[row0 + ix1]
    t01 = flat[row1 + ix0]
    t11 = flat[row1 + ix1]
    gx = (1 - fy) * (t10 - t00) + fy * (t11 - t01)
    gy = (1 - fx) * (t01 - t00) + fx * (t11 - t10)
    return np.stack([gx, gy], axis=-1)


def _uv_edges(uv):
    return np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)  # columns: UV edges


def _det(M):
    return M[..., 0, 0] * M[..., 1, 1] - M[..., 0, 1] * M[..., 1, 0]


def signal_metric_tensors(V, F, uv, texture, *, channels="all", samples_per_texel=4.0, max_level=16):
    """Signal-stretch metric tensor of every triangle, ``Gamma_T = integral_T (grad f)(grad f)^T dA``.

    :func:`iter_signal_metric_tensors` is the same computation as a generator that hands control back while it
    runs.

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
    uv : (m, 3, 2) array_like of float
        The UVs through which ``texture`` is mapped onto the surface (the input parameterization).
    texture : (h, w) or (h, w, c) array_like of float
        Row 0 is the bottom (v = 0); bilinear with REPEAT, as everywhere in the package.
    channels : {"all", "luma"}, optional
        ``"all"`` sums the tensors of the colour channels (alpha ignored); ``"luma"`` uses Rec. 601 luma.
    samples_per_texel : float, optional
        Integration points per texel of UV area (the subdivision level is
        ``ceil(sqrt(samples_per_texel * texel_area))``).
    max_level : int, optional
        Cap on the subdivision level (at most ``max_level^2`` points per triangle).

    Returns
    -------
    (m, 2, 2) float64 ndarray
        Symmetric positive semi-definite tensors in each triangle's frame: first axis along the edge from
        corner 0 to corner 1, second axis in the plane, towards corner 2. Units: signal^2 (a gradient per
        unit length squared, times an area). Zero for triangles with no surface area.

    References
    ----------
    Sander et al. 2002, Sec. 3-4 (signal stretch, pre-integrated metric tensor); Sun et al. 2022, Eq. 9.
    """
    return run_generator(iter_signal_metric_tensors(V, F, uv, texture, channels=channels,
                                                    samples_per_texel=samples_per_texel, max_level=max_level))


def iter_signal_metric_tensors(V, F, uv, texture, *, channels="all", samples_per_texel=4.0, max_level=16):
    """Generator form of :func:`signal_metric_tensors`: yields ``(done, total)`` and returns the tensors.

    ``total`` is the number of triangles with surface area (the ones integrated), ``done`` how many of them are
    integrated so far. It yields ``(0, total)`` after each band of texture rows it checks and converts, and
    ``(done, total)`` after each slice of triangles (at most ``_POINTS_PER_SLICE`` integration points); the
    result does not depend on the slicing, it is bit for bit that of one pass. Use
    ``metric = yield from iter_signal_metric_tensors(...)`` in a pipeline generator.
    """
    V, F, uv = _check_mesh(V, F, uv)
    texture, signal = _checked_texture(texture, channels)
    if not samples_per_texel > 0:
        raise ValueError(f"samples_per_texel must be positive, got {samples_per_texel}")
    if int(max_level) < 1:
        raise ValueError(f"max_level must be at least 1, got {max_level}")
    h, w = signal.shape[:2]
    m = F.shape[0]
    X, area = _triangle_frames(V, F)
    U = _uv_edges(uv)
    valid = area > 0
    total = int(np.count_nonzero(valid))
    # Map from the surface frame to UV: A = U X^-1 (defined wherever the surface triangle is not degenerate).
    A = np.zeros((m, 2, 2))
    A[valid] = U[valid] @ inverse_2x2(X[valid])

    rows_per_band = max(1, _TEXELS_PER_SLICE // w)
    for start in range(0, h, rows_per_band):
        _fill_signal(texture, channels, signal, slice(start, start + rows_per_band))
        yield 0, total

    texel_area = 0.5 * np.abs(_det(U)) * w * h
    level = np.clip(np.ceil(np.sqrt(samples_per_texel * texel_area)), 1, int(max_level)).astype(np.int64)
    texel_scale = np.array([w, h], dtype=np.float64)
    gamma_uv = np.zeros((m, 2, 2))  # mean of (grad_uv f)(grad_uv f)^T over the triangle
    done = 0
    for k in np.unique(level[valid]):
        bary = _subdivision_barycentrics(int(k))
        faces = np.flatnonzero(valid & (level == k))
        per_slice = max(1, _POINTS_PER_SLICE // bary.shape[0])
        for start in range(0, faces.size, per_slice):
            chunk = faces[start:start + per_slice]
            points = np.einsum("sk,tkd->tsd", bary, uv[chunk]) * texel_scale  # (t, s, 2) texel coords
            grad = _bilinear_gradient(signal, points.reshape(-1, 2)) * texel_scale  # d/du = w d/dx
            grad = grad.reshape(chunk.size, bary.shape[0], -1, 2)
            gamma_uv[chunk] = np.einsum("tscd,tsce->tde", grad, grad) / bary.shape[0]
            done += chunk.size
            yield done, total
    # grad_x f = A^T grad_uv f, so Gamma = |T| A^T E[g g^T] A.
    return area[:, None, None] * (np.swapaxes(A, 1, 2) @ gamma_uv @ A)
