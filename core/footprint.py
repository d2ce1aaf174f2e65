"""Texels that bilinear lookups read but a bake by texel centres leaves empty.

A bake writes the texels whose centres lie inside a target triangle (Cycles does). A bilinear lookup (Eq. 9) at a
point reads the four texels whose centres are less than one texel away in each axis, so a triangle narrower
than a texel is drawn from texels that no triangle covers, and a chart shrunk below a texel owns no texel at all.
A margin that copies the nearest covered texel gives those texels the colour of some other chart, and without a
margin they keep the clear colour: thin strips render as dark seams. The least-squares re-bake of Eq. 11 gives
every texel a screen pixel reads a value; :func:`footprint_texels` finds the texels a bake left empty that a
triangle reads, with the point of the nearest such triangle closest to the texel centre, so the caller can write
the source colour of that point there.
"""
import numpy as np

from ._jit import njit

__all__ = ["footprint_texels"]


@njit
def _closest_barycentric(px, py, ax, ay, bx, by, cx, cy):
    """Barycentric coordinates of the point of triangle abc nearest to p (Ericson, Real-Time Collision
    Detection, 5.1.5), for a triangle of non-zero area."""
    abx, aby, acx, acy = bx - ax, by - ay, cx - ax, cy - ay
    apx, apy = px - ax, py - ay
    d1 = abx * apx + aby * apy
    d2 = acx * apx + acy * apy
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx, bpy = px - bx, py - by
    d3 = abx * bpx + aby * bpy
    d4 = acx * bpx + acy * bpy
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cpx, cpy = px - cx, py - cy
    d5 = abx * cpx + aby * cpy
    d6 = acx * cpx + acy * cpy
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    denominator = 1.0 / (va + vb + vc)
    v = vb * denominator
    w = vc * denominator
    return 1.0 - v - w, v, w


@njit
def _footprint_kernel(corners, covered, count_only, out_texel, out_face, out_squared_distance, out_bary):
    """Count (``count_only``) or list the (uncovered texel, face) pairs closer than one texel."""
    height, width = covered.shape
    found = 0
    for f in range(corners.shape[0]):
        ax, ay = corners[f, 0, 0], corners[f, 0, 1]
        bx, by = corners[f, 1, 0], corners[f, 1, 1]
        cx, cy = corners[f, 2, 0], corners[f, 2, 1]
        if (bx - ax) * (cy - ay) - (by - ay) * (cx - ax) == 0.0:
            continue  # no area: never drawn
        x0 = int(np.ceil(min(ax, bx, cx) - 1.0))
        x1 = int(np.floor(max(ax, bx, cx) + 1.0))
        y0 = int(np.ceil(min(ay, by, cy) - 1.0))
        y1 = int(np.floor(max(ay, by, cy) + 1.0))
        for y in range(y0, y1 + 1):
            row = y % height
            for x in range(x0, x1 + 1):
                column = x % width
                if covered[row, column]:
                    continue
                u, v, w = _closest_barycentric(float(x), float(y), ax, ay, bx, by, cx, cy)
                qx = u * ax + v * bx + w * cx - x
                qy = u * ay + v * by + w * cy - y
                # the Chebyshev distance: a lookup reads the texel while both offsets are below one texel
                distance = max(abs(qx), abs(qy))
                if distance >= 1.0:
                    continue
                if not count_only:
                    out_texel[found] = row * width + column
                    out_face[found] = f
                    out_squared_distance[found] = qx * qx + qy * qy
                    out_bary[found, 0] = u
                    out_bary[found, 1] = v
                    out_bary[found, 2] = w
                found += 1
    return found


def footprint_texels(uv, covered):
    """Texels a bake left empty that bilinear lookups on a triangle read, with the triangle's nearest point.

    Parameters
    ----------
    uv : (m, 3, 2) array_like of float64
        Per-corner UVs of the triangles the image is drawn on; REPEAT wrapping: any real values.
    covered : (h, w) array_like of bool
        Texels the bake wrote (row 0 at v = 0).

    Returns
    -------
    rows, columns : (p,) int64 ndarray
        The uncovered texels whose centre is less than one texel, in both axes, from the nearest point of some
        triangle of non-zero area: a bilinear lookup there gives such a texel a non-zero weight. Each once.
    face : (p,) int64 ndarray
        Of all those triangles, the one whose nearest point is closest to the texel centre (Euclidean).
    bary : (p, 3) float64 ndarray
        Barycentric coordinates of that nearest point in ``face``.

    Notes
    -----
    The point is the one of the triangle nearest to the texel centre in texel space (texel centres at
    ``((j + 1/2) / w, (i + 1/2) / h)``), so an ``(h, w)`` image's texels are square whatever its aspect. A
    point inside a triangle is covered by the bake already, so every returned point lies on a triangle's
    border.

    References
    ----------
    Sun et al. 2022, Eq. 9 (bilinear lookup) and Eq. 11 (the re-bake gives every texel that screen pixels read
    a value).
    """
    covered = np.ascontiguousarray(covered, dtype=np.bool_)
    if covered.ndim != 2 or covered.size == 0:
        raise ValueError(f"covered must be a non-empty 2-D array, got shape {covered.shape}")
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2), got {uv.shape}")
    height, width = covered.shape
    corners = np.ascontiguousarray(uv * np.array([width, height]) - 0.5)
    texel = np.empty(0, dtype=np.int64)
    face = np.empty(0, dtype=np.int64)
    distance = np.empty(0)
    bary = np.empty((0, 3))
    total = _footprint_kernel(corners, covered, True, texel, face, distance, bary)
    texel, face, distance, bary = (np.empty(total, dtype=np.int64), np.empty(total, dtype=np.int64),
                                   np.empty(total), np.empty((total, 3)))
    _footprint_kernel(corners, covered, False, texel, face, distance, bary)
    order = np.lexsort((face, distance, texel))  # nearest first; ties to the lower face index
    texel, face, bary = texel[order], face[order], bary[order]
    first = np.ones(total, dtype=bool)
    first[1:] = texel[1:] != texel[:-1]
    texel = texel[first]
    return texel // width, texel % width, face[first], bary[first]
