"""core.packing: charts packed with translations and quarter turns on the image's pixel grid (hand-computed)."""
import numpy as np
import pytest

from perceptual_uv.core.packing import iter_pack_charts, island_capacity, pack_charts

QUARTER_TURNS = [np.eye(2), np.array([[0, -1], [1, 0]]), -np.eye(2), np.array([[0, 1], [-1, 0]])]


def rectangle(x, y, w, h):
    """Two triangles covering [x, x + w] x [y, y + h], counter-clockwise."""
    a, b, c, d = (x, y), (x + w, y), (x + w, y + h), (x, y + h)
    return [[a, b, c], [a, c, d]]


def charts_of(rectangles):
    uv = np.array([t for r in rectangles for t in rectangle(*r)], dtype=float)
    face_chart = np.repeat(np.arange(len(rectangles)), 2)
    return uv, face_chart


def chart_motion(before, after):
    """Scale s and the linear part L / s of the affine map taking a chart's corners ``before`` to ``after``."""
    p, q = before.reshape(-1, 2), after.reshape(-1, 2)
    A = np.hstack([p, np.ones((len(p), 1))])
    solution, *_ = np.linalg.lstsq(A, q, rcond=None)
    linear = solution[:2].T
    s = np.sqrt(abs(np.linalg.det(linear)))
    return s, linear / s


def pixel_boxes(packing, face_chart):
    """Each chart's [min, max] corner in pixels of the packed image."""
    pixels = packing.uv * packing.size
    return [(pixels[face_chart == c].reshape(-1, 2).min(0), pixels[face_chart == c].reshape(-1, 2).max(0))
            for c in range(face_chart.max() + 1)]


def test_four_unit_squares_at_8_texels_fill_a_16_px_image():
    # Each chart covers exactly 8 x 8 pixels: 256 pixels, the narrowest strip tried is sqrt(256) = 16 wide.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1), (0, 5, 1, 1), (7, 7, 1, 1)])
    packing = pack_charts(uv, face_chart, margin=0, texels_per_unit=8)
    assert packing.size == (16, 16)
    assert packing.coverage == pytest.approx(1.0)
    assert packing.texels_per_unit == 8
    corners = sorted(tuple(np.round(low).astype(int)) for low, _ in pixel_boxes(packing, face_chart))
    assert corners == [(0, 0), (0, 8), (8, 0), (8, 8)]


def test_margin_keeps_charts_that_many_pixels_apart():
    # margin 2: every chart grows by 1 px on each side, 10 x 10 pixels, four of them in a 20 px square.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1), (0, 5, 1, 1), (7, 7, 1, 1)])
    packing = pack_charts(uv, face_chart, margin=2, texels_per_unit=8)
    assert packing.size == (20, 20)
    boxes = pixel_boxes(packing, face_chart)
    for i, (low_i, high_i) in enumerate(boxes):
        assert (low_i >= 1 - 1e-9).all() and (high_i <= 19 + 1e-9).all()  # half a margin to the border
        for low_j, high_j in boxes[i + 1:]:
            gap = np.maximum(low_j - high_i, low_i - high_j).max()  # separation along the better axis
            assert gap >= 2 - 1e-9


def test_every_chart_moves_rigidly_with_one_common_scale():
    rng = np.random.default_rng(3)
    rectangles = [(rng.uniform(0, 5), rng.uniform(0, 5), rng.uniform(0.2, 2), rng.uniform(0.2, 2)) for _ in range(12)]
    uv, face_chart = charts_of(rectangles)
    angles = rng.uniform(0, 2 * np.pi, 12)
    for c, angle in enumerate(angles):  # charts at arbitrary angles: the packer must not undo them
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        uv[face_chart == c] = uv[face_chart == c] @ rotation.T
    packing = pack_charts(uv, face_chart, margin=3, texels_per_unit=20)
    expected_scale = 20 / packing.width
    for c in range(12):
        scale, turn = chart_motion(uv[face_chart == c], packing.uv[face_chart == c])
        assert scale == pytest.approx(expected_scale, rel=1e-9)
        np.testing.assert_allclose(turn, QUARTER_TURNS[packing.turns[c]], atol=1e-9)
    assert packing.uv.min() >= 0 and packing.uv.max() <= 1
    area = sum(w * h for _, _, w, h in rectangles) * 20 ** 2 / (packing.width * packing.height)
    assert packing.coverage == pytest.approx(area)


def test_a_long_chart_is_laid_along_the_strip():
    # A 4 x 1 chart beside four unit squares, 8 texels per unit: 512 px, strips from 23 px wide. Upright (8 wide,
    # 32 tall) it would make the image at least 32 px; lying in a 32 px wide strip it does not fit a 23-27 px
    # strip either, so every strip ends 32 px tall or wide: the packing is 32 px and holds all five.
    uv, face_chart = charts_of([(0, 0, 1, 4), (2, 0, 1, 1), (4, 0, 1, 1), (6, 0, 1, 1), (8, 0, 1, 1)])
    packing = pack_charts(uv, face_chart, margin=0, texels_per_unit=8)
    assert packing.size == (32, 32)
    assert packing.coverage == pytest.approx(8 * 8 * 8 / 32 ** 2)


def test_explicit_resolution_fills_the_image_within_two_percent_of_the_best_density():
    # Four unit squares fit a 32 px image at up to 16 texels per unit, 2 x 2 squares of 16 px; above it a chart
    # touches 17 pixels per side and two no longer fit side by side.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1), (0, 5, 1, 1), (7, 7, 1, 1)])
    packing = pack_charts(uv, face_chart, margin=0, resolution=32)
    assert packing.size == (32, 32)
    assert 16 / 1.02 < packing.texels_per_unit <= 16
    assert packing.uv.min() >= 0 and packing.uv.max() == pytest.approx(1.0)  # scaled up to the border
    assert packing.coverage == pytest.approx(4 * (packing.texels_per_unit / 32) ** 2)


def test_explicit_resolution_keeps_the_margin():
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 2), (0, 5, 2, 1), (7, 7, 1, 1), (9, 9, 0.5, 0.5)])
    packing = pack_charts(uv, face_chart, margin=4, resolution=64)
    boxes = pixel_boxes(packing, face_chart)
    for i, (low_i, high_i) in enumerate(boxes):
        assert (low_i >= 2 - 1e-9).all() and (high_i <= 62 + 1e-9).all()
        for low_j, high_j in boxes[i + 1:]:
            assert np.maximum(low_j - high_i, low_i - high_j).max() >= 4 - 1e-9


def test_a_margin_too_wide_for_the_image_is_refused_saying_what_to_change():
    # Each chart takes at least one pixel plus half the 4 px margin on every side, 5 x 5: two never fit in 8 x 8.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1)])
    with pytest.raises(ValueError, match="do not fit a 8 px image with a 4 px margin: lower the margin"):
        pack_charts(uv, face_chart, margin=4, resolution=8)
    assert pack_charts(uv, face_chart, margin=1, resolution=8).size == (8, 8)


def test_charts_far_apart_pack_as_if_they_were_close():
    # Where the charts lie before packing does not count: 1e6 UV units apart, the same 16 px image as side by side.
    near, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1), (0, 5, 1, 1), (7, 7, 1, 1)])
    far, _ = charts_of([(0, 0, 1, 1), (1e6, 0, 1, 1), (0, -1e6, 1, 1), (1e6, 1e6, 1, 1)])
    assert pack_charts(far, face_chart, margin=0, texels_per_unit=8).size == (16, 16)
    np.testing.assert_allclose(pack_charts(far, face_chart, margin=0, texels_per_unit=8).uv,
                               pack_charts(near, face_chart, margin=0, texels_per_unit=8).uv, atol=1e-9)


def test_zero_area_triangles_go_with_their_chart():
    uv, face_chart = charts_of([(0, 0, 1, 1), (2, 0, 1, 1)])
    sliver = np.array([[[0.5, 0.5], [0.5, 0.5], [0.5, 0.5]]])  # a degenerate triangle inside chart 0
    uv, face_chart = np.concatenate([uv, sliver]), np.append(face_chart, 0)
    packing = pack_charts(uv, face_chart, margin=0, texels_per_unit=8)
    low, high = pixel_boxes(packing, face_chart)[0]
    point = packing.uv[-1, 0] * packing.size
    assert (point >= low).all() and (point <= high).all()
    np.testing.assert_allclose(point, low + 4, atol=1e-9)  # the chart's centre


@pytest.mark.parametrize("options, message", [
    ({}, "exactly one"), ({"resolution": 64, "texels_per_unit": 8}, "exactly one"),
    ({"texels_per_unit": 0}, "positive"), ({"resolution": 0}, "resolution must be"),
])
def test_bad_options_are_refused(options, message):
    uv, face_chart = charts_of([(0, 0, 1, 1)])
    with pytest.raises(ValueError, match=message):
        pack_charts(uv, face_chart, margin=0, **options)


def test_bad_input_is_refused():
    uv, face_chart = charts_of([(0, 0, 1, 1)])
    with pytest.raises(ValueError, match="zero total area"):
        pack_charts(np.zeros_like(uv), face_chart, margin=0, texels_per_unit=8)
    with pytest.raises(ValueError, match="labels"):
        pack_charts(uv, face_chart + 1, margin=0, texels_per_unit=8)
    with pytest.raises(ValueError, match="larger than 16384"):
        pack_charts(uv, face_chart, margin=0, texels_per_unit=20000)


def test_the_generator_hands_control_back_after_each_chart_and_each_try():
    # Five charts at one density: five bitmaps (a yield each) and at least one strip tried; with an explicit
    # resolution every density tried repeats the five bitmaps and one strip, and at least two densities are
    # tried (one that fits, one 5 % denser that does not). Either way the result is pack_charts'.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 2), (0, 5, 2, 1), (7, 7, 1, 1), (9, 9, 0.5, 0.5)])
    for size in ({"texels_per_unit": 8}, {"resolution": 64}):
        stage = iter_pack_charts(uv, face_chart, margin=2, **size)
        yields = 0
        while True:
            try:
                assert next(stage) is None
                yields += 1
            except StopIteration as finished:
                packing = finished.value
                break
        assert yields >= (6 if "texels_per_unit" in size else 12)
        expected = pack_charts(uv, face_chart, margin=2, **size)
        np.testing.assert_array_equal(packing.uv, expected.uv)
        assert packing.size == expected.size


def test_a_placed_bitmap_leaves_signed_runs_and_the_search_jumps_over_it():
    from perceptual_uv.core.chart_bitmaps import row_spans
    from perceptual_uv.core.packing import _empty_rows, _first_fit, _occupy

    free_run = _empty_rows(3, 10)
    longest = np.full(3, 10, dtype=np.int32)
    block = row_spans(np.ones((2, 2), dtype=bool))
    _occupy(free_run, longest, block, 2, 0, 3)  # a 2 x 2 block at column 3 of rows 0 and 1
    # free pixels: the free run to their right; occupied: minus the occupied run from them
    assert free_run[0].tolist() == [3, 2, 1, -2, -1, 5, 4, 3, 2, 1]
    assert free_run[1].tolist() == free_run[0].tolist()
    assert free_run[2].tolist() == list(range(10, 0, -1))
    assert longest.tolist() == [5, 5, 10]
    bar4 = row_spans(np.ones((1, 4), dtype=bool))
    assert _first_fit(free_run, longest, bar4, 1, 4, 0, 2) == (0, 5)  # 3 free pixels, then past the block
    bar6 = row_spans(np.ones((1, 6), dtype=bool))
    assert _first_fit(free_run, longest, bar6, 1, 6, 0, 2) == (2, 0)  # only the free row is long enough
    assert _first_fit(free_run, longest, bar6, 1, 6, 0, 1) == (-1, -1)  # not above row 1
    empty = np.empty((0, 3), dtype=np.int32)  # a chart of zero area: no pixel, it fits at the first place
    assert _first_fit(free_run, longest, empty, 1, 1, 0, 2) == (0, 0)


def _brute_force_place_all(grids, order, width, limit):
    """Every chart in ``order``: the lowest top, then lowest row, then leftmost column of any quarter turn's
    bitmap (``grids[chart][turn]``) on free pixels of a ``limit`` x ``width`` strip, tried pixel by pixel."""
    taken = np.zeros((limit, width), dtype=bool)
    positions, turns = {}, {}
    for chart in order:
        best = None
        for turn, grid in enumerate(grids[chart]):
            rows, cols = grid.shape
            for y in range(limit - rows + 1):
                for x in range(width - cols + 1):
                    if not (taken[y:y + rows, x:x + cols] & grid).any():
                        key = (y + rows, y, x)
                        if best is None or key < best[0]:
                            best = (key, turn, y, x, grid)
                        break  # the leftmost place of this row
        if best is None:
            return None
        _, turn, y, x, grid = best
        taken[y:y + grid.shape[0], x:x + grid.shape[1]] |= grid
        positions[chart], turns[chart] = (x, y), turn
    return positions, turns


def test_placement_matches_a_pixel_by_pixel_first_fit():
    from perceptual_uv.core.chart_bitmaps import row_spans
    from perceptual_uv.core.packing import _place_all
    from perceptual_uv.core.progress import run_generator

    rng = np.random.default_rng(3)
    for trial in range(30):
        grids = []
        for _ in range(int(rng.integers(3, 9))):
            grid = rng.random((int(rng.integers(1, 6)), int(rng.integers(1, 6)))) < 0.7
            grid[0, :] |= ~grid.any(axis=0)  # no empty column or row: a bitmap spans its box
            grid[:, 0] |= ~grid.any(axis=1)
            grids.append([np.rot90(grid, k) for k in range(4)])
        bitmaps = [[(g.shape, row_spans(g), None) for g in turns] for turns in grids]
        order = rng.permutation(len(grids))
        width = limit = int(rng.integers(6, 12))
        expected = _brute_force_place_all(grids, order, width, limit)
        placed = run_generator(_place_all(bitmaps, order, width, limit=limit))
        if expected is None:
            assert placed is None, trial
            continue
        assert placed is not None, trial
        positions, chosen, used = placed
        for chart in order:
            assert tuple(positions[chart].astype(int)) == expected[0][chart], trial
            assert chosen[chart] == expected[1][chart], trial


def test_charts_that_do_not_fit_largest_first_are_placed_longest_perimeter_first():
    from perceptual_uv.core.chart_bitmaps import row_spans
    from perceptual_uv.core.packing import _place_all, _placing_orders
    from perceptual_uv.core.progress import run_generator

    # Rectangles (columns x rows) A 7 x 6, B 4 x 5, C 7 x 1, D 4 x 3: 81 px. Largest first (A, B, D, C) in a
    # 10 x 10 image: A at (0, 0), B turned to 5 x 4 at (0, 6), D turned to 3 x 4 at (7, 0) (top 4), then C finds no
    # row with 7 free pixels and no column with 7 free rows (column 7: rows 4-9). Longest perimeter first (A, B, C,
    # D): C stands at column 7, rows 0-6, and D lies at (5, 7).
    uv, face_chart = charts_of([(0, 0, 7, 6), (20, 0, 4, 5), (40, 0, 7, 1), (60, 0, 4, 3)])
    pixels = np.array([42, 20, 7, 12])
    boxes = np.array([[6, 7], [5, 4], [1, 7], [3, 4]])
    orders = _placing_orders(pixels, boxes)
    assert [order.tolist() for order in orders] == [[0, 1, 3, 2], [0, 1, 2, 3]]
    grids = [np.ones((rows, cols), dtype=bool) for rows, cols in boxes]
    bitmaps = [[(np.rot90(g, k).shape, row_spans(np.rot90(g, k)), None) for k in range(4)] for g in grids]
    assert run_generator(_place_all(bitmaps, orders[0], 10, limit=10)) is None
    packing = pack_charts(uv, face_chart, margin=0, texels_per_unit=1.0)
    assert packing.size == (10, 10)
    expected = [([0, 0], [7, 6]), ([0, 6], [5, 10]), ([7, 0], [8, 7]), ([5, 7], [9, 10])]
    for (low, high), (want_low, want_high) in zip(pixel_boxes(packing, face_chart), expected):
        np.testing.assert_allclose(low, want_low, atol=1e-9)
        np.testing.assert_allclose(high, want_high, atol=1e-9)
    # A 10 px image holds them at their own density (within the density search's 1 % steps; largest first alone
    # reaches 0.91 of it).
    assert pack_charts(uv, face_chart, margin=0, resolution=10).texels_per_unit > 0.99


def test_no_placing_try_is_made_twice(monkeypatch):
    """The last step tries the first size that fits in the orders after the one that fitted and the sizes after it
    in every order; the tries before (the density search's) are never made again."""
    from perceptual_uv.core import packing as packing_module

    tries = []
    place_all = packing_module._place_all

    def recording(bitmaps, chart_order, width, *, limit):
        tries.append((id(bitmaps), tuple(chart_order), width, limit))  # one bitmaps list per density
        return (yield from place_all(bitmaps, chart_order, width, limit=limit))

    monkeypatch.setattr(packing_module, "_place_all", recording)
    # The four rectangles above: largest first never fits them at their own density, the second order does.
    uv, face_chart = charts_of([(0, 0, 7, 6), (20, 0, 4, 5), (40, 0, 7, 1), (60, 0, 4, 3)])
    for aspects in ((1.0,), (1.0, 4 / 3, 3 / 4)):
        tries.clear()
        pack_charts(uv, face_chart, margin=0, resolution=10, aspects=aspects)
        assert len(tries) == len(set(tries)) > 0


def test_image_sizes_keep_to_the_square_pixel_count():
    from perceptual_uv.core.packing import image_sizes

    # 16 * sqrt(2) = 22.6 -> 23 columns, 256 // 23 = 11 rows; 16 / sqrt(2) = 11.3 -> 11 columns, 23 rows
    assert image_sizes(16, (1.0, 2.0, 0.5)) == [(16, 16), (23, 11), (11, 23)]
    assert image_sizes(3, (4.0,)) == [(6, 1)]  # 9 // 6: at least one row


def test_two_squares_take_a_two_to_one_image_of_half_the_pixels():
    # Two 8 x 8 px charts: the square search ends at 16 x 16 (they do not sit side by side in fewer than 16
    # columns), 256 px. Aspect 2 at side 11 is round(11 sqrt 2) x round(11 / sqrt 2) = 16 x 8: both side by side,
    # every pixel covered; side 10 gives 14 x 7, lower than a chart.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1)])
    assert pack_charts(uv, face_chart, margin=0, texels_per_unit=8).size == (16, 16)
    packing = pack_charts(uv, face_chart, margin=0, texels_per_unit=8, aspects=(1.0, 2.0, 0.5))
    assert packing.size == (16, 8)
    assert packing.coverage == pytest.approx(1.0)
    assert packing.texels_per_unit == 8


def test_at_a_pixel_count_the_densest_aspect_wins_and_texels_stay_square():
    # 256 px: the 16 x 16 square holds two unit squares at 8 texels per unit (side by side), the 23 x 11 image at
    # 11 (its height; 2 x 11 = 22 <= 23 columns): 242 of its 253 pixels covered.
    uv, face_chart = charts_of([(0, 0, 1, 1), (3, 0, 1, 1)])
    square = pack_charts(uv, face_chart, margin=0, resolution=16)
    assert square.size == (16, 16) and square.texels_per_unit == pytest.approx(8, rel=0.02)
    packing = pack_charts(uv, face_chart, margin=0, resolution=16, aspects=(1.0, 2.0))
    assert packing.size == (23, 11)
    assert packing.texels_per_unit == pytest.approx(11)
    assert packing.coverage == pytest.approx(242 / 253)
    pixels = packing.uv * packing.size
    assert pixels.min() >= -1e-9 and (pixels.reshape(-1, 2).max(0) <= (23 + 1e-9, 11 + 1e-9)).all()
    for c in range(2):  # each chart: a uniform scale by 11 and a quarter turn in pixels
        scale, turn = chart_motion(uv[face_chart == c], pixels[face_chart == c])
        assert scale == pytest.approx(11)
        assert any(np.allclose(turn, q) for q in QUARTER_TURNS)


@pytest.mark.parametrize("aspects", [(), (0.0,), (32.0,)])
def test_aspects_outside_sixteen_to_one_are_refused(aspects):
    uv, face_chart = charts_of([(0, 0, 1, 1)])
    with pytest.raises(ValueError, match="aspects"):
        pack_charts(uv, face_chart, margin=0, texels_per_unit=8, aspects=aspects)


def test_island_capacity_is_the_most_islands_a_packing_holds():
    # An island's bitmap is at least one pixel grown by (margin + 1) // 2 on each side: 5 x 5 px with a 4 px
    # margin, 3 x 3 with 1 or 2, 1 x 1 with none; floor(w / s) * floor(h / s) of them fit.
    assert island_capacity(8, 8, 4) == 1
    assert island_capacity(11, 5, 4) == 2
    assert island_capacity(10, 10, 4) == 4
    assert island_capacity(9, 9, 1) == island_capacity(9, 9, 2) == 9
    assert island_capacity(9, 9, 3) == 1
    assert island_capacity(7, 3, 0) == 21
    # tight on tiny islands: as many as it says pack, one more does not, whatever the scale
    base = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    for margin, side in ((0, 3), (1, 6), (4, 10)):
        capacity = island_capacity(side, side, margin)
        for count in (capacity, capacity + 1):
            uv = np.stack([base + (3.0 * i, 0.0) for i in range(count)])
            if count == capacity:
                assert pack_charts(uv, np.arange(count), margin=margin, resolution=side).size == (side, side)
            else:
                with pytest.raises(ValueError, match="do not fit"):
                    pack_charts(uv, np.arange(count), margin=margin, resolution=side)
