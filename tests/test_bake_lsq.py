"""Eq. 11 re-bake: least squares with a well-defined answer for under-determined texels."""
import numpy as np
import pytest

from perceptual_uv.core.bake_lsq import _rebake_reference, rebake, render_texels


def test_unseen_texel_and_fixed_sum_take_the_minimum_norm_answer():
    # Texels 10, 20, 30, 40. Pixels read only 10 and 20, always half and half, target 1: only the sum
    # 0.5 x10 + 0.5 x20 = 1 is seen, and the minimum-norm solution splits it evenly: x10 = x20 = 1. Texels
    # 30 and 40 are read with weight 0: the minimum-norm answer is 0.
    texels = np.array([[10, 20, 30, 40]] * 3)
    weights = np.array([[0.5, 0.5, 0.0, 0.0]] * 3)
    target = np.ones(3)
    unique, values = rebake(texels, weights, target)
    np.testing.assert_array_equal(unique, [10, 20, 30, 40])
    np.testing.assert_allclose(values, [1, 1, 0, 0], atol=1e-8)
    np.testing.assert_allclose(render_texels(texels, weights, unique, values), target, atol=1e-8)


def test_inconsistent_targets_give_the_least_squares_mean():
    # One texel read with weight 1 by two pixels that want 0.2 and 0.6: least squares gives 0.4.
    texels = np.array([[5, 6, 7, 8], [5, 6, 7, 8]])
    weights = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    unique, values = rebake(texels, weights, [0.2, 0.6])
    assert values[0] == pytest.approx(0.4, abs=1e-9)


def _bilinear_system(rng, n_pixels, width, spacing):
    """Pixels on a rotated lattice of the given spacing in texel units, like a deformed screen."""
    side = int(np.sqrt(n_pixels))
    j, i = np.meshgrid(np.arange(side), np.arange(side))
    theta = rng.uniform(0, np.pi / 2)
    rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    points = (np.column_stack([j.ravel(), i.ravel()]) * spacing) @ rot.T + [width / 2, width / 2]
    x0 = np.floor(points - 0.5).astype(np.int64)
    f = points - 0.5 - x0
    texels = np.stack([x0[:, 1] * 1000 + x0[:, 0], x0[:, 1] * 1000 + x0[:, 0] + 1,
                       (x0[:, 1] + 1) * 1000 + x0[:, 0], (x0[:, 1] + 1) * 1000 + x0[:, 0] + 1], axis=1)
    weights = np.stack([(1 - f[:, 0]) * (1 - f[:, 1]), f[:, 0] * (1 - f[:, 1]), (1 - f[:, 0]) * f[:, 1],
                        f[:, 0] * f[:, 1]], axis=1)
    return texels, weights


@pytest.mark.parametrize("spacing", [0.2, 0.9, 1.7, 3.0])
def test_numba_matches_sparse_reference(spacing):
    rng = np.random.default_rng(int(spacing * 10))
    texels, weights = _bilinear_system(rng, 400, 40, spacing)
    target = rng.random(len(texels))
    unique, values = rebake(texels, weights, target)
    ref_unique, ref_values = _rebake_reference(texels, weights, target)
    order = np.argsort(unique)
    np.testing.assert_array_equal(unique[order], ref_unique)
    # Compare what matters and is unique: the render; and the texels themselves.
    np.testing.assert_allclose(render_texels(texels, weights, unique, values),
                               render_texels(texels, weights, ref_unique, ref_values), atol=1e-8)
    np.testing.assert_allclose(values[order], ref_values, atol=1e-6)


def test_fully_determined_texels_are_recovered():
    # Magnified (pixels 0.2 texel apart): interior texels are read by many pixels around their centres and are
    # determined; a target rendered from known texels gives them back. Texels at the rim of the footprint are
    # read only by pixels near their corners and may not be.
    rng = np.random.default_rng(3)
    texels, weights = _bilinear_system(rng, 900, 40, 0.2)
    unique = np.unique(texels)
    truth = rng.random(len(unique))
    target = np.einsum("pk,pk->p", weights, truth[np.searchsorted(unique, texels)])
    got_unique, got = rebake(texels, weights, target)
    order = np.argsort(got_unique)
    total_weight = np.bincount(np.searchsorted(unique, texels).ravel(), weights.ravel())
    interior = total_weight >= 2.0
    assert interior.sum() > 20
    np.testing.assert_allclose(got[order][interior], truth[interior], atol=1e-6)
    # The ridge (1e-9) pulls rim texels read with weights ~1e-3 slightly towards 0: ~1e-6 on their pixels.
    np.testing.assert_allclose(render_texels(texels, weights, got_unique, got), target, atol=2e-6)
    # Pixel order does not change the answer.
    perm = rng.permutation(len(texels))
    u2, v2 = rebake(texels[perm], weights[perm], target[perm])
    np.testing.assert_allclose(v2[np.argsort(u2)], got[order], atol=1e-9)


def test_validation():
    with pytest.raises(ValueError, match="ridge"):
        rebake([[0, 1, 2, 3]], [[1.0, 0, 0, 0]], [1.0], ridge=0)
    with pytest.raises(ValueError, match="weights"):
        rebake([[0, 1, 2, 3]], [[1.0, 0, 0]], [1.0])
    with pytest.raises(ValueError, match="target"):
        rebake([[0, 1, 2, 3]], [[1.0, 0, 0, 0]], [1.0, 2.0])
    assert rebake(np.zeros((0, 4), int), np.zeros((0, 4)), np.zeros(0))[0].size == 0


def test_band_and_envelope_cholesky_match_dense_solve():
    from perceptual_uv.core.bake_lsq import _band_cholesky_solve, _envelope_cholesky_solve

    rng = np.random.default_rng(7)
    n, b = 40, 5
    M = np.zeros((n, n))
    for d in range(b + 1):
        vals = rng.standard_normal(n - d) * (d > 0)
        M += np.diag(vals, d) + (np.diag(vals, -d) if d else 0)
    M += np.diag(np.abs(M).sum(1) + 1.0)  # diagonally dominant: SPD
    rhs = rng.standard_normal(n)
    expected = np.linalg.solve(M, rhs)
    band = np.zeros((n, b + 1))
    for d in range(b + 1):
        band[: n - d, d] = np.diagonal(M, d)
    x = rhs.copy()
    _band_cholesky_solve(band, x, 1e-12)
    np.testing.assert_allclose(x, expected, atol=1e-12)
    # The same matrix in envelope storage (rows from first[i] to i).
    first = np.maximum(np.arange(n) - b, 0)
    offset = np.concatenate([[0], np.cumsum(np.arange(n) - first + 1)])
    env = np.concatenate([M[i, first[i]:i + 1] for i in range(n)])
    x = rhs.copy()
    _envelope_cholesky_solve(env, offset, first, x, 1e-12)
    np.testing.assert_allclose(x, expected, atol=1e-12)
