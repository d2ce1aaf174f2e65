import numpy as np
import pytest

from perceptual_uv.core.overlap import (count_overlaps, overlapping_pairs, overlapping_pairs_reference,
                                       overlap_areas, restore_folded_charts, shared_area_fractions,
                                       triangles_overlap)

UNIT = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]


@pytest.mark.parametrize(
    "other, expected",
    [
        ([[2.0, 0], [3, 0], [2, 1]], False),  # far apart
        ([[1.0, 0], [1, 1], [0, 1]], False),  # shares the hypotenuse, other side
        ([[1.0, 0], [2, 0], [1, 1]], False),  # touches at one vertex
        ([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5]], False),  # touches the hypotenuse at its midpoint
        ([[0.2, 0.2], [0.4, 0.2], [0.2, 0.4]], True),  # strictly inside
        ([[0.0, 0], [0, 1], [1, 0]], True),  # the same triangle, opposite orientation
        ([[1.0, 0], [0, 1], [0.1, 0.1]], True),  # shares the hypotenuse, folded onto the same side
        ([[0.5, -0.2], [0.7, 1.0], [-0.3, 0.6]], True),  # edges cross, no vertex inside the other
        ([[0.6, 0.6], [2, 0.6], [0.6, 2]], False),  # boxes overlap, separated by the hypotenuse
        ([[0.2, 0.2], [0.4, 0.4], [0.6, 0.6]], False),  # zero area
    ],
)
def test_hand_made_pairs(other, expected):
    assert triangles_overlap(UNIT, other) is expected
    assert triangles_overlap(other, UNIT) is expected


def test_star_of_david_overlaps_without_contained_vertices():
    up = [[0.0, 1.0], [-0.866, -0.5], [0.866, -0.5]]
    down = [[0.0, -1.0], [0.866, 0.5], [-0.866, 0.5]]
    assert triangles_overlap(up, down)


def _grid_mesh(n):
    # n x n squares, two triangles each; neighbours share edges exactly.
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    p = np.stack([x.ravel(), y.ravel()], axis=1)
    a = p
    b = p + [1, 0]
    c = p + [1, 1]
    d = p + [0, 1]
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_tiling_has_no_overlaps_and_one_moved_triangle_is_found():
    uv = _grid_mesh(60)  # 7200 triangles, all sharing edges and vertices
    assert overlapping_pairs(uv).shape == (0, 2)
    uv = uv.copy()
    # Square (0, 0) is triangles 0 and 3600; drop a small copy of the first into square (10, 10) = index 610.
    uv[0] = [[10.2, 10.05], [10.9, 10.05], [10.9, 10.75]]
    pairs = overlapping_pairs(uv)
    # It lies inside the lower triangle of square (10, 10) (index 610) and clear of the upper one (4210).
    np.testing.assert_array_equal(pairs, [[0, 610]])


def test_grid_matches_brute_force_reference_on_random_triangles():
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 10, size=(400, 1, 2))
    uv = centres + rng.normal(scale=0.4, size=(400, 3, 2))
    uv[:20] = uv[20:40][:, [0, 2, 1]]  # exact duplicates with flipped orientation
    uv[40:50, 0] = uv[50:60, 1]  # shared vertices
    pairs = overlapping_pairs(uv)
    reference = overlapping_pairs_reference(uv)
    assert len(reference) > 100
    np.testing.assert_array_equal(pairs, reference)


def test_counts_split_by_chart():
    uv = np.array([UNIT, [[0.1, 0.1], [0.5, 0.1], [0.1, 0.5]], [[0.2, 0.0], [0.3, 0.0], [0.2, 0.3]],
                   [[5.0, 5], [6, 5], [5, 6]]])
    counts = count_overlaps(uv, face_chart=[0, 0, 1, 2])
    # Pairs: (0,1) same chart, (0,2) and (1,2) different charts; triangle 3 is alone.
    np.testing.assert_array_equal(counts.pairs, [[0, 1], [0, 2], [1, 2]])
    assert (counts.total, counts.within_charts, counts.between_charts, counts.triangles) == (3, 1, 2, 3)


def test_validation():
    with pytest.raises(ValueError, match="shape"):
        overlapping_pairs(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="face_chart"):
        count_overlaps(np.zeros((2, 3, 2)), face_chart=[0])
    with pytest.raises(ValueError, match="NaN"):
        overlapping_pairs(np.full((2, 3, 2), np.nan))


# --- restoring folded charts -----------------------------------------------------------------------------------

def test_a_chart_folded_by_the_fit_gets_its_input_layout_back_at_its_new_size():
    # chart 0: a unit square (2 triangles); the "fit" folds its second triangle onto the first and doubles the
    # area (each triangle 0.5 -> 1, total 2). chart 1: one triangle, shrunk, not folded.
    uv_in = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]],
                      [[3, 0], [4, 0], [3, 1]]], dtype=float)
    uv_new = np.array([[[0, 0], [2, 0], [2, 1]], [[0, 0], [2, 0], [2, 1]],
                       [[3, 0], [3.5, 0], [3, 0.5]]], dtype=float)
    chart = np.array([0, 0, 1])
    uv, restored = restore_folded_charts(uv_in, uv_new, chart)
    np.testing.assert_array_equal(restored, [0])
    np.testing.assert_allclose(uv[:2], np.sqrt(2.0) * uv_in[:2])  # area 1 -> 2: scale sqrt 2
    np.testing.assert_array_equal(uv[2], uv_new[2])
    assert count_overlaps(uv, chart).total == 0


def test_an_overlap_already_in_the_input_is_not_held_against_the_fit():
    tri = [[0, 0], [1, 0], [0, 1]]
    uv_in = np.array([tri, tri], dtype=float)  # two triangles of one chart sharing texels (mirrored halves)
    uv_new = 0.5 * uv_in
    uv, restored = restore_folded_charts(uv_in, uv_new, np.zeros(2, int))
    assert restored.size == 0
    np.testing.assert_array_equal(uv, uv_new)


def test_overlap_areas_by_hand():
    right = [[0, 0], [1, 0], [0, 1]]
    uv = np.array([right,
                   [[0.5, 0], [1.5, 0], [0.5, 1]],  # shifted by half: shares the triangle (0.5,0),(1,0),(0.5,0.5)
                   [[1, 0], [1, 1], [0, 1]],  # the square's other half: touches along the diagonal only
                   [[0, 1], [1, 0], [0, 0]]], dtype=float)  # the first one, clockwise
    # An equilateral triangle and its half-turn about the centroid: a hexagram, whose hexagon is 2/3 of either.
    corners = np.array([[np.cos(a), np.sin(a)] for a in np.pi / 2 + 2 * np.pi / 3 * np.arange(3)])
    star = np.array([corners, -corners])
    np.testing.assert_allclose(overlap_areas(uv, [[0, 1], [0, 2], [0, 3]]), [0.125, 0.0, 0.5], atol=1e-15)
    triangle_area = 3 * np.sqrt(3) / 4
    np.testing.assert_allclose(overlap_areas(star, [[0, 1]]), [2 / 3 * triangle_area], rtol=1e-12)
    with pytest.raises(ValueError, match="outside"):
        overlap_areas(uv, [[0, 4]])


def test_shared_area_fractions_count_each_charts_own_overlaps_only():
    right = np.array([[0, 0], [1, 0], [0, 1]], dtype=float)
    # chart 0: the right triangle and its copy shifted by half, sharing 0.125 of a chart area of 1;
    # chart 1: a lone triangle lying on chart 0 (an overlap between charts, left out); chart 2: no UV area.
    uv = np.array([right, right + [0.5, 0], right, np.zeros((3, 2))])
    np.testing.assert_allclose(shared_area_fractions(uv, np.array([0, 0, 1, 2]), 3), [0.125, 0.0, 0.0],
                               atol=1e-15)


@pytest.mark.parametrize("shift, folded", [(0.02, False), (0.1, True)])
def test_a_chart_is_restored_only_when_its_shared_area_grows_beyond_the_tolerance(shift, folded):
    # One chart of two unit right triangles (area 1 in all). The fit moves the second so that the two share
    # the corner triangle of legs `shift`: area shift^2 / 2, i.e. 2e-4 (a sliver, kept) or 5e-3 (restored).
    right = np.array([[0, 0], [1, 0], [0, 1]], dtype=float)
    uv_in = np.array([right, right + [3, 0]])
    uv_new = np.array([right, right + [1 - shift, 0]])
    uv, restored = restore_folded_charts(uv_in, uv_new, np.zeros(2, int))
    assert restored.size == int(folded)
    np.testing.assert_array_equal(uv, uv_in if folded else uv_new)
