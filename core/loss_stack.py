"""Numba kernels of the loss over a stack of planes on one texel grid: one operator assembly, many planes.

Planes of the same shape see the same texel-space points under a triangle's view and the same deformation,
so the screen operator of Eq. 8-9, the re-bake's normal equations (Eq. 11) and their Cholesky factor are the
same for all of them; only the right-hand sides (each plane's reference render) differ. One evaluation of
``P`` such planes pools the pixels into texel cells once, orders and factorizes once, and substitutes,
renders and takes GMSD (Eq. 3, 5) per plane (:func:`_evaluate_planes_kernel`). :class:`.loss_planes.StackProblem`
groups its active planes by shape and calls this for every group of two or more.

References
----------
Sun et al. 2022, Eq. 3, 5, 8-11.
"""
import numpy as np

from ._jit import njit
from .bake_lsq import (_apply_renumber, _band_cholesky_solve, _envelope_cholesky_solve, _group_by_component,
                       _render_ids, _solve_normal_equations)
from .gmsd import _covered_gmsd_kernel
from .loss import _deformed_ids, _envelope_cost, _add_off_diagonal

__all__ = []


@njit(fastmath=True)
def _band_substitute(band, rhs):
    """Numba: overwrite ``rhs`` with the solution of ``L L^T x = rhs``, ``band`` the factor that
    :func:`.bake_lsq._band_cholesky_solve` left (the same two sweeps)."""
    count, width = band.shape
    b = width - 1
    for j in range(count):
        y = rhs[j] / band[j, 0]
        rhs[j] = y
        m = min(b, count - 1 - j)
        for k in range(1, m + 1):
            rhs[j + k] -= band[j, k] * y
    for j in range(count - 1, -1, -1):
        m = min(b, count - 1 - j)
        s = 0.0
        for k in range(1, m + 1):
            s += band[j, k] * rhs[j + k]
        rhs[j] = (rhs[j] - s) / band[j, 0]


@njit(fastmath=True)
def _envelope_substitute(env, offset, first, rhs):
    """Numba: overwrite ``rhs`` with the solution of ``L L^T x = rhs``, ``env`` the envelope factor that
    :func:`.bake_lsq._envelope_cholesky_solve` left (the same two sweeps)."""
    count = rhs.shape[0]
    for i in range(count):
        fi = first[i]
        bi = offset[i] - fi
        s = 0.0
        for k in range(fi, i):
            s += env[bi + k] * rhs[k]
        rhs[i] = (rhs[i] - s) / env[bi + i]
    for i in range(count - 1, -1, -1):
        fi = first[i]
        bi = offset[i] - fi
        xi = rhs[i] / env[bi + i]
        rhs[i] = xi
        for k in range(fi, i):
            rhs[k] -= env[bi + k] * xi


@njit
def _rebake_render_cells_planes(points, references, box, a00, a01, a10, a11, cx, cy, w, h, ridge, rendered):
    """Numba: :func:`.loss._rebake_render_cells` for ``P`` planes on one texel grid: one pooling pass, one
    ordering and one Cholesky factorization, ``P`` right-hand sides (``references`` (P, count)), ``P``
    renders into ``rendered`` (P, count). A copy of that kernel with the right-hand side widened: keep the two
    in step."""
    count = points.shape[0]
    n_planes = references.shape[0]
    # Conservative box of the deformed continuous coordinates from the corners of the input box.
    xlo = ylo = np.inf
    xhi = yhi = -np.inf
    for corner in range(4):
        dx = (box[1] if corner & 1 else box[0]) - cx
        dy = (box[3] if corner & 2 else box[2]) - cy
        x = a00 * dx + a01 * dy + cx - 0.5
        y = a10 * dx + a11 * dy + cy - 0.5
        xlo = min(xlo, x)
        xhi = max(xhi, x)
        ylo = min(ylo, y)
        yhi = max(yhi, y)
    if not (xhi - xlo < w - 4 and yhi - ylo < h - 4):
        return False
    ox = int(np.floor(xlo)) - 1  # one cell of slack for round-off
    oy = int(np.floor(ylo)) - 1
    width = int(np.floor(xhi)) - ox + 2
    height = int(np.floor(yhi)) - oy + 2
    if width + 1 > w or height + 1 > h:
        return False
    # Cells are found through a dense grid over the box, or through a hash table when the box is sparse (a
    # one-ring across UV seams spans distant islands; minified footprints spread out).
    dense = width * height <= 16 * count + 4096
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
        dx = points[p, 0] - cx
        dy = points[p, 1] - cy
        x = a00 * dx + a01 * dy + cx - 0.5
        y = a10 * dx + a11 * dy + cy - 0.5
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
    # Per-cell sums of the bilinear weight products; runs of pixels in one cell are summed in registers. The
    # weights are (1 - fx, fx) x (1 - fy, fy), so the 10 products are 9 distinct products of the 3 entries
    # of each factor's outer product (w0 w3 == w1 w2).
    c = pix_cell[0] if count else -1
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s8 = s9 = 0.0
    srhs = np.zeros(4 * n_planes)
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
            for q in range(4 * n_planes):
                acc[c, 10 + q] += srhs[q]
            if p == count:
                break
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s8 = s9 = 0.0
            srhs[:] = 0.0
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
        for q in range(n_planes):
            t = references[q, p]
            tx0 = t * gx0
            tx1 = t * fx
            srhs[4 * q] += tx0 * gy0
            srhs[4 * q + 1] += tx1 * gy0
            srhs[4 * q + 2] += tx0 * fy
            srhs[4 * q + 3] += tx1 * fy
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
    # Normal equations from the cells, then a Cholesky solve: in band storage when the envelope is nearly a
    # full band (compact footprints; the band kernel vectorizes better), else in envelope storage.
    bandwidth = 0
    for i in range(n_tex):
        bandwidth = max(bandwidth, i - first[i])
    rhs = np.zeros((n_planes, n_tex))
    if n_tex * bandwidth * bandwidth <= 1.5 * cost:
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
        _band_cholesky_solve(band, rhs[0], ridge)
        for q in range(1, n_planes):
            _band_substitute(band, rhs[q])
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
        _envelope_cholesky_solve(env, offset, first, rhs[0], ridge)
        for q in range(1, n_planes):
            _envelope_substitute(env, offset, first, rhs[q])
    cell_value = np.empty((n_cells, 4))
    for q in range(n_planes):
        for c in range(n_cells):
            for k in range(4):
                cell_value[c, k] = rhs[q, cell_tex[c, k]]
        for p in range(count):
            c = pix_cell[p]
            fx = frac[p, 0]
            fy = frac[p, 1]
            rendered[q, p] = ((1.0 - fx) * ((1.0 - fy) * cell_value[c, 0] + fy * cell_value[c, 2])
                              + fx * ((1.0 - fy) * cell_value[c, 1] + fy * cell_value[c, 3]))
    return True




@njit
def _evaluate_planes_kernel(params, points, pooled_index, box, references, reference_gradients, centre, w, h,
                            ridge, c_gmsd, use_cells):
    """Numba: E of ``P`` planes on one texel grid, (k, 4) params -> (k, P); :func:`.loss._evaluate_kernel` with
    the operator shared (``references`` (P, count), ``reference_gradients`` (P, m, m))."""
    k = params.shape[0]
    n_planes = references.shape[0]
    out = np.empty((k, n_planes))
    m = reference_gradients.shape[1]
    count = points.shape[0]
    rendered = np.empty((n_planes, count))
    size = (m + 2) * (m + 2)
    sums = np.empty(size)
    counts = np.zeros(size)
    for p in range(count):
        counts[pooled_index[p]] += 1.0
    flat_gradients = reference_gradients.copy().reshape(n_planes, m * m)
    value = np.empty(size)
    queue = np.empty(size, np.int64)
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
        done = count > 0 and use_cells and _rebake_render_cells_planes(
            points, references, box, a00, a01, a10, a11, centre[0], centre[1], w, h, ridge, rendered)
        if not done:
            ids, weights, texel = _deformed_ids(points, a00, a01, a10, a11, centre[0], centre[1], w, h)
            for q in range(n_planes):
                values = _solve_normal_equations(ids, weights, references[q], texel.shape[0], ridge)
                rendered[q, :] = _render_ids(ids, weights, values)
        for q in range(n_planes):
            sums[:] = 0.0
            for p in range(count):
                sums[pooled_index[p]] += rendered[q, p]
            out[s, q] = _covered_gmsd_kernel(sums, counts, m, flat_gradients[q], c_gmsd, value, queue)
    return out
