"""Packing UV charts into one image with translations and quarter turns, on the image's pixel grid.

Each chart is drawn at a fixed texel density into a bitmap of the pixels it touches (conservative raster),
grown by half the margin on every side; the bitmaps, largest first, are placed bottom-left in a strip as wide as
the image, each in the quarter turn whose top edge ends lowest, and the smallest image that holds them all is
searched. Where largest first does not fit, the charts are placed again longest perimeter first: a greedy
placement's result depends on its order, and a second order lowers the odds that an unlucky one sets the size.
Charts move by whole pixels, so the gap between two charts is at least the margin in pixels of the final image,
and nothing rotates by other angles or shears (paper Sec. 5.1, "Texture packing": the orientation the mesh-wise
stage chose relative to the texel grid is kept).

The texel density is what the cost fixes (Eq. 20-21): at ``d`` pixels per unit of the fitted UV map, a chart
of fitted area ``a`` covers ``d^2 a`` texels whatever the image size, so the image's pixel count is simply what
the packing needs. With an explicit resolution (a pixel count) the density is searched instead.

The image is a square unless the caller lets it take other width-to-height ratios (``aspects``): a few large
charts often fill a rectangle better than a square (a bottle's label and cap, a fruit's skin and cut face), and
at the same pixel count the image that holds them densest carries the most texels. Texels stay square: a chart
is scaled alike along both axes whatever the image's shape.

:func:`iter_pack_charts` is the same packing as a generator that hands control back after each chart's bitmaps
and each try (an image size or a density), so that the Blender operator driving the pipeline stays responsive
while many charts or a density search take seconds.
"""
import dataclasses

import numpy as np

from ._jit import njit
from .chart_bitmaps import chart_bitmap, row_spans
from .charts import signed_uv_areas
from .progress import run_generator

__all__ = ["IMAGE_ASPECTS", "Packing", "image_sizes", "aspect_size", "island_capacity", "pack_charts",
           "iter_pack_charts"]

_MAX_SIDE = 16384
#: Width-to-height ratios a packed image may take when the caller allows other shapes than a square.
IMAGE_ASPECTS = (1.0, 4 / 3, 3 / 4, 3 / 2, 2 / 3, 2.0, 1 / 2)


@dataclasses.dataclass(frozen=True)
class Packing:
    """A packed UV map.

    Attributes
    ----------
    uv : (m, 3, 2) float64 ndarray
        Per-corner UV coordinates in the unit square of a ``width x height`` px image.
    width, height : int
        The image's size in pixels.
    turns : (k,) int ndarray
        Quarter turns (counter-clockwise) of each chart.
    texels_per_unit : float
        Pixels of the image per unit of the input UV map, along both axes: a chart's ``u`` is scaled by
        ``texels_per_unit / width``, its ``v`` by ``texels_per_unit / height``.
    coverage : float
        Fraction of the image the charts' triangles cover.
    """

    uv: np.ndarray
    width: int
    height: int
    turns: np.ndarray
    texels_per_unit: float
    coverage: float

    @property
    def size(self):
        """``(width, height)`` in pixels."""
        return (self.width, self.height)


def image_sizes(side, aspects):
    """The image sizes of ``aspects`` (width over height) that hold at most ``side * side`` pixels.

    Parameters
    ----------
    side : int
        Side of the square whose pixel count every size keeps to.
    aspects : sequence of float
        Width-to-height ratios.

    Returns
    -------
    list of (int, int)
        ``(width, height)`` per aspect: ``width = round(side * sqrt(aspect))``, ``height`` the most rows that
        keep ``width * height <= side * side`` (an aspect of 1 gives ``(side, side)``).
    """
    sizes = []
    for aspect in aspects:
        width = max(1, int(round(side * np.sqrt(aspect))))
        sizes.append((width, max(1, side * side // width)))
    return sizes


def aspect_size(side, aspect, *, minimum=1):
    """``(round(side sqrt(aspect)), round(side / sqrt(aspect)))``, each at least ``minimum``: the image of width-to-
    height ratio ``aspect`` with about the pixels of a ``side x side`` square (unlike :func:`image_sizes`, it may
    hold a few more)."""
    return (max(minimum, int(round(side * np.sqrt(aspect)))), max(minimum, int(round(side / np.sqrt(aspect)))))


def island_capacity(width, height, margin):
    """The most islands a ``width x height`` image holds with ``margin``, however small they are packed.

    Every island's bitmap holds at least one pixel grown by ``g = (margin + 1) // 2`` on every side, a square of
    side ``s = 1 + 2 g``, and the grown bitmaps of two islands do not overlap (:func:`iter_pack_charts`); at most
    ``floor(width / s) * floor(height / s)`` disjoint ``s x s`` squares fit in the image. More islands than that
    cannot be packed at any density.

    Parameters
    ----------
    width, height : int
        The image's size in pixels.
    margin : int
        Smallest gap between islands, in pixels.

    Returns
    -------
    int
    """
    side = 1 + 2 * ((int(margin) + 1) // 2)
    return (int(width) // side) * (int(height) // side)


def pack_charts(uv, face_chart, *, margin, texels_per_unit=None, resolution=None, aspects=(1.0,)):
    """Pack the charts of ``uv`` with translations and quarter turns into one image.

    :func:`iter_pack_charts` run to its end; see it for the parameters.

    Returns
    -------
    Packing
    """
    return run_generator(iter_pack_charts(uv, face_chart, margin=margin, texels_per_unit=texels_per_unit,
                                          resolution=resolution, aspects=aspects))


def iter_pack_charts(uv, face_chart, *, margin, texels_per_unit=None, resolution=None, aspects=(1.0,)):
    """Generator: pack the charts of ``uv`` with translations and quarter turns into one image.

    Yields None after each chart's bitmap in each quarter turn and after each chart placed in each try; returns
    the :class:`Packing` (through ``StopIteration.value``, as ``yield from`` gives it).

    Parameters
    ----------
    uv : (m, 3, 2) array_like
        Per-corner UV coordinates of the charts, at any common scale.
    face_chart : (m,) array_like of int
        Chart of each triangle, labels ``0 .. k-1``.
    margin : int
        Smallest gap between charts, in pixels of the packed image.
    texels_per_unit : float, optional
        Pixels per unit of ``uv``: each chart keeps this density and the image is as small (in pixels) as the
        packing found needs. Exactly one of ``texels_per_unit`` and ``resolution`` is given.
    resolution : int, optional
        Side of the square whose pixel count the image keeps (:func:`image_sizes`): the density is the largest
        found (within 1 %) whose packing fits.
    aspects : sequence of float, optional
        Width-to-height ratios the image may take (:data:`IMAGE_ASPECTS`); the default is a square. Every aspect
        is packed and the one that holds the charts at the highest density (``resolution``) or in the fewest
        pixels (``texels_per_unit``) wins, the earlier of equals.

    Returns
    -------
    Packing

    Raises
    ------
    ValueError
        Bad shapes, no chart with area, or a packing larger than 16384 px.

    References
    ----------
    Sun et al. 2022, Sec. 5.1 ("translations and 90-degree rotations only") and Eq. 20-21 (texel cost).
    """
    uv = np.asarray(uv, dtype=np.float64)
    face_chart = np.asarray(face_chart, dtype=np.int64)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2) or face_chart.shape != uv.shape[:1]:
        raise ValueError(f"uv must be (m, 3, 2) and face_chart (m,), got {uv.shape} and {face_chart.shape}")
    if (texels_per_unit is None) == (resolution is None):
        raise ValueError("give exactly one of texels_per_unit and resolution")
    if margin < 0:
        raise ValueError(f"margin must be >= 0 pixels, got {margin}")
    aspects = tuple(float(aspect) for aspect in aspects)
    if not aspects or not all(1 / 16 <= aspect <= 16 for aspect in aspects):
        raise ValueError(f"aspects must be width-to-height ratios in [1/16, 16], got {aspects}")
    if not np.isfinite(uv).all():
        raise ValueError("uv has non-finite coordinates")
    area = float(np.abs(signed_uv_areas(uv)).sum())
    if area <= 0:
        raise ValueError("the charts have zero total area: nothing to pack")
    charts = np.unique(face_chart)
    if charts[0] < 0 or charts[-1] != len(charts) - 1:
        raise ValueError("face_chart labels must be 0 .. k-1")
    layout = _Layout(uv, face_chart, len(charts), int(margin))
    if texels_per_unit is not None:
        if not texels_per_unit > 0:
            raise ValueError(f"texels_per_unit must be positive, got {texels_per_unit}")
        return (yield from _pack_at(layout, float(texels_per_unit), aspects))
    if not 1 <= resolution <= _MAX_SIDE:
        raise ValueError(f"resolution must be in [1, {_MAX_SIDE}], got {resolution}")
    best = yield from _pack_into(layout, image_sizes(int(resolution), aspects), int(resolution) * np.sqrt(0.6 / area))
    if best is None:
        raise ValueError(f"the charts do not fit a {resolution} px image with a {margin} px margin: lower the "
                         "margin or give the image more pixels (a higher cost or resolution)")
    return best


class _Layout:
    """The charts to pack and their bitmaps at each density tried (kept: the aspects try the same densities)."""

    def __init__(self, uv, face_chart, count, margin):
        self.uv, self.count, self.margin = uv, count, margin
        self.grow = (margin + 1) // 2
        self.order = np.argsort(face_chart, kind="stable")
        self.starts = np.searchsorted(face_chart[self.order], np.arange(count + 1))
        # Where the charts lie relative to each other does not count (they are moved), only each chart's own
        # extent and their total area.
        self.extent = (np.maximum.reduceat(uv[self.order].max(axis=1), self.starts[:-1])
                       - np.minimum.reduceat(uv[self.order].min(axis=1), self.starts[:-1])).max()
        self.root_area = np.sqrt(np.abs(signed_uv_areas(uv)).sum())
        self._bitmaps = {}

    def too_dense(self, density):
        return self.extent * density > _MAX_SIDE or self.root_area * density > _MAX_SIDE

    def bitmaps(self, density):
        """Generator: per chart and quarter turn (bitmap's shape, its rows' spans, origin), the placing orders
        (:func:`_placing_orders`), the pixels they cover and the largest of the charts' narrower sides; yields
        after each chart's bitmap in each turn the first time a density is asked for."""
        if density not in self._bitmaps:
            bitmaps = []
            sizes = np.zeros(self.count, dtype=np.int64)
            for chart in range(self.count):
                pixels = self.uv[self.order[self.starts[chart]:self.starts[chart + 1]]] * density
                turns = []
                for turn in range(4):
                    grid, origin = chart_bitmap(_turn(pixels, turn), grow=self.grow)
                    turns.append((grid.shape, row_spans(grid), origin))
                    if turn == 0:
                        sizes[chart] = grid.sum()
                    yield
                bitmaps.append(turns)
            boxes = np.array([turns[0][0] for turns in bitmaps], dtype=np.int64).reshape(-1, 2)
            self._bitmaps[density] = (bitmaps, _placing_orders(sizes, boxes), int(sizes.sum()),
                                      int(boxes.min(axis=1).max()))
        return self._bitmaps[density]

    def place(self, density, width, height, *, every_order=False, first_order=0):
        """Generator: the charts at ``density`` placed in a ``width x height`` image in the placing orders from
        ``first_order`` on, as a list of ``(order, packing)``: the first order that fits, or with ``every_order``
        every one that fits; empty if none does. Yields after each bitmap made and each chart placed."""
        bitmaps, orders, _, narrowest = yield from self.bitmaps(density)
        found = []
        if min(width, height) >= narrowest and max(width, height) <= _MAX_SIDE:
            for order in range(first_order, len(orders)):
                placed = yield from _place_all(bitmaps, orders[order], width, limit=height)
                if placed is not None:
                    found.append((order, self._packing(bitmaps, density, width, height, *placed[:2])))
                    if not every_order:
                        break
        return found

    def _packing(self, bitmaps, density, width, height, positions, chosen):
        out = np.empty_like(self.uv)
        for chart in range(self.count):
            rows = self.order[self.starts[chart]:self.starts[chart + 1]]
            turn = chosen[chart]
            origin = bitmaps[chart][turn][2]
            out[rows] = (_turn(self.uv[rows] * density, turn) - origin + positions[chart]) / (width, height)
        coverage = float(np.abs(signed_uv_areas(out)).sum())
        return Packing(uv=out, width=int(width), height=int(height), turns=np.asarray(chosen, dtype=np.int64),
                       texels_per_unit=float(density), coverage=coverage)


def _placing_orders(pixels, boxes):
    """The orders the charts are placed in, each tried when the ones before it do not fit: largest bitmap first,
    then longest box perimeter first (ties in the order before), without repeats.

    Parameters
    ----------
    pixels : (k,) int ndarray
        Pixels of each chart's bitmap.
    boxes : (k, 2) int ndarray
        Rows and columns of each chart's bitmap.

    Returns
    -------
    tuple of (k,) int ndarray
    """
    largest = np.argsort(-pixels, kind="stable")
    orders = [largest]
    perimeter = largest[np.argsort(-boxes[largest].sum(axis=1), kind="stable")]
    if not np.array_equal(perimeter, largest):
        orders.append(perimeter)
    return tuple(orders)


def _pack_into(layout, sizes, density):
    """Generator: the densest packing found that fits one of ``sizes`` (``(width, height)`` each), scaled up to
    fill it, or None.

    Each try fills a strip as wide as an image bottom-left, in each placing order until one is no higher than
    the image; a density fits when one size does. The density moves in 5 % steps from ``density`` (a guess)
    until one try fits and the next does not, then 1 % steps go down from the one that did not (whether a
    packing fits is not monotonic in the density) and the first that fits wins. Every size and order that fits
    at that density is scaled up until its charts reach the far border but for half a margin (every gap grows
    with it), and the densest result wins, the earlier size (then order) of equals. The sizes share one density
    search, so they share its bitmaps too.
    """
    # generator: the first size's packing that fits at ``density`` as ``[(order, packing)]``, or ``[]``
    def attempt(density):
        if layout.too_dense(density):
            return []
        for width, height in sizes:
            found = yield from layout.place(density, width, height)
            if found:
                return found
        return []

    best = yield from attempt(density)
    too_dense = None
    for _ in range(100):
        if not best:  # shrink until a try fits
            too_dense, density = density, density / 1.05
            best = yield from attempt(density)
            continue
        if too_dense is not None:
            break
        larger = yield from attempt(density * 1.05)  # grow until a try does not fit
        if not larger:
            too_dense = density * 1.05
        else:
            density, best = density * 1.05, larger
    if not best:
        return None
    for step in range(1, 5):
        candidate = too_dense / 1.01 ** step
        if candidate <= density:
            break
        finer = yield from attempt(candidate)
        if finer:
            density, best = candidate, finer
            break
    # the sizes before the first that fits do not fit; that one in the orders after the one that fitted, and those
    # after it in every order, may
    (order, packing), = best
    first = sizes.index(packing.size)
    for index in range(first, len(sizes)):
        best.extend((yield from layout.place(density, *sizes[index], every_order=True,
                                             first_order=order + 1 if index == first else 0)))
    return max((_fill(packing, layout.margin) for _, packing in best), key=lambda packing: packing.texels_per_unit)


def _fill(packing, margin):
    """``packing`` scaled up until its charts reach the far border but for half a margin."""
    width, height = packing.size
    reach = packing.uv.reshape(-1, 2).max(axis=0) * (width, height)
    room = np.array([width, height], dtype=np.float64) - (margin + 1) // 2
    scale = max(float(np.min(np.where(reach > 0, room / np.maximum(reach, 1e-300), np.inf))), 1.0)
    if not np.isfinite(scale):
        scale = 1.0
    size = np.array([width, height], dtype=np.float64)
    return Packing(uv=packing.uv * size * scale / size, width=width, height=height, turns=packing.turns,
                   texels_per_unit=packing.texels_per_unit * scale,
                   coverage=packing.coverage * (width * scale / width) ** 2)


def _pack_at(layout, density, aspects):
    """Generator: pack at ``density`` into the image of ``aspects`` with the fewest pixels found; yields after
    each chart's bitmaps and each chart placed."""
    if layout.too_dense(density):
        raise ValueError(f"the charts need an image larger than {_MAX_SIDE} px at {density:.4g} texels per UV "
                         "unit; lower the target cost or set an explicit resolution")
    _, _, total, narrowest = yield from layout.bitmaps(density)
    best = None
    for aspect in aspects:
        def attempt(side):  # generator: the packing in the image of this side, or None
            found = yield from layout.place(density, *aspect_size(side, aspect))
            return found[0][1] if found else None

        # the image's shorter side holds the widest chart's narrower side; its pixels hold the charts'
        start = max(int(np.ceil(narrowest / min(np.sqrt(aspect), 1 / np.sqrt(aspect)))), int(np.ceil(np.sqrt(total))))
        packing = yield from _smallest_side(attempt, start)
        if packing is not None and (best is None or packing.width * packing.height < best.width * best.height):
            best = packing
    if best is None:
        raise ValueError(f"the charts need an image larger than {_MAX_SIDE} px at {density:.4g} texels per UV "
                         "unit; lower the target cost or set an explicit resolution")
    return best


def _smallest_side(attempt, start):
    """Generator: the packing of the smallest side found for which the generator ``attempt(side)`` fits: 5 %
    steps from ``start`` until one side fits and the one below does not, then 1 % steps up from that one
    (fitting is not monotonic in the side); yields what ``attempt`` yields."""
    side, too_small = start, None
    best = yield from attempt(start)
    for _ in range(200):
        if best is None:  # grow until a side fits
            too_small, side = side, max(side + 1, int(np.ceil(side * 1.05)))
            if side > _MAX_SIDE:
                return None
            best = yield from attempt(side)
            continue
        if too_small is not None:
            break
        smaller_side = min(side - 1, int(side / 1.05))
        smaller = None
        if smaller_side >= 1:  # shrink until a side does not fit
            smaller = yield from attempt(smaller_side)
        if smaller is None:
            too_small = smaller_side
        else:
            side, best = smaller_side, smaller
    for step in range(1, 5):
        candidate = int(np.ceil(too_small * 1.01 ** step))
        if candidate >= side:
            break
        finer = yield from attempt(candidate)
        if finer is not None:
            return finer
    return best


def _turn(points, turn):
    """``points`` (..., 2) turned by ``turn`` quarter turns counter-clockwise about the origin."""
    x, y = points[..., 0], points[..., 1]
    turned = [(x, y), (-y, x), (-x, -y), (y, -x)][turn % 4]
    return np.stack(turned, axis=-1)


def _place_all(bitmaps, chart_order, width, *, limit):
    """Generator: bottom-left placement of every chart in a strip ``width`` wide, no higher than ``limit``;
    yields after each chart placed; returns positions, turns and the used height, or None if they do not fit."""
    count = len(bitmaps)
    # A chart whose top would pass the limit does not fit: the strip holds the limit's rows only, and each turn's
    # search stops at the rows where its top would pass the limit or the best turn's top so far.
    free_run = _empty_rows(limit, width)
    longest = np.full(limit, width, dtype=np.int32)
    positions = np.zeros((count, 2))
    chosen = np.zeros(count, dtype=np.int64)
    used = 0
    lowest = 0
    for chart in chart_order:
        best = None
        for turn, ((rows, cols), spans, _) in enumerate(bitmaps[chart]):
            if cols > width or rows > limit:
                continue
            stop = limit - rows if best is None else min(limit - rows, best[0][0] - rows)
            y, x = _first_fit(free_run, longest, spans, rows, cols, lowest, stop)
            if y < 0:
                continue
            key = (y + rows, y, x)
            if best is None or key < best[0]:
                best = (key, turn, y, x, spans, rows)
        if best is None:
            return None
        (top, _, _), turn, y, x, spans, rows = best
        _occupy(free_run, longest, spans, rows, y, x)
        positions[chart] = (x, y)
        chosen[chart] = turn
        used = max(used, top)
        while lowest < limit and longest[lowest] == 0:
            lowest += 1
        yield
    return positions, chosen, used


def _empty_rows(height, width):
    """Runs of ``height`` empty rows: at column ``c``, ``width - c`` free pixels to the right.

    In a row, a free pixel holds the length of the free run from it to the right (> 0), an occupied one minus
    the length of the occupied run from it (< 0) (:func:`_occupy`)."""
    return np.repeat(np.arange(width, 0, -1, dtype=np.int32)[None, :], height, axis=0)


@njit
def _first_fit(free_run, longest, spans, rows, cols, lowest, stop):
    """Lowest row, no higher than ``stop``, then leftmost column, where every span of the bitmap lands on free
    pixels; (-1, -1) if none.

    ``free_run`` is signed (:func:`_empty_rows`): where a span does not fit, the search jumps past the free run
    it met and the occupied run after it, or past the occupied run it started in, in one step; any failing span
    gives a jump that skips no valid place, so the order the spans are tried in does not change the result.
    ``longest`` holds each row's longest free run: a row where the bitmap's widest span would lie without a
    free run that long is skipped (testing every span there costs more than the places it saves).
    """
    height, width = free_run.shape
    count = spans.shape[0]
    widest_row, widest_length = 0, 0  # an empty bitmap (a chart of zero area) fits anywhere
    for s in range(count):
        if spans[s, 2] - spans[s, 1] > widest_length:
            widest_row, widest_length = spans[s, 0], spans[s, 2] - spans[s, 1]
    failed = 0  # the span that failed last is tried first at the next place: it usually fails again
    for y in range(lowest, min(height - rows, stop) + 1):
        if longest[y + widest_row] < widest_length:
            continue
        x = 0
        while x <= width - cols:
            ok = True
            for k in range(count):
                s = k + failed if k + failed < count else k + failed - count
                row, start, end = spans[s, 0], spans[s, 1], spans[s, 2]
                line = free_run[y + row]
                run = line[x + start]
                if run < end - start:
                    ok = False
                    failed = s
                    if run <= 0:
                        x -= run  # start in the first free pixel after this occupied run
                    elif x + start + run < width:
                        x += run - line[x + start + run]  # past this free run and the occupied run that ends it
                    else:
                        x = width  # the free run reaches the row's end and is too short: no place further right
                    break
            if ok:
                return y, x
    return -1, -1


@njit
def _occupy(free_run, longest, spans, rows, y, x):
    """Mark the bitmap's spans at ``(x, y)`` occupied and recompute the runs and the longest free run of the rows
    it touches."""
    width = free_run.shape[1]
    for s in range(spans.shape[0]):
        row, start, end = spans[s, 0], spans[s, 1], spans[s, 2]
        for c in range(x + start, x + end):
            free_run[y + row, c] = 0
    for row in range(rows):
        line = free_run[y + row]
        free = 0
        busy = 0
        most = 0
        for c in range(width - 1, -1, -1):
            if line[c] <= 0:
                free = 0
                busy += 1
                line[c] = -busy
            else:
                busy = 0
                free += 1
                line[c] = free
                most = max(most, free)
        longest[y + row] = most
