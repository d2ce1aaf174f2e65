"""A chart's pixels on the packed image's grid: the bitmaps :mod:`.packing` places.

A chart's bitmap is the conservative raster of its triangles (every pixel a triangle covers part of), grown by
half the packing's margin; its rows' runs of marked pixels are what the packer's first fit tests against the
image's free runs. A triangle's pixels in one row are one run (its part in the row is convex), so each row
costs the separating-axes tests at the run's two ends, not one per pixel of the triangle's box.
"""
import numpy as np

from ._jit import njit

__all__ = ["chart_bitmap", "row_spans"]


def chart_bitmap(pixels, *, grow):
    """The pixels a chart's triangles overlap, grown by ``grow`` pixels on every side.

    The chart's lower corner lands on a pixel corner ``grow`` pixels in. A pixel is marked where a triangle
    covers part of it (more than its boundary: a conservative raster), then every pixel within ``grow`` of a
    marked one along each axis is marked too (a square dilation), so two bitmaps placed without overlap keep their
    charts ``2 grow`` pixels apart.

    Parameters
    ----------
    pixels : (m, 3, 2) ndarray of float64
        The chart's triangles in pixels of the image (u, v).
    grow : int
        Pixels added on every side.

    Returns
    -------
    grid : (rows, cols) bool ndarray
        The bitmap (rows: v, columns: u), ``ceil`` of the chart's extent plus ``2 grow`` along each axis.
    origin : (2,) ndarray of float64
        The bitmap's lower corner in the coordinates of ``pixels``.
    """
    low = pixels.reshape(-1, 2).min(axis=0)
    extent = pixels.reshape(-1, 2).max(axis=0) - low
    shape = (np.maximum(np.ceil(extent), 1) + 2 * grow).astype(np.int64)
    grid = np.zeros((shape[1], shape[0]), dtype=np.bool_)
    origin = low - grow
    _touch_triangles(pixels - origin, grid, grow)
    return grid, origin


@njit
def _touch_triangles(pixels, grid, grow):
    """Mark in ``grid`` every pixel a triangle overlaps, then grow the marks by ``grow`` pixels on every side."""
    rows, cols = grid.shape
    touched = np.zeros((rows, cols), dtype=np.bool_)
    normals = np.empty((3, 2))
    projections = np.empty((3, 2))
    for t in range(pixels.shape[0]):
        x0, y0 = pixels[t, 0, 0], pixels[t, 0, 1]
        x1, y1 = pixels[t, 1, 0], pixels[t, 1, 1]
        x2, y2 = pixels[t, 2, 0], pixels[t, 2, 1]
        _edge_axes(x0, y0, x1, y1, x2, y2, normals, projections)
        # pixels [c, c + 1) that meet the open interval of the triangle's extent (at least one per axis)
        cx0 = int(np.floor(min(x0, x1, x2)))
        cx1 = max(cx0, int(np.ceil(max(x0, x1, x2))) - 1)
        cy0 = int(np.floor(min(y0, y1, y2)))
        cy1 = max(cy0, int(np.ceil(max(y0, y1, y2))) - 1)
        first, last = max(cx0, 0), min(cx1, cols - 1)
        for cy in range(max(cy0, 0), min(cy1, rows - 1) + 1):
            # The triangle meets a run of the row's pixels (its part in the row is convex). The run's ends are
            # searched from where that part begins and ends along x, a separating-axes test per pixel they move
            # by; where rounding puts the guess off the run, the search walks the row until it meets it.
            x_low, x_high = _slab_extent(x0, y0, x1, y1, x2, y2, cy, cy + 1)
            left = min(max(int(np.floor(x_low)), first), last)
            if not _box_meets_axes(normals, projections, left, cy):
                probe = left + 1
                while probe <= last and not _box_meets_axes(normals, projections, probe, cy):
                    probe += 1
                if probe > last:
                    probe = left - 1
                    while probe >= first and not _box_meets_axes(normals, projections, probe, cy):
                        probe -= 1
                    if probe < first:
                        continue
                left = probe
            while left > first and _box_meets_axes(normals, projections, left - 1, cy):
                left -= 1
            right = max(min(int(np.ceil(x_high)) - 1, last), left)
            if _box_meets_axes(normals, projections, right, cy):
                while right < last and _box_meets_axes(normals, projections, right + 1, cy):
                    right += 1
            else:
                while not _box_meets_axes(normals, projections, right, cy):
                    right -= 1
            for cx in range(left, right + 1):
                touched[cy, cx] = True
    _grow_marks(touched, grid, grow)


@njit
def _slab_extent(x0, y0, x1, y1, x2, y2, bottom, top):
    """``(low, high)``: the extent along x of the triangle's part with ``bottom <= y <= top`` (the triangle's
    x extent if that part is empty)."""
    xs = (x0, x1, x2)
    ys = (y0, y1, y2)
    low, high = np.inf, -np.inf
    for e in range(3):
        ax, ay = xs[e], ys[e]
        bx, by = xs[(e + 1) % 3], ys[(e + 1) % 3]
        if bottom <= ay <= top:
            low, high = min(low, ax), max(high, ax)
        if ay != by:
            for level in (bottom, top):
                if min(ay, by) <= level <= max(ay, by):
                    x = ax + (level - ay) * (bx - ax) / (by - ay)
                    low, high = min(low, x), max(high, x)
    if low > high:
        return min(x0, x1, x2), max(x0, x1, x2)
    return low, high


@njit
def _edge_axes(x0, y0, x1, y1, x2, y2, normals, projections):
    """The triangle's edge normals (either side; zero for an edge of zero length) and its projection onto each,
    ``[min, max]``: the axes :func:`_box_meets_axes` separates on."""
    xs = (x0, x1, x2)
    ys = (y0, y1, y2)
    for e in range(3):
        ax, ay = xs[e], ys[e]
        bx, by = xs[(e + 1) % 3], ys[(e + 1) % 3]
        nx, ny = -(by - ay), bx - ax
        low = high = nx * xs[0] + ny * ys[0]
        for k in range(1, 3):
            value = nx * xs[k] + ny * ys[k]
            low = min(low, value)
            high = max(high, value)
        normals[e, 0], normals[e, 1] = nx, ny
        projections[e, 0], projections[e, 1] = low, high


@njit
def _box_meets_axes(normals, projections, bx, by):
    """Whether the triangle of :func:`_edge_axes` and the unit box ``[bx, bx+1] x [by, by+1]`` overlap in more
    than their boundaries (separating axes: the box's two axes, which the caller's bounding-box loop covers, and
    the triangle's edge normals; a degenerate triangle, a segment, meets the boxes its inside crosses).

    The box's projection onto a normal ``(nx, ny)`` is lowest at its corner ``(bx + [nx < 0], by + [ny < 0])``
    and highest at the opposite one: rounding is monotonic, so these two corners give the extremes of all four
    in floating point too.
    """
    for e in range(3):
        nx, ny = normals[e, 0], normals[e, 1]
        if nx == 0.0 and ny == 0.0:
            continue
        low = nx * (bx + (1 if nx < 0.0 else 0)) + ny * (by + (1 if ny < 0.0 else 0))
        high = nx * (bx + (1 if nx > 0.0 else 0)) + ny * (by + (1 if ny > 0.0 else 0))
        if high <= projections[e, 0] or low >= projections[e, 1]:
            return False
    return True


@njit
def _grow_marks(touched, grid, grow):
    """Mark in ``grid`` every pixel within ``grow`` pixels (along each axis) of a pixel marked in ``touched``:
    the square dilation, as a dilation along the rows and then one along the columns."""
    rows, cols = touched.shape
    across = np.zeros((rows, cols), dtype=np.bool_)
    for cy in range(rows):
        marked = -1  # the last column marked in this row
        for cx in range(cols):
            if touched[cy, cx]:
                for c in range(max(cx - grow, marked + 1), min(cx + grow, cols - 1) + 1):
                    across[cy, c] = True
                marked = min(cx + grow, cols - 1)
    marked = np.full(cols, -1, dtype=np.int64)  # the last row marked in each column
    for cy in range(rows):
        for cx in range(cols):
            if across[cy, cx]:
                for r in range(max(cy - grow, marked[cx] + 1), min(cy + grow, rows - 1) + 1):
                    grid[r, cx] = True
                marked[cx] = min(cy + grow, rows - 1)


@njit
def row_spans(grid):
    """Per row of a bitmap, its runs of marked pixels.

    Parameters
    ----------
    grid : (rows, cols) bool ndarray

    Returns
    -------
    (n, 3) int32 ndarray
        ``(row, start, end)`` per run, ``end`` exclusive, in row order and then left to right.
    """
    rows, cols = grid.shape
    count = 0
    for r in range(rows):
        for c in range(cols):
            if grid[r, c] and (c == 0 or not grid[r, c - 1]):
                count += 1
    spans = np.empty((count, 3), dtype=np.int32)
    n = 0
    for r in range(rows):
        c = 0
        while c < cols:
            if grid[r, c]:
                start = c
                while c < cols and grid[r, c]:
                    c += 1
                spans[n, 0], spans[n, 1], spans[n, 2] = r, start, c
                n += 1
            else:
                c += 1
    return spans
