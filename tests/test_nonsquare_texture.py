# SPDX-License-Identifier: GPL-3.0-or-later
"""The mesh-wise stage on a texture that is not square: targets are met on the texel grid.

The triangle-wise targets are Jacobians between texel coordinates ``(u w, v h)`` of the input texture
(:mod:`perceptual_uv.core.loss`). A map met in UV units, ``J_uv``, is ``D J_uv D^-1`` in texels with
``D = diag(w, h)``, so on a ``w != h`` texture only Jacobians that commute with ``D`` (diagonal ones: no
rotation, stretch along the axes) come out the same in both frames. Every test here uses one chart of eight
triangles, a 2 x 2 grid of squares 8 texels wide on a 64 x 32 texture (``D = diag(64, 32)``, aspect 2:1),
with the same target on every triangle, so the target is one affine map that the chart can follow exactly:
the expected texel Jacobian is the target itself (up to Eq. 16's quarter turns), derived by hand.

Tolerance: the solver meets such a target to round-off (errors of about 1e-15 here): the barrier is inactive
(``det J`` stays above its threshold) and the local step's stretch differs from the target by a factor
``w_rs / (w_S + w_rs) = 1e-5`` of the residual, so the error contracts 1e5 times per iteration. ``1e-9`` is far
above that round-off and far below the errors of a solve in UV units (0.1 to 0.25 in Jacobian entries, a
ratio of singular values of 2.08 instead of 1), which :func:`test_a_solve_in_uv_units_misreads_the_targets`
reproduces with ``texel_scale=(1, 1)``.
"""
import numpy as np
import pytest

from perceptual_uv.core.chart_orientation import orient_charts
from perceptual_uv.core.chartfit import fit_charts
from perceptual_uv.core.deformation import jacobian, rotation
from perceptual_uv.core.meshwise import flipped_triangles, solve_meshwise

W, H = 64, 32
TEXEL_SCALE = (W, H)
TOL = 1e-9


def _grid_chart(cells=2, side=8.0):
    """One chart: ``cells x cells`` texel squares of ``side`` texels, two triangles each, on the W x H texture.

    Returns
    -------
    F : (2 cells^2, 3) int64 ndarray
    uv : (2 cells^2, 3, 2) float64 ndarray
        Counter-clockwise corners in UV units, ``texel / (W, H)``.
    """
    n = cells + 1
    texels = np.array([[i, j] for j in range(n) for i in range(n)], dtype=np.float64) * side
    faces = []
    for j in range(cells):
        for i in range(cells):
            a = j * n + i
            faces += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    F = np.array(faces, dtype=np.int64)
    return F, texels[F] / np.array([W, H], dtype=np.float64)


F, UV = _grid_chart()
M = len(F)


def _texel_jacobians(uv_new, uv_in=UV):
    """Per-triangle Jacobian from input texels to new texels, both ``(u W, v H)``: (m, 2, 2)."""
    scale = np.array([W, H], dtype=np.float64)[:, None]

    def edges(corners):
        return np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=-1) * scale

    return edges(uv_new) @ np.linalg.inv(edges(uv_in))


def _targets(alpha, lambda1, lambda2, beta):
    return np.tile([alpha, lambda1, lambda2, beta], (M, 1))


def _angle(J):
    return np.arctan2(J[:, 1, 0] - J[:, 0, 1], J[:, 0, 0] + J[:, 1, 1])


def _quarter_turn_residue(angle):
    """``angle`` modulo a quarter turn, in ``[-pi/4, pi/4)``."""
    return np.mod(angle + np.pi / 4, np.pi / 2) - np.pi / 4


def test_the_chart_is_square_in_texels_and_tall_in_uv():
    """The fixture itself: each cell is 8 x 8 texels, i.e. 0.125 x 0.25 in UV units."""
    assert M == 8
    np.testing.assert_allclose(UV.reshape(-1, 2).max(axis=0), [16 / W, 16 / H], rtol=0, atol=0)
    np.testing.assert_allclose(_texel_jacobians(UV), np.tile(np.eye(2), (M, 1, 1)), atol=1e-15)


@pytest.mark.parametrize("w_R", [1.0, 0.0], ids=["with-rotation-terms", "without-rotation-terms"])
def test_an_isotropic_target_is_isotropic_in_texels(w_R):
    """(a) Target ``R = I``, ``lambda1 = lambda2 = 0.5`` in texels: the texel Jacobian is ``0.5 I``.

    Without rotation terms the rotation is free, and the solver, starting from the identity, has no reason to
    turn the chart: ``0.5 I`` as well. (``0.5 I`` commutes with ``D``, so this case alone does not tell the
    frames apart; the next tests do.)
    """
    result = solve_meshwise(F, UV, _targets(0.0, 0.5, 0.5, 0.0), np.full(M, w_R), np.ones(M),
                            texel_scale=TEXEL_SCALE)
    J = _texel_jacobians(result.uv)
    np.testing.assert_allclose(J, np.tile(0.5 * np.eye(2), (M, 1, 1)), atol=TOL)
    sigma = np.linalg.svd(J, compute_uv=False)
    np.testing.assert_allclose(sigma[:, 0] / sigma[:, 1], 1.0, atol=TOL)
    assert result.flipped == 0 and result.degenerate == 0 and result.converged


@pytest.mark.parametrize("alpha", [np.pi / 6, np.pi / 3, 2.0, -0.4])
def test_any_rotation_target_is_met_in_texels(alpha):
    """(c) Target ``0.5 R(alpha)`` in texels with rotation terms: the texel Jacobian is ``0.5 R(alpha')``,
    ``alpha'`` the residue of ``alpha`` modulo a quarter turn (Eq. 16's symmetry; the solver starts at the
    identity and takes the quarter turn nearest it), i.e. a similarity of the texel grid."""
    result = solve_meshwise(F, UV, _targets(alpha, 0.5, 0.5, 0.0), np.ones(M), np.ones(M),
                            texel_scale=TEXEL_SCALE)
    J = _texel_jacobians(result.uv)
    expected = 0.5 * rotation(np.full(M, _quarter_turn_residue(alpha)))
    np.testing.assert_allclose(J, expected, atol=TOL)
    np.testing.assert_allclose(_quarter_turn_residue(_angle(J) - alpha), 0.0, atol=TOL)
    np.testing.assert_allclose(np.linalg.svd(J, compute_uv=False), 0.5, atol=TOL)


@pytest.mark.parametrize("w_R", [1.0, 0.0], ids=["with-rotation-terms", "without-rotation-terms"])
def test_an_oblique_stretch_target_is_met_in_texels(w_R):
    """Target ``S(1, 0.5, pi/4)``: lengths along the texel diagonal ``(1, 1)`` kept, along ``(1, -1)`` halved.
    The texel Jacobian is that symmetric matrix, ``[[0.75, 0.25], [0.25, 0.75]]``, with singular values 1 and
    0.5. (Met in UV units it would be ``[[0.75, 0.5], [0.125, 0.75]]`` in texels, singular values 1.0856 and
    0.4606.)"""
    params = _targets(0.0, 1.0, 0.5, np.pi / 4)
    _, S_bar = jacobian(params)
    np.testing.assert_allclose(S_bar[0], [[0.75, 0.25], [0.25, 0.75]], atol=1e-15)  # V(beta) diag V(beta)^T
    result = solve_meshwise(F, UV, params, np.full(M, w_R), np.ones(M), texel_scale=TEXEL_SCALE)
    J = _texel_jacobians(result.uv)
    np.testing.assert_allclose(J, S_bar, atol=TOL)
    np.testing.assert_allclose(np.linalg.svd(J, compute_uv=False), np.tile([1.0, 0.5], (M, 1)), atol=TOL)


def test_a_solve_in_uv_units_misreads_the_targets():
    """What the tests above guard against: with ``texel_scale=(1, 1)`` the targets are met in UV units, and in
    texels the Jacobian is ``D A D^-1`` (``D = diag(2, 1)`` up to a factor). For ``A = 0.5 R(pi/6)`` that is
    ``0.5 [[c, -2 s], [s / 2, c]]`` with ``c = cos(pi/6)``, ``s = 1/2``: singular values 0.7215 and 0.3465,
    a ratio of 2.08 where the target has 1."""
    alpha = np.pi / 6
    result = solve_meshwise(F, UV, _targets(alpha, 0.5, 0.5, 0.0), np.ones(M), np.ones(M))
    J = _texel_jacobians(result.uv)
    c, s = np.cos(alpha), np.sin(alpha)
    np.testing.assert_allclose(J, np.tile(0.5 * np.array([[c, -2 * s], [s / 2, c]]), (M, 1, 1)), atol=TOL)
    sigma = np.linalg.svd(J, compute_uv=False)
    np.testing.assert_allclose(sigma[0], [0.72150, 0.34650], atol=1e-5)
    assert sigma[0, 0] / sigma[0, 1] > 2.08


def test_orient_charts_turns_by_a_quarter_turn_on_the_texel_grid():
    """(b) Target angle 90 degrees, on a chart the fit left at 0.5 R(20 degrees) in texels: the chart turns by
    70 degrees about its centre, in texels, and its texel Jacobian becomes ``0.5 R(pi/2)``, a pure quarter
    turn: the texel axis u goes onto the texel axis v and v onto -u, each halved, nothing sheared. (The same
    quarter turn made in UV units would be ``D R(pi/2) D^-1 = [[0, -2], [1/2, 0]]`` in texels.)"""
    turn = np.deg2rad(20.0)
    scale = np.array([W, H], dtype=np.float64)
    uv_new = 0.5 * (UV * scale) @ rotation(turn).T / scale + [0.3, 0.6]
    uv, angles = orient_charts(UV, uv_new, np.zeros(M, dtype=np.int64), np.full(M, np.pi / 2), np.ones(M),
                               texel_scale=TEXEL_SCALE)
    np.testing.assert_allclose(angles, [np.pi / 2 - turn], atol=TOL)
    J = _texel_jacobians(uv)
    np.testing.assert_allclose(J, np.tile(0.5 * rotation(np.pi / 2), (M, 1, 1)), atol=TOL)
    np.testing.assert_allclose(J @ [1.0, 0.0], np.tile([0.0, 0.5], (M, 1)), atol=TOL)
    np.testing.assert_allclose(J @ [0.0, 1.0], np.tile([-0.5, 0.0], (M, 1)), atol=TOL)
    # Turned about the chart's centre in texels, so the chart stays where it was.
    np.testing.assert_allclose(uv.reshape(-1, 2).mean(axis=0), uv_new.reshape(-1, 2).mean(axis=0), atol=TOL)


def _fit_error(alpha, lambda1, lambda2, beta):
    """A ``measure`` for :func:`fit_charts`: Eq. 15's residual in texels, ``min_k |J - R(k pi/2) R S|^2``."""
    R, S = jacobian(_targets(alpha, lambda1, lambda2, beta))

    def error(uv_new):
        J = _texel_jacobians(uv_new)
        return np.min([((J - rotation(np.full(M, k * np.pi / 2)) @ R @ S) ** 2).sum(axis=(1, 2))
                       for k in range(4)], axis=0)

    def measure(fits):
        return np.stack([error(uv_new) for uv_new in fits])

    return measure


@pytest.mark.parametrize("target", [(np.pi / 2 + np.pi / 9, 0.5, 0.5, 0.0), (0.3, 1.0, 0.5, np.pi / 4)],
                         ids=["isotropic-turned", "oblique-stretch"])
def test_fit_charts_meets_the_targets_in_texels(target):
    """:func:`fit_charts` as the pipeline calls it (``texel_scale=(w, h)``): whichever fit the chart keeps,
    its texel Jacobian is the target ``R(alpha) S`` up to a quarter turn. Both fits reach it here: the one with
    rotation terms directly, the one without them through the chart turn. For the oblique stretch, fits in UV
    units leave singular values 1.0856 and 0.4606 (without rotation terms) or 0.8747 and 0.5716 (with them)
    in texels, which no rigid turn can repair."""
    R, S = jacobian(_targets(*target))
    fit = fit_charts(F, UV, _targets(*target), np.ones(M), np.ones(M), measure=_fit_error(*target),
                     texel_scale=TEXEL_SCALE)
    J = _texel_jacobians(fit.uv)
    k = np.round((_angle(J) - _angle(R @ S)) / (np.pi / 2))
    np.testing.assert_allclose(J, rotation(k * np.pi / 2) @ R @ S, atol=TOL)
    np.testing.assert_allclose(np.linalg.svd(J, compute_uv=False), np.tile(target[1:3], (M, 1)), atol=TOL)
    np.testing.assert_allclose(fit.losses, 0.0, atol=TOL)
    assert fit.flipped == 0 and fit.restored.size == 0


def test_only_the_aspect_of_the_texture_matters():
    """Eq. 19 does not see a uniform scale of the frame: 64 x 32 and 2 x 1 textures give the same UVs, bit for
    bit (the solver works in ``(sqrt(w / h), sqrt(h / w))``, the same for both)."""
    params = _targets(0.4, 0.9, 0.3, 1.1)
    first = solve_meshwise(F, UV, params, np.ones(M), np.ones(M), texel_scale=(64, 32), max_iterations=5)
    second = solve_meshwise(F, UV, params, np.ones(M), np.ones(M), texel_scale=(2.0, 1.0), max_iterations=5)
    np.testing.assert_array_equal(first.uv, second.uv)


def test_flipped_triangles_takes_the_texel_scale():
    """Orientation does not depend on the frame: a mirrored triangle is flipped at any aspect."""
    mirrored = UV.copy()
    mirrored[0] = UV[0] * [-1.0, 1.0]
    for scale in [(1.0, 1.0), TEXEL_SCALE]:
        np.testing.assert_array_equal(flipped_triangles(UV, mirrored, texel_scale=scale), np.arange(M) == 0)
    with pytest.raises(ValueError, match="texel_scale"):
        flipped_triangles(UV, mirrored, texel_scale=(W, 0))


@pytest.mark.parametrize("texel_scale", [(1.0, -1.0), (np.inf, 1.0), (1.0, 2.0, 3.0)])
def test_bad_texel_scale_is_refused(texel_scale):
    with pytest.raises(ValueError, match="texel_scale"):
        solve_meshwise(F, UV, _targets(0.0, 0.5, 0.5, 0.0), weights="identity", texel_scale=texel_scale)
