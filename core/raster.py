"""The rendering H of Eq. 8-9 as an exact sparse linear map from texel values to screen pixels.

Pipeline for one screen pixel (no lighting, one sample at the pixel centre): pixel centre -> ray along
``-N`` (orthographic) -> nearest visible triangle of the drawn set and its barycentrics -> UV of that point
(per-corner UVs of the triangle) -> bilinear weights of 4 texels (Eq. 9). Pixels that hit nothing are
background. Everything after the ray cast is linear in the texel values, so a render is
``screen[pixel] = sum_k weights[pixel, k] * texture.flat[texels[pixel, k]]``.

Texture convention (shared by the package): a texture is ``(h, w)`` or ``(h, w, c)``, row 0 is the BOTTOM
(``v = 0``), as in Blender's ``image.pixels``. Texel coordinates of a UV point are ``(u * w, v * h)``; texel
``(ix, iy)`` covers ``[ix, ix + 1) x [iy, iy + 1)`` and its centre is ``(ix + 0.5, iy + 0.5)`` (OpenGL and
Blender). Bilinear interpolation reads the 4 texels around ``(u * w - 0.5, v * h - 0.5)`` and wraps with
REPEAT. The flat texel index of ``(ix, iy)`` is ``iy * w + ix`` (``texture.reshape(h * w, ...)``).

Screen convention: see :mod:`.camera` (row 0 is the bottom of the view, pixel centres sampled).
"""
from dataclasses import dataclass

import numpy as np

from ._jit import njit
from .camera import CLIP_FAR, CLIP_NEAR, EYE_DISTANCE, TriangleCameras
from .mesh import check_mesh  # re-exported: loss and trianglewise import it from here

__all__ = ["Raster", "check_mesh", "rasterize", "texel_coordinates", "bilinear_weights", "sample_bilinear",
           "deform_points", "screen_operator"]

# A pixel centre on a shared edge must land in one of the two triangles despite round-off.
_INSIDE_TOLERANCE = 1e-12
# Heights along N (relative to the barycentre) that the near/far planes of Algorithm 1 keep.
_HEIGHT_MAX = EYE_DISTANCE - CLIP_NEAR
_HEIGHT_MIN = EYE_DISTANCE - CLIP_FAR


@dataclass(frozen=True)
class Raster:
    """Which surface point each covered pixel sees.

    Attributes
    ----------
    pixel : (p,) ndarray of int64
        Flat pixel index ``i * n + j`` (row ``i`` from the bottom), ascending.
    face : (p,) ndarray of int64
        Triangle seen by the pixel.
    bary : (p, 3) ndarray of float64
        Barycentric coordinates of the seen point in that triangle (corners in ``F`` order).
    screen_pixels : int
    """

    pixel: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    screen_pixels: int


@njit
def _rasterize_kernel(V, F, draw, origin, right, up, normal, bounds, box, n):
    npix = n * n
    depth = np.full(npix, -np.inf)
    hit_face = np.full(npix, -1, np.int64)
    hit_bary = np.zeros((npix, 3))
    left, bottom = bounds[0], bounds[2]
    step = (bounds[1] - bounds[0]) / n
    xs = np.empty(3)
    ys = np.empty(3)
    hs = np.empty(3)
    # Pixels whose centre lies in the drawn box (the camera's ``box``).
    box_j0 = max(int(np.ceil((box[0] - left) / step - 0.5)), 0)
    box_j1 = min(int(np.floor((box[1] - left) / step - 0.5)), n - 1)
    box_i0 = max(int(np.ceil((box[2] - bottom) / step - 0.5)), 0)
    box_i1 = min(int(np.floor((box[3] - bottom) / step - 0.5)), n - 1)
    for t in range(draw.shape[0]):
        f = draw[t]
        for k in range(3):
            d0 = V[F[f, k], 0] - origin[0]
            d1 = V[F[f, k], 1] - origin[1]
            d2 = V[F[f, k], 2] - origin[2]
            xs[k] = d0 * right[0] + d1 * right[1] + d2 * right[2]
            ys[k] = d0 * up[0] + d1 * up[1] + d2 * up[2]
            hs[k] = d0 * normal[0] + d1 * normal[1] + d2 * normal[2]
        area2 = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (ys[1] - ys[0])
        if area2 == 0.0:
            continue  # seen edge-on: covers no pixel centre
        # Pixel columns j with centre x in [min x, max x], rows likewise.
        j0 = max(int(np.ceil((min(xs[0], xs[1], xs[2]) - left) / step - 0.5)), box_j0)
        j1 = min(int(np.floor((max(xs[0], xs[1], xs[2]) - left) / step - 0.5)), box_j1)
        i0 = max(int(np.ceil((min(ys[0], ys[1], ys[2]) - bottom) / step - 0.5)), box_i0)
        i1 = min(int(np.floor((max(ys[0], ys[1], ys[2]) - bottom) / step - 0.5)), box_i1)
        for i in range(i0, i1 + 1):
            y = bottom + (i + 0.5) * step
            for j in range(j0, j1 + 1):
                x = left + (j + 0.5) * step
                b1 = ((x - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (y - ys[0])) / area2
                b2 = ((xs[1] - xs[0]) * (y - ys[0]) - (x - xs[0]) * (ys[1] - ys[0])) / area2
                b0 = 1.0 - b1 - b2
                if b0 < -_INSIDE_TOLERANCE or b1 < -_INSIDE_TOLERANCE or b2 < -_INSIDE_TOLERANCE:
                    continue
                h = b0 * hs[0] + b1 * hs[1] + b2 * hs[2]
                if h > _HEIGHT_MAX or h < _HEIGHT_MIN:
                    continue
                p = i * n + j
                if h > depth[p]:
                    depth[p] = h
                    hit_face[p] = f
                    hit_bary[p, 0] = b0
                    hit_bary[p, 1] = b1
                    hit_bary[p, 2] = b2
    count = 0
    for p in range(npix):
        if hit_face[p] >= 0:
            count += 1
    pixel = np.empty(count, np.int64)
    face = np.empty(count, np.int64)
    bary = np.empty((count, 3))
    c = 0
    for p in range(npix):
        if hit_face[p] >= 0:
            pixel[c] = p
            face[c] = hit_face[p]
            bary[c, 0] = hit_bary[p, 0]
            bary[c, 1] = hit_bary[p, 1]
            bary[c, 2] = hit_bary[p, 2]
            c += 1
    return pixel, face, bary


def _rasterize_reference(V, F, draw, camera):
    """Plain numpy version of :func:`rasterize` (every triangle against every pixel centre)."""
    n = camera.screen_pixels
    origin, right, up, normal, bounds = (camera.origin[0], camera.right[0], camera.up[0], camera.normal[0],
                                         camera.bounds[0])
    step = (bounds[1] - bounds[0]) / n
    x = np.broadcast_to(bounds[0] + (np.arange(n) + 0.5) * step, (n, n)).reshape(-1)
    y = np.broadcast_to((bounds[2] + (np.arange(n) + 0.5) * step)[:, None], (n, n)).reshape(-1)
    depth = np.full(n * n, -np.inf)
    face = np.full(n * n, -1, np.int64)
    bary = np.zeros((n * n, 3))
    box = camera.box[0]
    in_box = (x >= box[0]) & (x <= box[1]) & (y >= box[2]) & (y <= box[3])
    for f in draw:
        d = V[F[f]] - origin
        xs, ys, hs = d @ right, d @ up, d @ normal
        area2 = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (ys[1] - ys[0])
        if area2 == 0.0:
            continue
        b1 = ((x - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (y - ys[0])) / area2
        b2 = ((xs[1] - xs[0]) * (y - ys[0]) - (x - xs[0]) * (ys[1] - ys[0])) / area2
        b0 = 1.0 - b1 - b2
        h = b0 * hs[0] + b1 * hs[1] + b2 * hs[2]
        inside = (b0 >= -_INSIDE_TOLERANCE) & (b1 >= -_INSIDE_TOLERANCE) & (b2 >= -_INSIDE_TOLERANCE)
        wins = in_box & inside & (h <= _HEIGHT_MAX) & (h >= _HEIGHT_MIN) & (h > depth)
        depth[wins] = h[wins]
        face[wins] = f
        bary[wins] = np.stack([b0, b1, b2], axis=1)[wins]
    hit = np.flatnonzero(face >= 0)
    return Raster(hit, face[hit], bary[hit], n)


def rasterize(V, F, draw, camera):
    """Ray-cast the pixel centres of one orthographic camera against a set of triangles.

    Only pixels whose centre lies in the camera's ``box`` (the drawn part of the window, :mod:`.camera`) are
    drawn. Each of them sees the drawn triangle nearest to the eye (largest height along ``N``) among those
    whose hit point lies between the near and far planes of Algorithm 1; both faces of a triangle are visible
    (no back-face culling, like Blender's workbench default). A pixel centre on a shared edge goes to one of
    the two triangles.

    Parameters
    ----------
    V : (n, 3) array_like of float64
    F : (m, 3) array_like of int64
    draw : (t,) array_like of int
        Triangles to draw (e.g. a one-ring).
    camera : TriangleCameras
        A batch of length 1.

    Returns
    -------
    Raster
    """
    V, F = check_mesh(V, F)
    draw = np.ascontiguousarray(draw, dtype=np.int64).reshape(-1)
    if draw.size and (draw.min() < 0 or draw.max() >= len(F)):
        raise ValueError("draw refers to triangles outside F")
    if not isinstance(camera, TriangleCameras) or len(camera) != 1:
        raise ValueError("camera must be a TriangleCameras batch of length 1 (cameras[i])")
    n = camera.screen_pixels
    if not camera.valid[0]:
        empty = np.zeros(0, np.int64)
        return Raster(empty, empty.copy(), np.zeros((0, 3)), n)
    pixel, face, bary = _rasterize_kernel(V, F, draw, camera.origin[0], camera.right[0], camera.up[0],
                                          camera.normal[0], camera.bounds[0], camera.box[0], n)
    return Raster(pixel, face, bary, n)


def texel_coordinates(uv, face, bary, texture_shape):
    """Texel-space position ``(u * w, v * h)`` of surface points given by face and barycentrics.

    Parameters
    ----------
    uv : (m, 3, 2) array_like of float64
        Per-corner UVs.
    face : (p,) array_like of int
    bary : (p, 3) array_like of float64
    texture_shape : tuple
        ``(h, w)`` or ``(h, w, c)``.

    Returns
    -------
    (p, 2) ndarray of float64
    """
    uv = np.asarray(uv, dtype=np.float64)
    h, w = texture_shape[:2]
    points = np.einsum("pk,pkd->pd", np.asarray(bary, dtype=np.float64), uv[np.asarray(face)])
    return points * np.array([w, h], dtype=np.float64)


def bilinear_weights(points, texture_shape):
    """The 4 texels and weights that bilinear interpolation (Eq. 9) reads at texel-space points.

    Parameters
    ----------
    points : (p, 2) array_like of float64
        Texel-space positions ``(u * w, v * h)``.
    texture_shape : tuple
        ``(h, w)`` or ``(h, w, c)``.

    Returns
    -------
    texels : (p, 4) ndarray of int64
        Flat texel indices ``iy * w + ix`` after REPEAT wrapping, corners in the order
        ``(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)``.
    weights : (p, 4) ndarray of float64
        Non-negative, summing to 1 per point.

    References
    ----------
    Sun et al. 2022, Eq. 9.
    """
    points = np.asarray(points, dtype=np.float64)
    h, w = texture_shape[:2]
    x = points[:, 0] - 0.5
    y = points[:, 1] - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    ix = np.stack([x0, x0 + 1, x0, x0 + 1], axis=1).astype(np.int64) % w
    iy = np.stack([y0, y0, y0 + 1, y0 + 1], axis=1).astype(np.int64) % h
    weights = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    return iy * w + ix, weights


def sample_bilinear(texture, points):
    """Bilinear, REPEAT-wrapped texture lookup at texel-space points.

    Parameters
    ----------
    texture : (h, w) or (h, w, c) array_like
    points : (p, 2) array_like of float64
        Texel-space positions ``(u * w, v * h)``.

    Returns
    -------
    (p,) or (p, c) ndarray of float64
    """
    texture = np.asarray(texture)
    texels, weights = bilinear_weights(points, texture.shape)
    flat = texture.reshape(texture.shape[0] * texture.shape[1], -1)
    # only the texels read are widened to float64: a 4096^2 RGBA float32 texture would otherwise be copied whole
    values = np.einsum("pk,pkc->pc", weights, flat[texels].astype(np.float64))
    return values[:, 0] if texture.ndim == 2 else values


def deform_points(points, jacobian, centre):
    """Apply ``x -> A (x - c) + c`` to texel-space points.

    Parameters
    ----------
    points : (p, 2) array_like of float64
    jacobian : (2, 2) array_like
        ``A = R S`` (see :func:`.deformation.jacobian`).
    centre : (2,) array_like
        Fixed point ``c`` in texel units.

    Returns
    -------
    (p, 2) ndarray of float64
    """
    points = np.asarray(points, dtype=np.float64)
    centre = np.asarray(centre, dtype=np.float64)
    return (points - centre) @ np.asarray(jacobian, dtype=np.float64).T + centre


def screen_operator(raster, points, texture_shape):
    """The render as a sparse matrix from flat texels to flat screen pixels.

    Parameters
    ----------
    raster : Raster
    points : (p, 2) array_like
        Texel-space position seen by each covered pixel (``texel_coordinates`` of the raster, possibly
        deformed).
    texture_shape : tuple
        ``(h, w)`` or ``(h, w, c)``.

    Returns
    -------
    scipy.sparse.csr_matrix of shape (n * n, h * w)
        ``screen = H @ texture.reshape(h * w, ...)``; rows of background pixels are empty.

    References
    ----------
    Sun et al. 2022, Eq. 8-9.
    """
    import scipy.sparse

    texels, weights = bilinear_weights(points, texture_shape)
    n = raster.screen_pixels
    rows = np.repeat(raster.pixel, 4)
    h, w = texture_shape[:2]
    return scipy.sparse.csr_matrix((weights.reshape(-1), (rows, texels.reshape(-1))), shape=(n * n, h * w))
