"""Local step of the mesh-wise stage: per triangle, the quarter turn, rotation and stretch of Eq. 19 (App. B).

With the Jacobians ``J_i`` of the current map held fixed, Eq. 19 falls apart into one problem per triangle,

    w_R |R_i - R(k_i pi/2) R_bar_i|^2 + w_S |S_i - S_bar_i|^2 + w_rs |J_i - R_i S_i|^2,

over the quarter turn k_i, the rotation ``R_i = R(theta_i)`` and the symmetric stretch S_i (the barrier and the area
weight do not depend on them). :func:`local_step` solves it; ``_local_update_kernel`` is the form the solve of
:mod:`.meshwise` runs. :func:`fit_energy` is the fit of Eq. 16 (or Eq. 15) at a given map, which a result reports.

Decisions (the paper leaves them open):

* Local step: for each of the four quarter turns k, theta in closed form and then S from Eq. 26; the k with the
  lowest per-triangle energy wins, and a triangle keeps its previous (k, R, S) if that is lower still, so the
  objective never increases. theta minimizes the exact block of Eq. 19, ``w_R |R - R_k R_bar|^2 +
  w_rs |J - R S|^2``, whose maximizer of ``tr(R^T M)`` is ``M = w_R R_k R_bar + w_rs J S``; Eq. 25 writes
  the second term as ``w_rs |R - J S^-1|^2``, which agrees when S is a multiple of the identity and needs no
  inverse of S here. Eq. 26 is solved exactly over symmetric S: ``S = (w_S S_bar + w_rs sym(R^T J)) /
  (w_S + w_rs)`` (the linear system is diagonal in (s11, s12, s22)).
* Hot loop: the local step is a numba kernel (``_local_update_kernel``); it keeps a plain numpy reference
  (``_local_update_reference``) that the tests compare against.

References
----------
Sun et al. 2022, Eq. 15-17, 19; App. B, Eq. 25-26.
"""
import numpy as np

from ._jit import njit
from .deformation import rotation

__all__ = ["local_step", "fit_energy"]


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
