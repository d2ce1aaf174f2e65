"""The per-triangle deformation Jacobian in the paper's 4-D box parameterization (Sec. 4.1.2).

``grad phi = R(alpha) V(beta) diag(lambda1, lambda2) V(beta)^T``: a rotation times a symmetric positive
stretch (polar decomposition), the stretch written by its eigen decomposition.
"""
import numpy as np

__all__ = ["rotation", "stretch", "jacobian", "inverse_2x2"]


def rotation(theta):
    """Counter-clockwise 2-D rotation matrices.

    Parameters
    ----------
    theta : (k,) array_like or float
        Angles in radians.

    Returns
    -------
    (k, 2, 2) ndarray, or (2, 2) for a scalar angle.
    """
    theta = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def stretch(lambda1, lambda2, beta):
    """Symmetric stretch ``S = V(beta) diag(lambda1, lambda2) V(beta)^T``.

    Parameters
    ----------
    lambda1, lambda2 : (k,) array_like or float
        Eigenvalues (positive for an orientation-preserving map).
    beta : (k,) array_like or float
        Angle of the first eigenvector.

    Returns
    -------
    (k, 2, 2) ndarray, or (2, 2) for scalars.

    References
    ----------
    Sun et al. 2022, Sec. 4.1.2 (eigen decomposition of S_i before Eq. 12).
    """
    lambda1, lambda2, beta = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (lambda1, lambda2, beta)))
    c, s = np.cos(beta), np.sin(beta)
    xx = lambda1 * c * c + lambda2 * s * s
    yy = lambda1 * s * s + lambda2 * c * c
    xy = (lambda1 - lambda2) * c * s
    return np.stack([np.stack([xx, xy], axis=-1), np.stack([xy, yy], axis=-1)], axis=-2)


def jacobian(params):
    """Deformation Jacobians from ``(alpha, lambda1, lambda2, beta)`` rows.

    Parameters
    ----------
    params : (k, 4) or (4,) array_like
        Rows ``(alpha, lambda1, lambda2, beta)`` of Eq. 13-14.

    Returns
    -------
    R : (k, 2, 2) or (2, 2) ndarray
        Rotation ``R(alpha)``.
    S : (k, 2, 2) or (2, 2) ndarray
        Stretch ``V(beta) diag(lambda1, lambda2) V(beta)^T``; ``grad phi = R @ S``.

    References
    ----------
    Sun et al. 2022, Eq. 13-14.
    """
    params = np.asarray(params, dtype=np.float64)
    if params.shape[-1] != 4:
        raise ValueError(f"params must have 4 columns (alpha, lambda1, lambda2, beta), got shape {params.shape}")
    alpha, lambda1, lambda2, beta = np.moveaxis(params, -1, 0)
    return rotation(alpha), stretch(lambda1, lambda2, beta)


def inverse_2x2(matrices):
    """Inverse of each 2 x 2 matrix, in closed form: ``[[d, -b], [-c, a]] / (a d - b c)``.

    Parameters
    ----------
    matrices : (..., 2, 2) array_like
        Invertible matrices (a singular one gives infinities or NaN, no error).

    Returns
    -------
    (..., 2, 2) ndarray of float64

    Notes
    -----
    ``numpy.linalg.inv`` calls LAPACK once per matrix; with a multi-threaded OpenBLAS on busy cores each call
    waits for its threads, so a batch of small inverses can take seconds in the interface's thread. The closed
    form is plain array arithmetic.
    """
    m = np.asarray(matrices, dtype=np.float64)
    if m.shape[-2:] != (2, 2):
        raise ValueError(f"matrices must have shape (..., 2, 2), got {m.shape}")
    a, b, c, d = m[..., 0, 0], m[..., 0, 1], m[..., 1, 0], m[..., 1, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([np.stack([d, -b], axis=-1), np.stack([-c, a], axis=-1)], axis=-2) / (a * d - b * c)[
            ..., None, None]
