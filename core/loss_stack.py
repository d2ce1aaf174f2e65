"""Numba kernels of the loss E over a stack of planes on one texel grid: one operator assembly, many planes.

Planes of the same shape see the same texel-space points under a triangle's view and the same deformation,
so the screen operator of Eq. 8-9, the re-bake's normal equations (Eq. 11) and their Cholesky factor are the
same for all of them; only the right-hand sides (each plane's reference render) differ. One evaluation of
``P`` such planes pools the pixels into texel cells once, orders and factorizes once, and per plane only
substitutes, renders and takes GMSD (Eq. 3, 5) (:func:`_evaluate_planes_kernel`). The per-plane work is done
for all planes in one pass wherever a pass reads shared data: the right-hand sides of planes after the first in
one sweep over the pixels, the substitutions in one pass over the factor (planes side by side), the renders
and the screens' pooled sums in one pass over the pixels, and the GMSD's fill of uncovered cells, which
depends on the covered pixels only, planned once per call of two screens or more
(:func:`.gmsd._extension_plan`). The single-map loss
(:func:`.loss._evaluate_kernel`) is the case P = 1; :class:`.loss_planes.StackProblem` groups its active
planes by shape and calls this for every group of two or more.

The re-bake's solve dominates an evaluation whose view reads many texels: a band or envelope Cholesky
(:mod:`.bake_lsq`) costs about ``T W^2`` for ``T`` texels in a footprint ``W`` texels wide, which near the
identity of a triangle whose view has about one pixel per texel (``T`` up to tens of thousands, ``W`` in
the hundreds) is hundreds of milliseconds. When that work estimate exceeds :data:`DISSECTION_COST`, the same
normal equations are factorized in nested-dissection order by a multifrontal Cholesky instead
(:mod:`.multifrontal`, about ``T^{3/2}``): about as fast at the threshold, 2-3x faster at 10x-100x its
work and 10x beyond, the renders equal to about 1e-11. Both are direct solves, so the ill-conditioned
systems near the identity (about one pixel per texel, held only by the ridge) are solved as exactly as the
well-conditioned ones of shrunk triangles.

Before either, the pixels that the re-bake matches exactly are taken out (:mod:`.rebake_peel`): a pixel alone in
its cell that reads a texel no other pixel reads renders its reference whatever the other texels are, and
removing it can leave the next pixel the only reader of a texel. A view whose texels are finer than its pixels
(a footprint wider than the largest view, under a mild shrink) peels away entirely, E = 0 without a
factorization, where the solve would couple the footprint's pixels, a few texels apart, into one large system.

References
----------
Sun et al. 2022, Eq. 3, 5, 8-11.
"""
import numpy as np

from ._jit import njit
from .bake_lsq import (_apply_renumber, _band_cholesky_solve, _band_factorize, _band_substitute_planes,
                       _envelope_cholesky_solve, _envelope_factorize, _envelope_first,
                       _envelope_substitute_planes, _first_occurrence_ids, _group_by_component, _render_ids,
                       _solve_normal_equations)
from .gmsd import _covered_gmsd_kernel, _covered_gmsd_planned, _extension_plan
from .multifrontal import _multifrontal_solve
from .rebake_peel import _core_cells, _peel_cells, _single_pixel_weights

__all__ = []

#: Envelope work estimate (:func:`_envelope_cost`) above which the re-bake is solved in nested-dissection order
#: (:func:`.multifrontal._multifrontal_solve`) instead of by the band or envelope Cholesky: about where the two
#: take the same time (a few thousand texels in a footprint 30-40 texels wide).
DISSECTION_COST = 1_000_000

#: Cells of one pixel in a view from which on the re-bake first peels the pixels it matches exactly
#: (:mod:`.rebake_peel`); below it the peeling pass costs about what it saves.
PEEL_MIN_CELLS = 1024


@njit(inline="always")
def _deform(px, py, a00, a01, a10, a11, cx, cy):
    """Numba: ``A (p - c) + c`` for a texel-space point ``p``, as a continuous texel coordinate (texel ``t``
    centred at ``t``, so bilinear lookups read ``floor`` and ``floor + 1``)."""
    dx = px - cx
    dy = py - cy
    return a00 * dx + a01 * dy + cx - 0.5, a10 * dx + a11 * dy + cy - 0.5


@njit(inline="always")
def _dense_grid_fits(width, height, count):
    """Numba: whether a dense grid over a ``width`` x ``height`` box of texel cells is small enough next to the
    ``count`` points that fill it (otherwise the cells go through a hash table)."""
    return width * height <= 16 * count + 4096


@njit
def _deformed_ids(points, a00, a01, a10, a11, cx, cy):
    """Numba: texel ids (first occurrence, local) and bilinear weights of the deformed points.

    A texel is its integer position in the plane of the deformed points, without REPEAT wrapping: the re-baked
    neighbourhood gets texels of its own wherever it reaches (see :func:`_rebake_render_cells`)."""
    count = points.shape[0]
    base_x = np.empty(count, np.int64)
    base_y = np.empty(count, np.int64)
    weights = np.empty((count, 4))
    min_x = min_y = np.iinfo(np.int64).max
    max_x = max_y = np.iinfo(np.int64).min
    for p in range(count):
        x, y = _deform(points[p, 0], points[p, 1], a00, a01, a10, a11, cx, cy)
        fx0 = np.floor(x)
        fy0 = np.floor(y)
        fx = x - fx0
        fy = y - fy0
        ix = int(fx0)
        iy = int(fy0)
        base_x[p] = ix
        base_y[p] = iy
        weights[p, 0] = (1.0 - fx) * (1.0 - fy)
        weights[p, 1] = fx * (1.0 - fy)
        weights[p, 2] = (1.0 - fx) * fy
        weights[p, 3] = fx * fy
        min_x = min(min_x, ix)
        max_x = max(max_x, ix)
        min_y = min(min_y, iy)
        max_y = max(max_y, iy)
    ids = np.empty((count, 4), np.int64)
    if count == 0:
        return ids, weights, np.zeros(0, np.int64)
    width = max_x - min_x + 2
    height = max_y - min_y + 2
    if _dense_grid_fits(width, height, count):
        grid = np.full(width * height, -1, np.int64)
        texel = np.empty(4 * count, np.int64)
        n_texels = 0
        for p in range(count):
            for k in range(4):
                cell = (base_y[p] - min_y + (k >> 1)) * width + base_x[p] - min_x + (k & 1)
                t = grid[cell]
                if t < 0:
                    t = n_texels
                    grid[cell] = t
                    texel[t] = cell
                    n_texels += 1
                ids[p, k] = t
        return ids, weights, texel[:n_texels]
    keys = np.empty((count, 4), np.int64)
    for p in range(count):
        for k in range(4):
            keys[p, k] = (base_y[p] - min_y + (k >> 1)) * width + base_x[p] - min_x + (k & 1)
    ids, texel = _first_occurrence_ids(keys)
    return ids, weights, texel


@njit
def _envelope_cost(cell_tex, count):
    """Envelope first columns of an ordering and the Cholesky work estimate ``sum (i - first[i])^2``."""
    first = _envelope_first(cell_tex, count)
    cost = 0
    for i in range(count):
        cost += (i - first[i]) * (i - first[i])
    return first, cost


@njit(inline="always")
def _add_off_diagonal(env, offset, first, i, j, value):
    if j > i:
        i, j = j, i
    env[offset[i] - first[i] + j] += value


@njit(inline="always")
def _cell_grid(points, a00, a01, a10, a11, cx, cy):
    """Numba: origin ``(ox, oy)`` and size ``(width, height)`` of a grid of texel cells that holds the deformed
    points, with one cell of slack for round-off."""
    xlo = ylo = np.inf
    xhi = yhi = -np.inf
    for p in range(points.shape[0]):
        x, y = _deform(points[p, 0], points[p, 1], a00, a01, a10, a11, cx, cy)
        xlo = min(xlo, x)
        xhi = max(xhi, x)
        ylo = min(ylo, y)
        yhi = max(yhi, y)
    ox = int(np.floor(xlo)) - 1
    oy = int(np.floor(ylo)) - 1
    return ox, oy, int(np.floor(xhi)) - ox + 2, int(np.floor(yhi)) - oy + 2


@njit
def _rebake_render_cells(points, references, box, a00, a01, a10, a11, cx, cy, ridge, rendered,
                         dissection_cost=DISSECTION_COST, peel_min_cells=PEEL_MIN_CELLS):
    """Numba: deform, re-bake (Eq. 11) and re-render ``P`` planes in one sweep; False if the caller must fall
    back.

    ``references`` (P, count) holds each plane's reference render at the points, ``rendered`` (P, count)
    receives the re-baked renders: the planes share the pooling, the ordering and the Cholesky factor, one
    right-hand side each, substituted for all planes in one pass over the factor
    (:func:`.bake_lsq._band_substitute_planes`, :func:`.bake_lsq._envelope_substitute_planes`,
    :func:`.multifrontal._substitute`). One plane (P = 1) is the single-map loss.

    A texel is its integer position in the plane of the deformed points, without REPEAT wrapping: the re-baked
    neighbourhood gets texels of its own wherever it reaches, as the packed atlas gives every chart texels of
    its own. Two points share a texel only where the deformed UVs overlap, never because a footprint wider
    than the texture wraps around it (a view drawing faces from across the atlas, turned).

    Pixels whose deformed points fall in the same texel cell (same 4 texels) are pooled first: each cell
    keeps the sums of its 10 weight products and of 4 weighted targets per plane, so the normal equations
    are assembled from cells instead of pixels (magnified footprints have ~10-20 pixels per cell). Texels are
    numbered row by row along the shorter side of their bounding box, or in the order the pixels first read
    them, whichever gives the smaller envelope (the first suits compact footprints, the second minified ones
    where pixels read disjoint texel groups). Falls back only when round-off puts a point outside the box.

    Pixels alone in their cell that the re-bake matches exactly (:mod:`.rebake_peel`) render their reference and
    leave the system first, when the view has at least ``peel_min_cells`` (default :data:`PEEL_MIN_CELLS`) cells
    of one pixel; ``2**62`` turns it off. The solve is a band or envelope Cholesky in that numbering, or, when
    its work estimate exceeds ``dissection_cost`` (default :data:`DISSECTION_COST`), a multifrontal Cholesky in
    nested-dissection order over the texels' positions in the box (:func:`.multifrontal._multifrontal_solve`).
    Tests force either with ``0`` or ``inf``.
    """
    count = points.shape[0]
    n_planes = references.shape[0]
    # The deformed corners of the input box bound the deformed points without a pass over them. Under a turn or a
    # shear those corners reach up to sqrt(2) times further than any point: when their box is too sparse for a
    # dense grid, the exact box from the points decides.
    corners = np.empty((4, 2))
    for corner in range(4):
        corners[corner, 0] = box[corner & 1]
        corners[corner, 1] = box[2 + (corner >> 1)]
    ox, oy, width, height = _cell_grid(corners, a00, a01, a10, a11, cx, cy)
    if not _dense_grid_fits(width, height, count):
        ox, oy, width, height = _cell_grid(points, a00, a01, a10, a11, cx, cy)
    # Cells are found through a dense grid over the box, or through a hash table when the box is sparse (a
    # one-ring across UV seams spans distant islands; minified footprints spread out).
    dense = _dense_grid_fits(width, height, count)
    grid = np.full(width * height if dense else 0, -1, np.int64)
    table_bits = 4
    while (1 << table_bits) < 4 * count:
        table_bits += 1
    mask = (1 << table_bits) - 1
    table_key = np.full(0 if dense else mask + 1, -1, np.int64)
    table_value = np.empty(0 if dense else mask + 1, np.int64)
    cell_pos = np.empty(count, np.int64)
    acc = np.empty((count, 10 + 4 * n_planes))
    pix_cell = np.empty(count, np.int64)
    frac = np.empty((count, 2))
    n_cells = 0
    last_cell = -1
    c = -1
    for p in range(count):
        x, y = _deform(points[p, 0], points[p, 1], a00, a01, a10, a11, cx, cy)
        x0 = np.floor(x)
        y0 = np.floor(y)
        frac[p, 0] = x - x0
        frac[p, 1] = y - y0
        gx = int(x0) - ox
        gy = int(y0) - oy
        if gx < 0 or gy < 0 or gx >= width or gy >= height:
            return False
        cell = gy * width + gx
        if cell != last_cell:
            if dense:
                c = grid[cell]
                if c < 0:
                    c = n_cells
                    grid[cell] = c
            else:
                slot = ((cell * 0x2545F491) ^ (cell >> 13)) & mask
                while table_key[slot] >= 0 and table_key[slot] != cell:
                    slot = (slot + 1) & mask
                if table_key[slot] < 0:
                    table_key[slot] = cell
                    table_value[slot] = n_cells
                    c = -1
                else:
                    c = table_value[slot]
            if c < 0 or c == n_cells:
                c = n_cells
                cell_pos[c] = cell
                acc[c, :] = 0.0
                n_cells += 1
            last_cell = cell
        pix_cell[p] = c
    # Per-cell sums of the bilinear weight products and, per plane, of the 4 weighted targets (the right-hand
    # sides); runs of pixels in one cell are summed in registers. The first sweep takes the weight products and
    # the first plane, a second one every further plane. The weights are (1 - fx, fx) x (1 - fy, fy), so the 10
    # products are 9 distinct products of the 3 entries of each factor's outer product (w0 w3 == w1 w2).
    c = pix_cell[0]
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s8 = s9 = s10 = s11 = s12 = s13 = 0.0
    for p in range(count + 1):
        if p == count or pix_cell[p] != c:
            acc[c, 0] += s0
            acc[c, 1] += s1
            acc[c, 2] += s2
            acc[c, 3] += s3
            acc[c, 4] += s4
            acc[c, 5] += s5
            acc[c, 6] += s6
            acc[c, 8] += s8
            acc[c, 9] += s9
            acc[c, 10] += s10
            acc[c, 11] += s11
            acc[c, 12] += s12
            acc[c, 13] += s13
            if p == count:
                break
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s8 = s9 = s10 = s11 = s12 = s13 = 0.0
            c = pix_cell[p]
        fx = frac[p, 0]
        fy = frac[p, 1]
        gx0 = 1.0 - fx
        gy0 = 1.0 - fy
        xa = gx0 * gx0
        xb = gx0 * fx
        xc = fx * fx
        ya = gy0 * gy0
        yb = gy0 * fy
        yc = fy * fy
        s0 += xa * ya
        s1 += xc * ya
        s2 += xa * yc
        s3 += xc * yc
        s4 += xb * ya
        s5 += xa * yb
        s6 += xb * yb
        s8 += xc * yb
        s9 += xb * yc
        t = references[0, p]
        tx0 = t * gx0
        tx1 = t * fx
        s10 += tx0 * gy0
        s11 += tx1 * gy0
        s12 += tx0 * fy
        s13 += tx1 * fy
    if n_planes > 1:
        run = np.zeros(4 * (n_planes - 1))
        c = pix_cell[0]
        for p in range(count + 1):
            if p == count or pix_cell[p] != c:
                for r in range(run.shape[0]):
                    acc[c, 14 + r] += run[r]
                    run[r] = 0.0
                if p == count:
                    break
                c = pix_cell[p]
            fx = frac[p, 0]
            fy = frac[p, 1]
            gx0 = 1.0 - fx
            gy0 = 1.0 - fy
            for q in range(1, n_planes):
                t = references[q, p]
                tx0 = t * gx0
                tx1 = t * fx
                r = 4 * (q - 1)
                run[r] += tx0 * gy0
                run[r + 1] += tx1 * gy0
                run[r + 2] += tx0 * fy
                run[r + 3] += tx1 * fy
    # Texels touched, numbered along the shorter side of the texel box (ordering A); in sparse boxes, row by
    # row (sorted keys), then grouped by connected component below.
    tw = width + 1
    th = height + 1
    cell_tex = np.empty((n_cells, 4), np.int64)
    if dense:
        tgrid = np.full(tw * th, -1, np.int64)
        for c in range(n_cells):
            cell = cell_pos[c]
            t0 = (cell // width) * tw + cell % width
            tgrid[t0] = -2
            tgrid[t0 + 1] = -2
            tgrid[t0 + tw] = -2
            tgrid[t0 + tw + 1] = -2
        n_tex = 0
        if tw <= th:
            for t in range(tw * th):
                if tgrid[t] == -2:
                    tgrid[t] = n_tex
                    n_tex += 1
        else:
            for tx in range(tw):
                for ty in range(th):
                    t = ty * tw + tx
                    if tgrid[t] == -2:
                        tgrid[t] = n_tex
                        n_tex += 1
        for c in range(n_cells):
            cell = cell_pos[c]
            t0 = (cell // width) * tw + cell % width
            cell_tex[c, 0] = tgrid[t0]
            cell_tex[c, 1] = tgrid[t0 + 1]
            cell_tex[c, 2] = tgrid[t0 + tw]
            cell_tex[c, 3] = tgrid[t0 + tw + 1]
    else:
        keys = np.empty(4 * n_cells, np.int64)
        for c in range(n_cells):
            cell = cell_pos[c]
            t0 = (cell // width) * tw + cell % width
            keys[4 * c] = t0
            keys[4 * c + 1] = t0 + 1
            keys[4 * c + 2] = t0 + tw
            keys[4 * c + 3] = t0 + tw + 1
        order = np.argsort(keys)
        n_tex = 0
        flat_tex = cell_tex.reshape(-1)
        for r in range(order.shape[0]):
            if r > 0 and keys[order[r]] != keys[order[r - 1]]:
                n_tex += 1
            flat_tex[order[r]] = n_tex
        n_tex += 1
    # Cells of one pixel that read a texel of their own render their targets exactly (:mod:`.rebake_peel`):
    # they leave the system, which keeps only the core's cells and texels (in the same texel order).
    if n_cells >= peel_min_cells:
        weight, n_single = _single_pixel_weights(pix_cell, acc, n_cells)
        if n_single >= peel_min_cells:
            keep, kept = _peel_cells(cell_tex, weight, n_tex)
            if kept == 0:
                rendered[:, :] = references
                return True
            if kept < n_cells:
                cell_tex, acc, cell_pos, n_tex = _core_cells(keep, kept, cell_tex, acc, cell_pos, n_tex, pix_cell)
                n_cells = kept
    renumber, n_components = _group_by_component(cell_tex, n_tex)
    if n_components > 1:
        cell_tex = _apply_renumber(cell_tex, renumber)
    first, cost = _envelope_cost(cell_tex, n_tex)
    # Ordering B: first read.
    renumber = np.full(n_tex, -1, np.int64)
    n_b = 0
    for c in range(n_cells):
        for k in range(4):
            a = cell_tex[c, k]
            if renumber[a] < 0:
                renumber[a] = n_b
                n_b += 1
    cell_tex_b = np.empty((n_cells, 4), np.int64)
    for c in range(n_cells):
        for k in range(4):
            cell_tex_b[c, k] = renumber[cell_tex[c, k]]
    if n_components > 1:
        renumber, n_components = _group_by_component(cell_tex_b, n_tex)
        cell_tex_b = _apply_renumber(cell_tex_b, renumber)
    first_b, cost_b = _envelope_cost(cell_tex_b, n_tex)
    if cost_b < cost:
        cell_tex = cell_tex_b
        first = first_b
        cost = cost_b
    # Normal equations from the cells, then a Cholesky solve: in nested-dissection order when the envelope
    # work is large (wide footprints), else in band storage when the envelope is nearly a full band (compact
    # footprints; the band kernel vectorizes better), else in envelope storage.
    bandwidth = 0
    for i in range(n_tex):
        bandwidth = max(bandwidth, i - first[i])
    rhs = np.zeros((n_planes, n_tex))
    if cost > dissection_cost:
        cell_x = np.empty(n_cells, np.int64)
        cell_y = np.empty(n_cells, np.int64)
        for c in range(n_cells):
            cell_x[c] = cell_pos[c] % width
            cell_y[c] = cell_pos[c] // width
        _multifrontal_solve(cell_tex, acc, cell_x, cell_y, n_tex, ridge, rhs)
    elif n_tex * bandwidth * bandwidth <= 1.5 * cost:
        band = np.zeros((n_tex, bandwidth + 1))
        for c in range(n_cells):
            t0, t1, t2, t3 = cell_tex[c, 0], cell_tex[c, 1], cell_tex[c, 2], cell_tex[c, 3]
            for k in range(4):
                i = cell_tex[c, k]
                band[i, 0] += acc[c, k]
                for q in range(n_planes):
                    rhs[q, i] += acc[c, 10 + 4 * q + k]
            band[min(t0, t1), abs(t0 - t1)] += acc[c, 4]
            band[min(t0, t2), abs(t0 - t2)] += acc[c, 5]
            band[min(t0, t3), abs(t0 - t3)] += acc[c, 6]
            band[min(t1, t2), abs(t1 - t2)] += acc[c, 6]  # w1 w2 == w0 w3
            band[min(t1, t3), abs(t1 - t3)] += acc[c, 8]
            band[min(t2, t3), abs(t2 - t3)] += acc[c, 9]
        for i in range(n_tex):
            band[i, 0] += ridge
        if n_planes == 1:
            _band_cholesky_solve(band, rhs[0], ridge)
        else:
            # Every plane's right-hand side in one pass over the factor, the planes side by side.
            _band_factorize(band, ridge)
            x = np.ascontiguousarray(rhs.T)
            _band_substitute_planes(band, x)
            rhs[:, :] = x.T
    else:
        offset = np.empty(n_tex + 1, np.int64)
        offset[0] = 0
        for i in range(n_tex):
            offset[i + 1] = offset[i] + (i - first[i] + 1)
        env = np.zeros(offset[n_tex])
        for c in range(n_cells):
            for k in range(4):
                i = cell_tex[c, k]
                env[offset[i + 1] - 1] += acc[c, k]
                for q in range(n_planes):
                    rhs[q, i] += acc[c, 10 + 4 * q + k]
            t0, t1, t2, t3 = cell_tex[c, 0], cell_tex[c, 1], cell_tex[c, 2], cell_tex[c, 3]
            _add_off_diagonal(env, offset, first, t0, t1, acc[c, 4])
            _add_off_diagonal(env, offset, first, t0, t2, acc[c, 5])
            _add_off_diagonal(env, offset, first, t0, t3, acc[c, 6])
            _add_off_diagonal(env, offset, first, t1, t2, acc[c, 6])  # w1 w2 == w0 w3
            _add_off_diagonal(env, offset, first, t1, t3, acc[c, 8])
            _add_off_diagonal(env, offset, first, t2, t3, acc[c, 9])
        for i in range(n_tex):
            env[offset[i + 1] - 1] += ridge
        if n_planes == 1:
            _envelope_cholesky_solve(env, offset, first, rhs[0], ridge)
        else:
            _envelope_factorize(env, offset, first, ridge)
            x = np.ascontiguousarray(rhs.T)
            _envelope_substitute_planes(env, offset, first, x)
            rhs[:, :] = x.T
    # Render every plane in one pass over the pixels: the cells' 4 texel values of all planes side by side.
    cell_value = np.empty((n_cells, 4 * n_planes))
    for c in range(n_cells):
        for q in range(n_planes):
            for k in range(4):
                cell_value[c, 4 * q + k] = rhs[q, cell_tex[c, k]]
    if n_planes == 1:
        for p in range(count):
            c = pix_cell[p]
            if c < 0:
                rendered[0, p] = references[0, p]
                continue
            fx = frac[p, 0]
            fy = frac[p, 1]
            rendered[0, p] = ((1.0 - fx) * ((1.0 - fy) * cell_value[c, 0] + fy * cell_value[c, 2])
                              + fx * ((1.0 - fy) * cell_value[c, 1] + fy * cell_value[c, 3]))
        return True
    for p in range(count):
        c = pix_cell[p]
        if c < 0:
            for q in range(n_planes):
                rendered[q, p] = references[q, p]
            continue
        fx = frac[p, 0]
        fy = frac[p, 1]
        for q in range(n_planes):
            r = 4 * q
            rendered[q, p] = ((1.0 - fx) * ((1.0 - fy) * cell_value[c, r] + fy * cell_value[c, r + 2])
                              + fx * ((1.0 - fy) * cell_value[c, r + 1] + fy * cell_value[c, r + 3]))
    return True


@njit
def _evaluate_planes_kernel(params, points, pooled_index, box, references, reference_gradients, centre, ridge,
                            c_gmsd, use_cells, dissection_cost, peel_min_cells):
    """Numba: E of ``P`` planes on one texel grid, (k, 4) params -> (k, P) (``references`` (P, count),
    ``reference_gradients`` (P, m, m)); :func:`.loss._evaluate_kernel` is the case P = 1.
    ``dissection_cost`` chooses the re-bake's solver and ``peel_min_cells`` when it peels first
    (:func:`_rebake_render_cells`; callers pass :data:`DISSECTION_COST` and :data:`PEEL_MIN_CELLS`).

    Every argument is required: numba's dispatcher matches a call that leaves out an argument with a default
    in Python, not in its compiled fast path, which cost about 0.1 ms per call (a third of an evaluation of a
    64 px view)."""
    k = params.shape[0]
    n_planes = references.shape[0]
    out = np.empty((k, n_planes))
    m = reference_gradients.shape[1]
    count = points.shape[0]
    rendered = np.empty((n_planes, count))
    size = (m + 2) * (m + 2)
    counts = np.zeros(size)
    for p in range(count):
        counts[pooled_index[p]] += 1.0
    flat_gradients = reference_gradients.copy().reshape(n_planes, m * m)
    value = np.empty(size)
    queue = np.empty(size, np.int64)
    # Every screen of this call has the same covered pixels: the empty cells' fill is planned once when there
    # are two screens or more (planning costs about one search, replaying a fraction of one).
    planned = k * n_planes > 1
    covered, inner, fill = _extension_plan(counts, m) if planned else (queue[:0], queue[:0],
                                                                         np.empty((0, 2), np.int64))
    gms = np.empty(inner.shape[0])
    plane_sums = np.empty((n_planes, size))
    for s in range(k):
        alpha, l1, l2, beta = params[s, 0], params[s, 1], params[s, 2], params[s, 3]
        ca, sa = np.cos(alpha), np.sin(alpha)
        cb, sb = np.cos(beta), np.sin(beta)
        s00 = l1 * cb * cb + l2 * sb * sb
        s11 = l1 * sb * sb + l2 * cb * cb
        s01 = (l1 - l2) * cb * sb
        a00 = ca * s00 - sa * s01
        a01 = ca * s01 - sa * s11
        a10 = sa * s00 + ca * s01
        a11 = sa * s01 + ca * s11
        done = count > 0 and use_cells and _rebake_render_cells(
            points, references, box, a00, a01, a10, a11, centre[0], centre[1], ridge, rendered, dissection_cost,
            peel_min_cells)
        if not done:
            ids, weights, texel = _deformed_ids(points, a00, a01, a10, a11, centre[0], centre[1])
            for q in range(n_planes):
                values = _solve_normal_equations(ids, weights, references[q], texel.shape[0], ridge)
                rendered[q, :] = _render_ids(ids, weights, values)
        plane_sums[:] = 0.0
        if n_planes == 1:
            for p in range(count):
                plane_sums[0, pooled_index[p]] += rendered[0, p]
        else:
            for p in range(count):
                cell = pooled_index[p]
                for q in range(n_planes):
                    plane_sums[q, cell] += rendered[q, p]
        for q in range(n_planes):
            if planned:
                out[s, q] = _covered_gmsd_planned(plane_sums[q], counts, m, flat_gradients[q], c_gmsd, value,
                                                  covered, inner, fill, gms)
            else:
                out[s, q] = _covered_gmsd_kernel(plane_sums[q], counts, m, flat_gradients[q], c_gmsd, value,
                                                 queue)
    return out
