"""Re-bake normal equations (Eq. 11) solved by a multifrontal Cholesky in nested-dissection order.

The normal matrix ``B^T B + ridge I`` of a re-bake couples two texels when some pixel reads both, i.e. when
they are corners of one texel cell: texel ``(x, y)`` is coupled to the 8 texels around it at most (a 9-point
stencil on the texel lattice). A band or envelope Cholesky (:mod:`.bake_lsq`) costs about ``T W^2`` for ``T``
texels in a footprint ``W`` texels wide, ``T^2`` for a square footprint. Nested dissection (George 1973)
costs about ``T^{3/2}`` instead: one row (or column) of texels separates the texels on its two sides, so the
footprint is cut at the median of its longer side into two halves and a separator, recursively, down to
leaves of a few dozen texels; the halves are eliminated before their separator. Each node of that tree is
factorized as a dense frontal matrix (multifrontal method, Duff & Reid 1983): its own texels (the pivots) and
the texels of the enclosing separators they couple to (the node's boundary); the Schur complement on the
boundary (the update matrix) is added into the parent's front. Nodes are processed in postorder, so the
update matrices of a node's children are the last two on a stack.

This is a Cholesky factorization of the same matrix in another order, so it needs no good conditioning (near
the identity a view has about one pixel per texel and the normal matrix is singular but for the ridge):
pivots are floored as in the band and envelope solvers (:func:`.bake_lsq._floored_pivot`), the texels agree
with theirs to rounding amplified by the condition number, like theirs with the exact solution, and the
re-baked render to about 1e-11 of the texture's range. It pays off for wide footprints only: for a narrow
band the fronts' bookkeeping costs more than the band's whole factorization (:data:`.loss_stack.DISSECTION_COST`
chooses). The dense work inside a front is blocked so that most of it is matrix products (BLAS).

References
----------
Sun et al. 2022, Eq. 11. A. George, Nested dissection of a regular finite element mesh, SIAM J. Numer. Anal.
10 (1973). I. S. Duff and J. K. Reid, The multifrontal solution of indefinite sparse symmetric linear
equations, ACM TOMS 9 (1983).
"""
import numpy as np

from ._jit import njit
from .bake_lsq import _floored_pivot

__all__ = []

# Column of ``acc`` holding the product of the weights of cell corners k1 and k2, at k1 * 4 + k2.
_PAIR_COLUMN = np.array([0, 4, 5, 6, 4, 1, 6, 8, 5, 6, 2, 9, 6, 8, 9, 3], np.int64)

# Pivot rows per block of a front's factorization: row operations inside a block, a matrix product (BLAS) for
# the block's update of the rows after it.
_BLOCK = 16

#: Largest node the dissection does not split further (texels eliminated in one dense front).
LEAF_TEXELS = 32


@njit
def _dissection_tree(tex_x, tex_y, leaf_texels):
    """Numba: nested-dissection tree of texels at integer lattice points ``(tex_x, tex_y)``.

    Returns ``(perm, node_lo, node_sep, node_hi, n_children, postorder)``: ``perm`` lists the texels in
    elimination order; node ``v`` owns positions ``node_lo[v]:node_hi[v]`` of ``perm`` (its subtree) and
    eliminates ``node_sep[v]:node_hi[v]`` itself (its separator, or all of a leaf), after its children, whose
    ranges tile ``node_lo[v]:node_sep[v]``; ``postorder`` lists the nodes children first.
    """
    n = tex_x.shape[0]
    perm = np.arange(n)
    buffer = np.empty(n, np.int64)
    capacity = 2 * n + 1
    node_lo = np.empty(capacity, np.int64)
    node_sep = np.empty(capacity, np.int64)
    node_hi = np.empty(capacity, np.int64)
    n_children = np.zeros(capacity, np.int64)
    node_lo[0] = 0
    node_hi[0] = n
    n_nodes = 1
    stack = np.empty(capacity, np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        v = stack[top]
        lo = node_lo[v]
        hi = node_hi[v]
        node_sep[v] = lo
        if hi - lo <= leaf_texels:
            continue
        x_lo = y_lo = np.iinfo(np.int64).max
        x_hi = y_hi = np.iinfo(np.int64).min
        for r in range(lo, hi):
            t = perm[r]
            x_lo = min(x_lo, tex_x[t])
            x_hi = max(x_hi, tex_x[t])
            y_lo = min(y_lo, tex_y[t])
            y_hi = max(y_hi, tex_y[t])
        # Cut across the longer side: the separator is a line of texels along the shorter one.
        coord = tex_x if x_hi - x_lo >= y_hi - y_lo else tex_y
        low = x_lo if x_hi - x_lo >= y_hi - y_lo else y_lo
        extent = max(x_hi - x_lo, y_hi - y_lo)
        histogram = np.zeros(extent + 1, np.int64)
        for r in range(lo, hi):
            histogram[coord[perm[r]] - low] += 1
        # The median line: about half of the texels on either side.
        cut = 0
        below = 0
        while below + histogram[cut] <= (hi - lo) // 2 and cut < extent:
            below += histogram[cut]
            cut += 1
        # Stable three-way partition: below the line, above it, on it.
        n_below = 0
        n_above = 0
        for r in range(lo, hi):
            if coord[perm[r]] - low < cut:
                n_below += 1
            elif coord[perm[r]] - low > cut:
                n_above += 1
        i_below = lo
        i_above = lo + n_below
        i_line = lo + n_below + n_above
        for r in range(lo, hi):
            t = perm[r]
            offset = coord[t] - low
            if offset < cut:
                buffer[i_below] = t
                i_below += 1
            elif offset > cut:
                buffer[i_above] = t
                i_above += 1
            else:
                buffer[i_line] = t
                i_line += 1
        perm[lo:hi] = buffer[lo:hi]
        node_sep[v] = lo + n_below + n_above
        for child_lo, child_hi in ((lo, lo + n_below), (lo + n_below, lo + n_below + n_above)):
            if child_hi > child_lo:
                node_lo[n_nodes] = child_lo
                node_hi[n_nodes] = child_hi
                n_children[v] += 1
                stack[top] = n_nodes
                top += 1
                n_nodes += 1
    # Postorder: ranges end in elimination order, and a descendant that ends with its ancestor is smaller.
    key = np.empty(n_nodes, np.int64)
    for v in range(n_nodes):
        key[v] = node_hi[v] * (n + 1) + (node_hi[v] - node_lo[v])
    postorder = np.argsort(key, kind="mergesort")
    return perm, node_lo[:n_nodes], node_sep[:n_nodes], node_hi[:n_nodes], n_children[:n_nodes], postorder


@njit(fastmath=True)
def _partial_cholesky(front, n_pivots, pivot_floor):
    """Numba: eliminate the first ``p = n_pivots`` unknowns of the dense symmetric ``front`` in place (upper
    triangle used).

    On return the first ``p`` rows hold ``[U11 U12]``, the rows of the Cholesky factor ``L = U^T`` (``U11^T
    U11`` the pivot block, ``U12 = U11^{-T} front[:p, p:]``), and ``front[p:, p:]`` the update matrix
    ``front[p:, p:] - U12^T U12`` (upper triangle). Blocked right-looking by rows: inside a block of
    :data:`_BLOCK` pivot rows every update is a contiguous axpy over a row (``fastmath`` lets them vectorize);
    the block's update of the later pivot rows, and the update matrix, are matrix products (BLAS).
    """
    m = front.shape[0]
    p = n_pivots
    for j0 in range(0, p, _BLOCK):
        j1 = min(j0 + _BLOCK, p)
        for j in range(j0, j1):
            d = np.sqrt(_floored_pivot(front[j, j], pivot_floor))
            front[j, j] = d
            inv = 1.0 / d
            for k in range(j + 1, m):
                front[j, k] *= inv
            for i in range(j + 1, j1):
                u = front[j, i]
                if u != 0.0:
                    for k in range(i, m):
                        front[i, k] -= u * front[j, k]
        if j1 < p:
            left = np.ascontiguousarray(front[j0:j1, j1:p])
            panel = np.ascontiguousarray(front[j0:j1, j1:])
            product = np.dot(left.T, panel)
            for i in range(p - j1):
                for k in range(i, m - j1):
                    front[j1 + i, j1 + k] -= product[i, k]
    nb = m - p
    if p > 0 and nb > 0:
        coupling = np.ascontiguousarray(front[:p, p:])
        product = np.dot(coupling.T, coupling)
        for a in range(nb):
            for b in range(a, nb):
                front[p + a, p + b] -= product[a, b]


@njit
def _multifrontal_solve(cell_tex, acc, cell_x, cell_y, n_tex, ridge, rhs, leaf_texels=LEAF_TEXELS):
    """Numba: solve the re-bake's normal equations assembled from texel cells; ``rhs`` (P, n_tex) is
    overwritten with the P solutions.

    ``cell_tex[c]`` are the texels at lattice points ``(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)`` with
    ``(x, y) = (cell_x[c], cell_y[c])``; ``acc[c, :10]`` the cell's sums of weight products in the order of
    :func:`.loss_stack._rebake_render_cells` (diagonals 0-3; pairs 01, 02, 03 == 12, 13, 23 at 4, 5, 6, 8, 9)
    and ``acc[c, 10 + 4 q + k]`` corner ``k``'s right-hand side of plane ``q``. The matrix is the sum over
    cells plus ``ridge I``; pivots are floored at ``ridge``.
    """
    n_cells = cell_tex.shape[0]
    n_planes = rhs.shape[0]
    tex_x = np.empty(n_tex, np.int64)
    tex_y = np.empty(n_tex, np.int64)
    for c in range(n_cells):
        for k in range(4):
            tex_x[cell_tex[c, k]] = cell_x[c] + (k & 1)
            tex_y[cell_tex[c, k]] = cell_y[c] + (k >> 1)
    perm, node_lo, node_sep, node_hi, n_children, postorder = _dissection_tree(tex_x, tex_y, leaf_texels)
    inverse = np.empty(n_tex, np.int64)
    for r in range(n_tex):
        inverse[perm[r]] = r
    # The matrix as a 9-point stencil in elimination numbering: slot (dy + 1) * 3 + dx + 1 of a texel holds
    # its entry with the texel at offset (dx, dy), ``neighbour`` that texel (-1 if none); slot 4 the diagonal.
    stencil = np.zeros((n_tex, 9))
    neighbour = np.full((n_tex, 9), -1, np.int64)
    # The right-hand sides (n_tex, P) in elimination numbering, the planes side by side (as the substitution
    # takes them).
    x = np.zeros((n_tex, n_planes))
    ids = np.empty(4, np.int64)
    for c in range(n_cells):
        for k in range(4):
            ids[k] = inverse[cell_tex[c, k]]
        for k1 in range(4):
            i = ids[k1]
            for q in range(n_planes):
                x[i, q] += acc[c, 10 + 4 * q + k1]
            for k2 in range(4):
                slot = ((k2 >> 1) - (k1 >> 1) + 1) * 3 + (k2 & 1) - (k1 & 1) + 1
                stencil[i, slot] += acc[c, _PAIR_COLUMN[k1 * 4 + k2]]
                neighbour[i, slot] = ids[k2]
    n_nodes = node_lo.shape[0]
    position = np.empty(n_tex, np.int64)
    mark = np.full(n_tex, -1, np.int64)
    gathered = np.empty(n_tex, np.int64)
    pivot_blocks = [np.empty((0, 0))] * n_nodes
    couplings = [np.empty((0, 0))] * n_nodes
    boundaries = [np.empty(0, np.int64)] * n_nodes
    # Update matrices waiting for their parent: the trailing block of each child's front, from row and column
    # ``offsets``, with the texels ``front_ids``.
    fronts = [np.empty((0, 0))]
    offsets = [0]
    front_ids = [np.empty(0, np.int64)]
    for v in postorder:
        s = node_sep[v]
        e = node_hi[v]
        n_pivots = e - s
        # Boundary: the later texels coupled to the pivots, and the children's boundaries past the pivots.
        nb = 0
        for i in range(s, e):
            for slot in range(9):
                j = neighbour[i, slot]
                if j >= e and mark[j] != v:
                    mark[j] = v
                    gathered[nb] = j
                    nb += 1
        for child in range(n_children[v]):
            for j in front_ids[len(front_ids) - 1 - child]:
                if j >= e and mark[j] != v:
                    mark[j] = v
                    gathered[nb] = j
                    nb += 1
        bound = np.sort(gathered[:nb])
        m = n_pivots + nb
        for i in range(s, e):
            position[i] = i - s
        for a in range(nb):
            position[bound[a]] = n_pivots + a
        front = np.empty((m, m))
        for r in range(m):
            front[r, r:] = 0.0
        for i in range(s, e):
            li = i - s
            front[li, li] += ridge
            for slot in range(9):
                j = neighbour[i, slot]
                if j >= i:
                    front[li, position[j]] += stencil[i, slot]
        # Extend-add the children's update matrices: positions increase with the texel number, so an upper
        # triangle lands in the front's upper triangle.
        for _ in range(n_children[v]):
            child_front = fronts.pop()
            o = offsets.pop()
            local = position[front_ids.pop()]
            for a in range(local.shape[0]):
                row = local[a]
                for c in range(a, local.shape[0]):
                    front[row, local[c]] += child_front[o + a, o + c]
        _partial_cholesky(front, n_pivots, ridge)
        fronts.append(front)
        offsets.append(n_pivots)
        front_ids.append(bound)
        pivot_blocks[v] = np.ascontiguousarray(front[:n_pivots, :n_pivots])
        couplings[v] = np.ascontiguousarray(front[:n_pivots, n_pivots:])
        boundaries[v] = bound
    # Every plane's right-hand side at once: a node's coupling to its boundary is one matrix product (BLAS).
    _substitute(pivot_blocks, couplings, boundaries, node_sep, node_hi, postorder, x)
    for t in range(n_tex):
        for q in range(n_planes):
            rhs[q, t] = x[inverse[t], q]


@njit(fastmath=True)
def _substitute(pivot_blocks, couplings, boundaries, node_sep, node_hi, postorder, x):
    """Numba: overwrite the right-hand sides ``x`` (n_tex, P) (rows in elimination numbering) with the solutions
    of ``U^T U x = x``, ``U`` the factor rows :func:`_multifrontal_solve` kept per node as ``U11`` (its pivot
    block, ``pivot_blocks``) and ``U12`` (its coupling to the boundary, ``couplings``): forward substitution with
    ``U^T`` children first, then back substitution with ``U`` parents first. The ``P`` columns share every
    pass; a node's boundary update is a matrix product."""
    n_planes = x.shape[1]
    for v in postorder:
        s = node_sep[v]
        n_pivots = node_hi[v] - s
        pivots = pivot_blocks[v]
        bound = boundaries[v]
        block = np.ascontiguousarray(x[s:s + n_pivots])
        for j in range(n_pivots):
            inv = 1.0 / pivots[j, j]
            for q in range(n_planes):
                block[j, q] *= inv
            for k in range(j + 1, n_pivots):
                u = pivots[j, k]
                if u != 0.0:
                    for q in range(n_planes):
                        block[k, q] -= u * block[j, q]
        x[s:s + n_pivots] = block
        if bound.shape[0] > 0 and n_pivots > 0:
            update = np.dot(couplings[v].T, block)
            for a in range(bound.shape[0]):
                for q in range(n_planes):
                    x[bound[a], q] -= update[a, q]
    for r in range(postorder.shape[0] - 1, -1, -1):
        v = postorder[r]
        s = node_sep[v]
        n_pivots = node_hi[v] - s
        pivots = pivot_blocks[v]
        bound = boundaries[v]
        block = np.ascontiguousarray(x[s:s + n_pivots])
        if bound.shape[0] > 0 and n_pivots > 0:
            outer = np.empty((bound.shape[0], n_planes))
            for a in range(bound.shape[0]):
                for q in range(n_planes):
                    outer[a, q] = x[bound[a], q]
            block -= np.dot(couplings[v], outer)
        for j in range(n_pivots - 1, -1, -1):
            for k in range(j + 1, n_pivots):
                u = pivots[j, k]
                if u != 0.0:
                    for q in range(n_planes):
                        block[j, q] -= u * block[k, q]
            inv = 1.0 / pivots[j, j]
            for q in range(n_planes):
                block[j, q] *= inv
        x[s:s + n_pivots] = block
