"""Pixels that the re-bake (Eq. 11) matches exactly, found without solving: rows with a texel of their own.

The re-bake minimizes ``||B x - target||^2`` over the texels ``x`` (the ridge of :mod:`.bake_lsq` only picks a
solution among the minimizers; the render ``B x``, the projection of the target on the range of ``B``, is what E
sees). When pixel ``p`` is the only pixel that reads texel ``j`` (``B[q, j] = 0`` for every other pixel ``q``) and
reads it with a weight ``w > 0``, then for any values of the other texels ``x_j = (target[p] - sum_{k != j}
B[p, k] x_k) / w`` zeroes ``p``'s residual and changes no other pixel's. So every minimizer renders ``p`` as
``target[p]``, and the rest of the problem is the same least squares without row ``p`` and column ``j``. Removing
``p`` may leave another pixel the only reader of one of its texels: peeling repeats until no remaining pixel has
a texel of its own. What is left (the core) is the same for every peeling order, since a row that has a texel
of its own keeps it when other rows go.

Where this matters: a view whose texels are finer than its pixels (a footprint wider than the largest view, or
a deformation that keeps most of a texel-matched view's texels) gives each pixel texels no other pixel reads.
There the whole problem peels away: E is exactly 0 without a factorization, which was the costliest one of the
view (a footprint's pixels 2-3 texels apart couple into one large system). Views whose pixels share texels
(every shrunk, magnified deformation) keep their core and are solved as before.

Only cells holding one pixel are peeled (pixels pooled in one texel cell read the same 4 texels, so none of
them has a texel of its own), and only through texels read with weight at least :data:`PEEL_MIN_WEIGHT`: the
ridge-regularized solve it replaces reaches the exact projection within ``ridge / w^2`` of a residual, which
for the default ridge ``1e-9`` and ``w >= 1e-2`` is below ``1e-5``.

References
----------
Sun et al. 2022, Eq. 11.
"""
import numpy as np

from ._jit import njit

__all__ = []

#: Smallest bilinear weight through which a texel of its own matches a pixel exactly (see the module notes).
PEEL_MIN_WEIGHT = 1e-2


@njit(inline="always")
def _peelable(c, cell_tex, weight, readers, min_weight):
    if weight[c, 0] < 0.0:  # a cell of several pixels
        return False
    for k in range(4):
        if readers[cell_tex[c, k]] == 1 and weight[c, k] >= min_weight:
            return True
    return False


@njit
def _peel_cells(cell_tex, weight, n_tex, min_weight=PEEL_MIN_WEIGHT):
    """Numba: the cells the re-bake does not match exactly (the core), after peeling every cell that reads a
    texel of its own.

    Parameters
    ----------
    cell_tex : (c, 4) int64 array
        The 4 distinct texels (``0..n_tex-1``) each cell reads.
    weight : (c, 4) float64 array
        Bilinear weights of those texels for cells holding one pixel; ``weight[c, 0] < 0`` marks a cell of
        several pixels (never peeled).
    n_tex : int
    min_weight : float, optional

    Returns
    -------
    keep : (c,) bool array
        True for the core's cells.
    kept : int
        Their number.
    """
    n_cells = cell_tex.shape[0]
    readers = np.zeros(n_tex, np.int64)
    for c in range(n_cells):
        for k in range(4):
            readers[cell_tex[c, k]] += 1
    # Texel -> cells that read it (CSR), to find the last reader of a texel when its other readers are gone.
    start = np.zeros(n_tex + 1, np.int64)
    for t in range(n_tex):
        start[t + 1] = start[t] + readers[t]
    fill = start[:-1].copy()
    reader_cells = np.empty(4 * n_cells, np.int64)
    for c in range(n_cells):
        for k in range(4):
            t = cell_tex[c, k]
            reader_cells[fill[t]] = c
            fill[t] += 1
    keep = np.ones(n_cells, np.bool_)
    queued = np.zeros(n_cells, np.bool_)
    stack = np.empty(n_cells, np.int64)
    top = 0
    for c in range(n_cells):
        if _peelable(c, cell_tex, weight, readers, min_weight):
            queued[c] = True
            stack[top] = c
            top += 1
    kept = n_cells
    while top > 0:
        top -= 1
        c = stack[top]
        keep[c] = False
        kept -= 1
        for k in range(4):
            t = cell_tex[c, k]
            readers[t] -= 1
            if readers[t] == 1:
                for r in range(start[t], start[t + 1]):
                    other = reader_cells[r]
                    if keep[other] and not queued[other] and _peelable(other, cell_tex, weight, readers,
                                                                       min_weight):
                        queued[other] = True
                        stack[top] = other
                        top += 1
    return keep, kept


@njit
def _single_pixel_weights(pix_cell, acc, n_cells):
    """Numba: the ``weight`` rows :func:`_peel_cells` takes, from the pooled sums of
    :func:`.loss_stack._rebake_render_cells` (``acc[c, k]`` the sum of corner ``k``'s squared weight over the
    cell's pixels, ``pix_cell[p]`` pixel ``p``'s cell): a cell of one pixel gets its 4 weights, a cell of several
    ``-1`` first. Returns ``(weight, number of cells of one pixel)``."""
    pixels = np.zeros(n_cells, np.int64)
    for p in range(pix_cell.shape[0]):
        pixels[pix_cell[p]] += 1
    weight = np.empty((n_cells, 4))
    n_single = 0
    for c in range(n_cells):
        if pixels[c] == 1:
            n_single += 1
            for k in range(4):
                weight[c, k] = np.sqrt(acc[c, k])
        else:
            weight[c, 0] = -1.0
    return weight, n_single


@njit
def _core_cells(keep, kept, cell_tex, acc, cell_pos, n_tex, pix_cell):
    """Numba: the ``kept`` cells marked in ``keep`` and the texels they read, in the same orders: returns
    ``(cell_tex, acc, cell_pos, n_tex)`` of the core; ``pix_cell`` is renumbered in place, -1 for a pixel of a
    peeled cell."""
    new_cell = np.full(keep.shape[0], -1, np.int64)
    new_tex = np.full(n_tex, -1, np.int64)
    core_tex = np.empty((kept, 4), np.int64)
    core_acc = np.empty((kept, acc.shape[1]))
    core_pos = np.empty(kept, np.int64)
    c_new = 0
    for c in range(keep.shape[0]):
        if keep[c]:
            new_cell[c] = c_new
            core_acc[c_new, :] = acc[c, :]
            core_pos[c_new] = cell_pos[c]
            for k in range(4):
                new_tex[cell_tex[c, k]] = 0
            c_new += 1
    n_core = 0
    for t in range(n_tex):
        if new_tex[t] == 0:
            new_tex[t] = n_core
            n_core += 1
    c_new = 0
    for c in range(keep.shape[0]):
        if keep[c]:
            for k in range(4):
                core_tex[c_new, k] = new_tex[cell_tex[c, k]]
            c_new += 1
    for p in range(pix_cell.shape[0]):
        pix_cell[p] = new_cell[pix_cell[p]]
    return core_tex, core_acc, core_pos, n_core
