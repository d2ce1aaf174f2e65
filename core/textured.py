"""Which triangles show texture of their own: the texels their bilinear lookups read are not all equal.

A triangle all of whose lookups read one value shows no texture of its own: it renders the same whatever texels
it is given. :func:`textured_triangles` tells the textured triangles from the others, exactly for bilinear lookups
(Eq. 9, REPEAT) and on every plane of a material's stack (:func:`.loss_planes.texture_planes`), for

* the mesh-wise fit's targets: the texel floor and the signal-stretch blend apply to textured triangles only
  (:meth:`.trianglewise_result.TrianglewiseResult.fit_targets`, docs/DECISIONS.md);
* the bound's fractions: the share of textured triangles whose E exceeds epsilon at the fit's targets and after
  the fit (:func:`above_bound`; the pipeline's report, ``bridge.baselines`` and ``bench.compare``).

The test looks at the triangle's own texels, unlike :attr:`.loss.TriangleProblem.is_constant`, which looks at
every texel its view can read under a shrink. :func:`iter_textured_triangles` hands control back after each
slice of :data:`TEXTURED_SLICE` faces, so that an interface driving it stays responsive.

References
----------
Sun et al. 2022, Sec. 4.1.1 (the loss E, Eq. 3, 5, 8-11), Eq. 7 (the bound epsilon), Eq. 9 (bilinear lookup).
"""
import numpy as np

from ._jit import njit
from .loss_planes import texture_planes
from .progress import run_generator

__all__ = ["textured_triangles", "iter_textured_triangles", "above_bound"]

#: Faces :func:`iter_textured_triangles` tests in one plane between two yields (a few hundredths of a second on a
#: 2k texture).
TEXTURED_SLICE = 2048


def above_bound(uv, luma, epsilon, *, textured=None, **losses):
    """Fractions of the textured triangles whose loss E exceeds epsilon, for each named set of losses.

    Parameters
    ----------
    uv : (k, 3, 2) array_like of float64
        Input per-corner UVs of the triangles the losses belong to.
    luma : (h, w) or (h, w, c) array_like, or sequence of (h_i, w_i) ndarrays
        Their texture, or the stack of planes the losses were measured on (:func:`.loss_planes.texture_planes`).
    epsilon : float
        The bound of Eq. 7.
    textured : (k,) array_like of bool, optional
        :func:`textured_triangles` of ``uv`` and ``luma`` when the caller has it already (``luma`` is then not
        read).
    **losses : (k,) array_like of float
        E per triangle, e.g. ``targets=`` at the mesh-wise fit's targets and ``fit=`` after the fit; NaN and
        infinite values count as above the bound.

    Returns
    -------
    dict
        ``textured_triangles`` (how many of the k are textured, :func:`textured_triangles`) and, per keyword of
        ``losses``, the fraction of those whose E is above ``epsilon`` (0 when none is textured).

    Notes
    -----
    Untextured triangles are left out: their E is 0 under any deformation the box allows, so they would only
    dilute the fraction. The fraction at the targets shows how far the post-processing of the targets (the
    signal-stretch blend above all, then the texel floor) moves them past the bound the triangle-wise search
    kept (Sec. 4.1); the fraction after the fit, how far the fit moves the triangles off their targets.
    """
    if textured is None:
        textured = textured_triangles(uv, luma)
    textured = np.asarray(textured, dtype=bool)
    if textured.shape != (len(uv),):
        raise ValueError(f"textured must have a value per triangle, shape ({len(uv)},), got {textured.shape}")
    count = int(np.count_nonzero(textured))
    out = {"textured_triangles": count}
    for name, values in losses.items():
        values = np.asarray(values, dtype=np.float64)
        if values.shape != textured.shape:
            raise ValueError(f"{name} must have a loss per triangle, shape {textured.shape}, got {values.shape}")
        out[name] = float(np.mean(~(values[textured] <= epsilon))) if count else 0.0
    return out


def textured_triangles(uv, luma, *, per_plane=False):
    """Which triangles show texture of their own: the texels their bilinear lookups read are not all equal.

    Parameters
    ----------
    uv : (m, 3, 2) array_like of float64
        Per-corner UVs.
    luma : (h, w) or (h, w, c) array_like, or sequence of (h_i, w_i) ndarrays
        Texture (row 0 = bottom), as for :func:`.loss.prepare_triangles`, or a stack of planes each on its own texel
        grid (:func:`.loss_planes.texture_planes`); it repeats outside ``[0, 1]^2``.
    per_plane : bool, optional
        Give the answer for every plane of the stack separately.

    Returns
    -------
    (m,) ndarray of bool, or (p, m) with ``per_plane``
        False where, in every plane (in plane ``j`` for row ``j``), one value fills every texel any point of the
        triangle reads (constant texture, or a triangle inside a flat area whose neighbours may differ).

    Notes
    -----
    Exact for bilinear lookups: texel ``t`` is read when some point of the triangle lies less than one texel
    from its centre in both axes.
    """
    return run_generator(iter_textured_triangles(uv, luma, per_plane=per_plane))


def iter_textured_triangles(uv, luma, *, per_plane=False):
    """Generator form of :func:`textured_triangles` (same parameters and value): yields ``(done, total)`` pairs of
    a face and a plane tested, after each slice of :data:`TEXTURED_SLICE` faces of each plane, so that a caller
    driving an interface can hand control back between slices."""
    planes = texture_planes(luma)
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2), got {uv.shape}")
    if not np.isfinite(uv).all():
        raise ValueError("uv must be finite")
    m = len(uv)
    textured = np.zeros((len(planes), m), dtype=bool)
    for number, plane in enumerate(planes):
        h, w = plane.shape
        texels = np.ascontiguousarray(uv * np.array([w, h], dtype=np.float64))
        for start in range(0, m, TEXTURED_SLICE):
            stop = min(m, start + TEXTURED_SLICE)
            textured[number, start:stop] = _textured_kernel(plane, texels[start:stop])
            yield number * m + stop, len(planes) * m
    return textured if per_plane else textured.any(axis=0)


# ---------------------------------------------------------------------------------------------------- kernels
@njit
def _triangle_reads_one_value(luma, a, b, c):
    """True when every texel that a bilinear lookup at a point of triangle ``abc`` (texel units) reads has the
    same luma. A lookup at ``x`` reads texel ``t`` (centre ``t + 1/2``) when ``|x - t - 1/2|_inf < 1``, so
    ``t`` is read when the triangle meets the open square of half-width 1 around that centre; separating
    axes: x, y and the edge normals (an edge of zero length has none)."""
    h, w = luma.shape
    xs = (a[0], b[0], c[0])
    ys = (a[1], b[1], c[1])
    corners = (a, b, c)
    normals = np.zeros((3, 2))
    for e in range(3):
        p, q = corners[e], corners[(e + 1) % 3]
        normals[e, 0] = q[1] - p[1]
        normals[e, 1] = p[0] - q[0]
    first = True
    value = 0.0
    for ty in range(int(np.floor(min(ys) - 1.5)), int(np.ceil(max(ys) + 0.5)) + 1):
        if not (min(ys) < ty + 1.5 and max(ys) > ty - 0.5):
            continue
        for tx in range(int(np.floor(min(xs) - 1.5)), int(np.ceil(max(xs) + 0.5)) + 1):
            if not (min(xs) < tx + 1.5 and max(xs) > tx - 0.5):
                continue
            separated = False
            for e in range(3):
                nx, ny = normals[e, 0], normals[e, 1]
                if nx == 0.0 and ny == 0.0:
                    continue
                low = high = nx * a[0] + ny * a[1]
                for k in range(1, 3):
                    d = nx * corners[k][0] + ny * corners[k][1]
                    low, high = min(low, d), max(high, d)
                centre = nx * (tx + 0.5) + ny * (ty + 0.5)
                reach = abs(nx) + abs(ny)
                if high <= centre - reach or low >= centre + reach:
                    separated = True
                    break
            if separated:
                continue
            texel = luma[ty % h, tx % w]
            if first:
                value, first = texel, False
            elif texel != value:
                return False
    return True


@njit
def _textured_kernel(luma, corners):
    textured = np.empty(corners.shape[0], dtype=np.bool_)
    for f in range(corners.shape[0]):
        textured[f] = not _triangle_reads_one_value(luma, corners[f, 0], corners[f, 1], corners[f, 2])
    return textured
