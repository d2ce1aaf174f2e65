"""core.chart_bitmaps: a chart's pixels, against triangle-box clipping and a square dilation (hand-computed)."""
import numpy as np


def _clipped_area(triangle, x, y):
    """Area of the part of ``triangle`` (3, 2) inside the unit box at ``(x, y)`` (Sutherland-Hodgman clipping)."""
    polygon = [tuple(p) for p in triangle]
    for axis, bound, keep_below in ((0, x, False), (0, x + 1, True), (1, y, False), (1, y + 1, True)):
        inside = (lambda p: p[axis] <= bound) if keep_below else (lambda p: p[axis] >= bound)
        clipped = []
        for k, current in enumerate(polygon):
            previous = polygon[k - 1]
            if inside(current) != inside(previous):
                t = (bound - previous[axis]) / (current[axis] - previous[axis])
                clipped.append(tuple(previous[i] + t * (current[i] - previous[i]) for i in range(2)))
            if inside(current):
                clipped.append(current)
        polygon = clipped
        if not polygon:
            return 0.0
    xs, ys = np.array(polygon).T
    return 0.5 * abs(np.dot(xs, np.roll(ys, -1)) - np.dot(ys, np.roll(xs, -1)))


def test_a_chart_bitmap_marks_the_pixels_its_triangles_overlap_grown_by_half_the_margin():
    from scipy.ndimage import binary_dilation

    from perceptual_uv.core.chart_bitmaps import chart_bitmap, row_spans

    # By hand: the open triangle x + y < 3 overlaps the unit box at (cx, cy) where cx + cy < 3; the box at (2, 1)
    # only touches its hypotenuse. Its lower corner lands one pixel in with a growth of one.
    grid, origin = chart_bitmap(np.array([[[5.0, 7.0], [8.0, 7.0], [5.0, 10.0]]]), grow=0)
    assert grid.astype(int).tolist() == [[1, 1, 1], [1, 1, 0], [1, 0, 0]]
    assert origin.tolist() == [5.0, 7.0]
    grid, origin = chart_bitmap(np.array([[[5.0, 7.0], [8.0, 7.0], [5.0, 10.0]]]), grow=1)
    # covered: (1..3, 1), (1..2, 2), (1, 3); each grown to its 3 x 3 neighbourhood
    assert grid.astype(int).tolist() == [[1, 1, 1, 1, 1], [1, 1, 1, 1, 1], [1, 1, 1, 1, 1], [1, 1, 1, 1, 0],
                                         [1, 1, 1, 0, 0]]
    assert origin.tolist() == [4.0, 6.0]
    assert row_spans(grid[3:]).tolist() == [[0, 0, 4], [1, 0, 3]]
    # Random charts: a pixel is marked where some triangle covers part of it (clipped area), grown by a square.
    rng = np.random.default_rng(7)
    for trial in range(40):
        count = int(rng.integers(1, 6))
        pixels = rng.uniform(0, 12, size=(count, 3, 2)) * rng.uniform(0.2, 1.0, size=(count, 1, 2))
        grow = int(rng.integers(0, 3))
        grid, origin = chart_bitmap(pixels, grow=grow)
        shifted = pixels - origin
        covered = np.zeros_like(grid)
        for cy in range(grid.shape[0]):
            for cx in range(grid.shape[1]):
                covered[cy, cx] = any(_clipped_area(t, cx, cy) > 1e-9 for t in shifted)
        expected = binary_dilation(covered, np.ones((2 * grow + 1, 2 * grow + 1), dtype=bool)) if grow else covered
        np.testing.assert_array_equal(grid, expected, err_msg=f"trial {trial}")
        padded = np.pad(grid, ((0, 0), (1, 1))).astype(np.int8)
        rows, starts = np.nonzero(np.diff(padded, axis=1) == 1)
        _, ends = np.nonzero(np.diff(padded, axis=1) == -1)
        np.testing.assert_array_equal(row_spans(grid), np.stack([rows, starts, ends], axis=1))
