"""Texel cost of a UV map at a texture resolution and the resolution that meets a target cost (Sec. 5.1).

References
----------
Sun et al. 2022, Eq. 20 (cost ``c = r^2 sum |tri^t|``) and Eq. 21 (relative cost ``c_r = c / c_hat``).
"""
import numpy as np

from ._jit import njit
from .charts import signed_uv_areas
from .packing import aspect_size

__all__ = ["uv_area", "texel_reuse", "texel_cost", "relative_cost", "resolution_for_cost", "size_for_cost"]


def uv_area(uv):
    """Total unsigned area of the UV triangles.

    Parameters
    ----------
    uv : (m, 3, 2) array_like
        Per-corner UV coordinates.

    Returns
    -------
    float
        ``sum_i |tri_i^t|`` in UV units (the unit square has area 1). Overlapping triangles count twice,
        as in the paper's cost.
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2), got {uv.shape}")
    return float(np.abs(signed_uv_areas(uv)).sum())


@njit
def _covered_texels_kernel(points, h, w):
    """Numba: texels of an (h, w) image (REPEAT wrapping) whose centre lies in some triangle, inclusive of edges."""
    covered = np.zeros(h * w, np.bool_)
    for t in range(points.shape[0]):
        ax, ay = points[t, 0, 0], points[t, 0, 1]
        bx, by = points[t, 1, 0] - ax, points[t, 1, 1] - ay
        cx, cy = points[t, 2, 0] - ax, points[t, 2, 1] - ay
        det = bx * cy - by * cx
        if det == 0.0:
            continue
        x_lo = int(np.floor(min(ax, ax + bx, ax + cx) - 0.5))
        x_hi = int(np.ceil(max(ax, ax + bx, ax + cx) - 0.5))
        y_lo = int(np.floor(min(ay, ay + by, ay + cy) - 0.5))
        y_hi = int(np.ceil(max(ay, ay + by, ay + cy) - 0.5))
        for iy in range(y_lo, y_hi + 1):
            for ix in range(x_lo, x_hi + 1):
                px = ix + 0.5 - ax
                py = iy + 0.5 - ay
                s = (px * cy - py * cx) / det
                r = (bx * py - by * px) / det
                if s >= 0.0 and r >= 0.0 and s + r <= 1.0:
                    covered[(iy % h) * w + ix % w] = True
    return covered


def texel_reuse(uv, texture_shape):
    """How many times, on average, the UV triangles use each texel they cover.

    An atlas gives every surface point texels of its own, reuse 1; tiled UVs, several islands laid on the same
    texels and mirrored halves share texels, so the summed UV area exceeds the image area they cover. A new UV
    map that gives every triangle its own texels needs ``reuse`` times the input's covered texels for the
    input's texel density, whatever the texture shows.

    Parameters
    ----------
    uv : (m, 3, 2) array_like
        Per-corner UV coordinates (REPEAT wrapping: any real values).
    texture_shape : tuple of int
        ``(h, w)`` of the texture the UVs read.

    Returns
    -------
    float
        ``sum_i |tri_i^t|`` in texels over the number of distinct texels whose centre lies in some triangle;
        ``nan`` when no texel centre does.

    Examples
    --------
    Two copies of the square [0, 1/2]^2 (two triangles each) on an 8 x 8 texture:

    >>> square = [[[0, 0], [0.5, 0], [0.5, 0.5]], [[0, 0], [0.5, 0.5], [0, 0.5]]]
    >>> float(texel_reuse(square * 2, (8, 8)))
    2.0
    """
    area = uv_area(uv)  # checks the shape
    h, w = int(texture_shape[0]), int(texture_shape[1])
    if h <= 0 or w <= 0:
        raise ValueError(f"texture_shape must be positive, got {texture_shape}")
    points = np.asarray(uv, dtype=np.float64) * np.array([w, h], dtype=np.float64)
    covered = int(_covered_texels_kernel(np.ascontiguousarray(points), h, w).sum())
    return area * w * h / covered if covered else float("nan")


def _pixel_count(resolution):
    width, height = (resolution, resolution) if np.ndim(resolution) == 0 else resolution
    if width <= 0 or height <= 0:
        raise ValueError(f"resolution must be positive, got {resolution}")
    return float(width) * float(height)


def texel_cost(uv, resolution):
    """Number of texels a UV map covers at a texture resolution (Eq. 20).

    Parameters
    ----------
    uv : (m, 3, 2) array_like
        Per-corner UV coordinates.
    resolution : int or (int, int)
        ``r`` for an ``r x r`` texture, or ``(width, height)``.

    Returns
    -------
    float
        ``width * height * sum |tri^t|``.
    """
    return _pixel_count(resolution) * uv_area(uv)


def relative_cost(uv, resolution, *, reference_uv, reference_resolution):
    """Cost relative to the input parameterization at its own resolution (Eq. 21).

    Parameters
    ----------
    uv : (m, 3, 2) array_like
        The candidate UV map.
    resolution : int or (int, int)
        Its texture resolution.
    reference_uv : (m, 3, 2) array_like
        The input UV map.
    reference_resolution : int or (int, int)
        The input texture's resolution ``r_hat`` (``(width, height)`` for non-square images).

    Returns
    -------
    float
    """
    reference = texel_cost(reference_uv, reference_resolution)
    if reference <= 0:
        raise ValueError("the reference UV map has zero area: its relative cost is undefined")
    return texel_cost(uv, resolution) / reference


def resolution_for_cost(uv, target, *, reference_uv, reference_resolution, minimum=1):
    """The integer square resolution whose relative cost is closest to a target (Eq. 20-21).

    Parameters
    ----------
    uv : (m, 3, 2) array_like
        The candidate UV map.
    target : float
        Target relative cost ``c_r`` (> 0).
    reference_uv : (m, 3, 2) array_like
        The input UV map.
    reference_resolution : int or (int, int)
        The input texture's resolution.
    minimum : int, optional
        Smallest resolution returned.

    Returns
    -------
    int
        ``r`` minimizing ``|c_r(uv, r) - target|``; ties go to the larger ``r``.
    """
    if not target > 0:
        raise ValueError(f"target relative cost must be positive, got {target}")
    area = uv_area(uv)
    if area <= 0:
        raise ValueError("the UV map has zero area: no resolution can meet a cost")
    reference = texel_cost(reference_uv, reference_resolution)
    if reference <= 0:
        raise ValueError("the reference UV map has zero area: its relative cost is undefined")
    exact = np.sqrt(target * reference / area)
    candidates = [max(minimum, int(np.floor(exact))), max(minimum, int(np.ceil(exact)))]
    errors = [abs(r * r * area / reference - target) for r in candidates]
    return candidates[1] if errors[1] <= errors[0] else candidates[0]


def size_for_cost(uv, target, *, reference_uv, reference_resolution, aspect=1.0, minimum=1):
    """The image size ``(width, height)`` of a width-to-height ratio whose relative cost is closest to a target.

    Parameters
    ----------
    uv, target, reference_uv, reference_resolution, minimum
        As :func:`resolution_for_cost` takes them.
    aspect : float, optional
        Width over height of the image the UV map was laid out for (a packing's, ``core.packing``): texels stay
        square only in an image of that shape.

    Returns
    -------
    (int, int)
        ``(r, r)`` from :func:`resolution_for_cost` for an aspect of 1; otherwise the side ``s`` that meets the
        target exactly as a square's, ``(round(s sqrt(aspect)), round(s / sqrt(aspect)))``, each at least
        ``minimum``.
    """
    if not aspect > 0:
        raise ValueError(f"aspect must be positive, got {aspect}")
    if aspect == 1.0:
        side = resolution_for_cost(uv, target, reference_uv=reference_uv, reference_resolution=reference_resolution,
                                   minimum=minimum)
        return side, side
    resolution_for_cost(uv, target, reference_uv=reference_uv, reference_resolution=reference_resolution)  # checks
    exact = np.sqrt(target * texel_cost(reference_uv, reference_resolution) / uv_area(uv))
    return aspect_size(exact, aspect, minimum=minimum)

