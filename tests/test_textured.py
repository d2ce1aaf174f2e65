"""Which triangles show texture of their own (core.textured): the texel test and the bound's fractions."""
import numpy as np
import pytest

from perceptual_uv.core.textured import above_bound, textured_triangles


def test_textured_triangles_reads_the_texels_within_one_texel_in_both_axes():
    """An 8 x 8 texture, zero but for the texel of centre (4.5, 4.5): a bilinear lookup reads it from the open
    square (3.5, 5.5)^2, so a triangle shows it when some point of the triangle lies in that square."""
    texture = np.zeros((8, 8))
    texture[4, 4] = 1.0

    def shows(*corners):
        return bool(textured_triangles(np.array([corners], float) / 8, texture)[0])

    assert not shows((1, 1), (2, 1), (1, 2))
    assert shows((3.6, 3.6), (2, 1), (1, 2))  # corner 0.9 texel from the centre in both axes
    assert not shows((3.4, 3.4), (2, 1), (1, 2))  # 1.1 texels away
    # x + y <= 6 meets the square's bounding box but not the square, whose nearest corner has x + y = 7
    assert not shows((0, 6), (6, 0), (0, 0))
    assert shows((0, 7.2), (7.2, 0), (0, 0))
    assert shows((3.0, 4.5), (3.0, 4.5), (3.6, 4.5))  # a zero-area sliver reaching x = 3.6
    assert not shows((3.0, 4.5), (3.0, 4.5), (3.4, 4.5))
    # the texture repeats: the texel's copy right of u = 1 has its centre at (12.5, 4.5)
    assert shows((11.6, 4.5), (11.0, 4.5), (11.0, 4.0))
    assert not shows((11.4, 4.5), (11.0, 4.5), (11.0, 4.0))
    # the same triangles, colour input, several at once
    uv = np.array([[(1, 1), (2, 1), (1, 2)], [(3.6, 3.6), (2, 1), (1, 2)]], float) / 8
    colour = np.repeat(texture[:, :, None], 3, axis=2)
    np.testing.assert_array_equal(textured_triangles(uv, colour), [False, True])
    with pytest.raises(ValueError, match="uv"):
        textured_triangles(uv[:, :2], texture)


def test_above_bound_counts_textured_triangles_only_and_non_finite_losses_as_above():
    """A 16 x 16 texture, flat on its left half and a checkerboard on its right half: two triangles deep in the
    flat half are untextured whatever their loss; of the three on the checkerboard, 0.02 and NaN exceed 0.01
    and 0.005 does not, so 2 of 3 (by hand)."""
    texture = np.full((16, 16), 0.5)
    texture[:, 8:] = (np.indices((16, 8)).sum(axis=0) % 2).astype(float)
    flat = np.array([[0.1, 0.1], [0.3, 0.1], [0.1, 0.3]])
    checker = flat + [0.55, 0.4]
    uv = np.stack([flat, flat + [0.0, 0.5], checker, checker + [0.1, 0.0], checker + [0.0, 0.2]])
    losses = np.array([0.5, 0.0, 0.02, np.nan, 0.005])
    assert above_bound(uv, texture, 0.01, fit=losses, targets=np.zeros(5)) == {
        "textured_triangles": 3, "fit": pytest.approx(2 / 3), "targets": 0.0}
    assert above_bound(uv[:2], texture, 0.01, fit=losses[:2]) == {"textured_triangles": 0, "fit": 0.0}
    with pytest.raises(ValueError, match="fit must have a loss per triangle"):
        above_bound(uv, texture, 0.01, fit=losses[:4])
