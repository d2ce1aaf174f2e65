"""Texels that bilinear lookups read next to a triangle but a bake by texel centres leaves empty."""
import numpy as np
import pytest

from perceptual_uv.core.footprint import footprint_texels

R = 16


def to_uv(texel_points):
    """UVs of points given in texel-centre coordinates (texel (i, j) centred at x = j, y = i) of an R x R image."""
    return (np.asarray(texel_points, dtype=float) + 0.5) / R


def centres_inside(corners):
    """(R, R) mask of texel centres inside a counter-clockwise triangle given in texel-centre coordinates."""
    y, x = np.mgrid[0:R, 0:R].astype(float)
    inside = np.ones((R, R), dtype=bool)
    for k in range(3):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 3]
        inside &= (bx - ax) * (y - ay) - (by - ay) * (x - ax) >= 0
    return inside


# Right isosceles triangle with corners off the texel lattice, so no centre lies at distance exactly 1.
TRIANGLE = np.array([[4.25, 4.25], [9.25, 4.25], [4.25, 9.25]])


def test_the_ring_read_by_lookups_matches_a_dense_sampling_of_the_triangle():
    covered = centres_inside(TRIANGLE)
    rows, columns, face, bary = footprint_texels(to_uv(TRIANGLE)[None], covered)
    found = np.zeros((R, R), dtype=bool)
    found[rows, columns] = True
    assert len(rows) == found.sum()  # each texel once
    assert not (found & covered).any()
    # Independently: Chebyshev distance from each texel centre to 20 301 points spread over the triangle.
    s, t = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201))
    keep = s + t <= 1
    points = TRIANGLE[0] + s[keep, None] * (TRIANGLE[1] - TRIANGLE[0]) + t[keep, None] * (TRIANGLE[2] - TRIANGLE[0])
    y, x = np.mgrid[0:R, 0:R]
    distance = np.full((R, R), np.inf)
    for px, py in points:
        distance = np.minimum(distance, np.maximum(np.abs(x - px), np.abs(y - py)))
    reached = (distance < 1 - 0.02) & ~covered
    beyond = distance > 1 + 0.02
    assert (found[reached]).all() and not found[beyond].any()
    # By hand: column x = 4 for y = 4..10 (7, with the corner), row y = 4 for x = 5..10 (6), and past the
    # hypotenuse x + y = 13.5 the diagonals x + y = 14 (x = 5..9) and 15 (x = 5..10), at Chebyshev distance
    # 0.25 and 0.75 (5 + 6).
    assert found.sum() == 24
    assert (face == 0).all()
    # Each point is on the triangle and is the nearest one (to within the sampling's spacing).
    nearest = bary @ TRIANGLE
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1)
    euclid = np.hypot(x[rows, columns] - nearest[:, 0], y[rows, columns] - nearest[:, 1])
    dense = np.min(np.hypot(x[rows, columns, None] - points[None, :, 0], y[rows, columns, None] - points[None, :, 1]),
                   axis=1)
    np.testing.assert_allclose(euclid, dense, atol=0.03)


def test_nearest_points_by_hand():
    rows, columns, _, bary = footprint_texels(to_uv(TRIANGLE)[None], centres_inside(TRIANGLE))
    at = {(int(r), int(c)): b for r, c, b in zip(rows, columns, bary)}
    # (x, y) = (4, 6): left of edge a-c, nearest point (4.25, 6) = a + 0.35 (c - a)
    np.testing.assert_allclose(at[6, 4], [0.65, 0, 0.35])
    # (4, 4): below-left of corner a
    np.testing.assert_allclose(at[4, 4], [1, 0, 0])
    # (7, 7): beyond the hypotenuse x + y = 13.5, nearest point (6.75, 6.75) = b + 0.5 (c - b)
    np.testing.assert_allclose(at[7, 7], [0, 0.5, 0.5])
    # (3, 5) is 1.25 texels left of the triangle: a lookup on it never reads that texel
    assert (5, 3) not in at


def test_with_nothing_covered_inner_texels_map_to_themselves():
    rows, columns, _, bary = footprint_texels(to_uv(TRIANGLE)[None], np.zeros((R, R), dtype=bool))
    inside = centres_inside(TRIANGLE)[rows, columns]
    assert inside.sum() == centres_inside(TRIANGLE).sum()
    np.testing.assert_allclose(bary[inside] @ TRIANGLE, np.stack([columns, rows], axis=1)[inside], atol=1e-12)


def test_the_nearer_of_two_triangles_wins():
    left = np.array([[2.25, 2.25], [5.6, 2.25], [2.25, 8.25]])
    right = np.array([[6.6, 2.25], [10.25, 2.25], [10.25, 8.25]])
    uv = to_uv(np.stack([left, right]))
    rows, columns, face, _ = footprint_texels(uv, centres_inside(left) | centres_inside(right))
    at = {(int(r), int(c)): int(f) for r, c, f in zip(rows, columns, face)}
    # (6, 2): 0.4 right of the left triangle's corner (5.6, 2.25), 0.6 left of the right one's corner (6.6, 2.25)
    assert at[2, 6] == 0
    # (7, 3) is 0.056 left of the right triangle's edge (x = 7.056 at y = 3) and 1.4 from the left triangle
    assert at[3, 7] == 1


def test_wraps_around_the_image_like_repeat():
    # A triangle hanging over the right edge reads texels of column 0 and 1 (REPEAT); shifting it by one whole
    # tile changes nothing.
    corners = np.array([[13.5, 3.5], [16.6, 3.5], [13.5, 8.5]])
    covered = np.zeros((R, R), dtype=bool)
    first = footprint_texels(to_uv(corners)[None], covered)
    second = footprint_texels(to_uv(corners)[None] + [1.0, -2.0], covered)
    for a, b in zip(first, second):
        np.testing.assert_allclose(a, b, atol=1e-9)
    assert {0, 1} <= set(first[1].tolist()) and first[1].max() < R


def test_zero_area_triangles_are_never_read_and_covered_texels_are_never_returned():
    segment = to_uv([[2.0, 2.0], [8.0, 8.0], [5.0, 5.0]])[None]
    assert all(len(a) == 0 for a in footprint_texels(segment, np.zeros((R, R), dtype=bool)))
    assert all(len(a) == 0 for a in footprint_texels(to_uv(TRIANGLE)[None], np.ones((R, R), dtype=bool)))


@pytest.mark.parametrize("uv, covered", [(np.zeros((2, 3)), np.zeros((4, 4), bool)),
                                         (np.zeros((1, 3, 2)), np.zeros(4, bool))])
def test_rejects_bad_shapes(uv, covered):
    with pytest.raises(ValueError, match="shape"):
        footprint_texels(uv, covered)
