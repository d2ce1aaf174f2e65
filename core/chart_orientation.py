"""The rigid turn of every chart towards its triangles' rotation targets, after the mesh-wise fit (Eq. 16).

The mesh-wise fit (:mod:`.meshwise`), and every other method, leaves each chart at some angle. :func:`orient_charts`
turns each chart as a whole to the angle that minimizes Eq. 16's rotation term over its triangles, with the
90-degree symmetry that the packer's quarter turns give; a rigid turn changes no stretch, no determinant and no
other term of Eq. 19. :func:`.chartfit.finish_charts` applies it to every method's charts.

References
----------
Sun et al. 2022, Eq. 16 (rotation targets with 90-degree symmetry), Eq. 17 (``w_R``), Eq. 19.
"""
import numpy as np

from .deformation import inverse_2x2, rotation
from .meshwise import _parse_weights
from .meshwise_local import _angle_of

__all__ = ["orient_charts"]


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
