"""Texel cost of a UV map at a texture resolution and the resolution that meets a target cost (Sec. 5.1).

References
----------
Sun et al. 2022, Eq. 20 (cost ``c = r^2 sum |tri^t|``) and Eq. 21 (relative cost ``c_r = c / c_hat``).
"""
import numpy as np

from .charts import signed_uv_areas

__all__ = ["uv_area", "texel_cost", "relative_cost", "resolution_for_cost"]


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
