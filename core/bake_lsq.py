"""Re-bake of Eq. 11: the texel values whose render best matches a target screen in least squares.

Given, for every covered pixel ``p``, the 4 texels ``texels[p]`` and bilinear weights ``weights[p]`` that the
render reads (:func:`.raster.bilinear_weights`), and the target value ``target[p]`` (the reference render),
the re-baked texels minimize ``||B x - target||^2 + ridge ||x||^2`` over the texels that some pixel reads.

Why a ridge: texels can be under-determined (a texel read with weight 0, or two texels that every pixel
reads with the same weights, i.e. only their weighted sum is seen; this happens whenever the deformed
triangle is minified on screen). Every least-squares solution renders the same screen (``B x`` is the
projection of the target on the range of ``B``), so E does not depend on the choice; the tiny ridge picks
the minimum-norm solution in the limit ``ridge -> 0`` and makes the normal matrix positive definite so a
Cholesky factorization without pivoting works. With ``ridge = 1e-9`` and normal-matrix diagonals that are
sums of squared bilinear weights (order 1e-3 to 10 on screens of 64 px), the render moves by less than
1e-6 of a pixel value relative to the exact projection.

Solver: normal equations ``(B^T B + ridge I) x = B^T target`` in envelope (profile) storage, factorized by
a row-oriented Cholesky. Unknowns are numbered in the order in which the pixels first read them; row
``i`` of the envelope spans from the first unknown coupled to ``i`` (read by a common pixel) to ``i``.
Screen pixels are scanned row by row, so couplings reach back about one screen row of newly read texels,
and texels read by disjoint pixel groups (minified footprints) stay uncoupled: the envelope stays narrow.

References
----------
Sun et al. 2022, Eq. 10-11.
"""
import numpy as np

from ._jit import njit

__all__ = ["DEFAULT_RIDGE", "rebake", "render_texels"]

DEFAULT_RIDGE = 1e-9


@njit
def _first_occurrence_ids(keys):
    """Numba: number the distinct values of ``keys`` (p, 4) in order of first appearance (row-major).

    Returns ``ids`` (p, 4) and ``unique`` (t,) with ``unique[ids] == keys``.
    """
    flat = keys.reshape(-1)
    order = np.argsort(flat, kind="mergesort")  # stable: equal keys keep their first position first
    sorted_id = np.empty(flat.size, np.int64)
    first_pos = np.empty(flat.size, np.int64)
    groups = 0
    for r in range(flat.size):
        pos = order[r]
        if r == 0 or flat[pos] != flat[order[r - 1]]:
            first_pos[groups] = pos
            groups += 1
        sorted_id[pos] = groups - 1
    # Renumber the groups by their first position.
    rank = np.argsort(first_pos[:groups])
    new_id = np.empty(groups, np.int64)
    unique = np.empty(groups, keys.dtype)
    for k in range(groups):
        new_id[rank[k]] = k
        unique[k] = flat[first_pos[rank[k]]]
    ids = np.empty(flat.size, np.int64)
    for r in range(flat.size):
        ids[r] = new_id[sorted_id[r]]
    return ids.reshape(keys.shape), unique


@njit
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]  # path halving
        i = parent[i]
    return i


@njit
def _group_by_component(ids, count):
    """Numba: renumbering that makes the unknowns of each connected component consecutive.

    Unknowns are connected when a row of ``ids`` (p, 4) holds both. Components are laid out in the order of
    their first unknown and keep their unknowns' relative order, so an ordering that is good inside a
    component stays good, and distant groups (a one-ring across UV seams, minified blocks) never share an
    envelope row. Returns ``(renumber, n_components)``.
    """
    parent = np.arange(count)
    for r in range(ids.shape[0]):
        a = _find(parent, ids[r, 0])
        for k in range(1, 4):
            b = _find(parent, ids[r, k])
            if a != b:
                if a < b:
                    parent[b] = a
                else:
                    parent[a] = b
                    a = b
    component = np.full(count, -1, np.int64)
    n_components = 0
    size = np.zeros(count + 1, np.int64)
    label = np.empty(count, np.int64)
    for i in range(count):
        root = _find(parent, i)
        if component[root] < 0:
            component[root] = n_components
            n_components += 1
        label[i] = component[root]
        size[label[i] + 1] += 1
    for c in range(n_components):
        size[c + 1] += size[c]
    renumber = np.empty(count, np.int64)
    for i in range(count):
        renumber[i] = size[label[i]]
        size[label[i]] += 1
    return renumber, n_components


@njit
def _apply_renumber(ids, renumber):
    out = np.empty_like(ids)
    for r in range(ids.shape[0]):
        for k in range(ids.shape[1]):
            out[r, k] = renumber[ids[r, k]]
    return out


@njit
def _envelope_first(ids, count):
    """Numba: first column of each row's envelope (the smallest unknown coupled to it by a pixel)."""
    first = np.arange(count)
    for p in range(ids.shape[0]):
        low = min(min(ids[p, 0], ids[p, 1]), min(ids[p, 2], ids[p, 3]))
        for k in range(4):
            if low < first[ids[p, k]]:
                first[ids[p, k]] = low
    return first


@njit
def _solve_normal_equations(ids, weights, target, count, ridge):
    """Numba: minimize ``||B x - target||^2 + ridge ||x||^2`` for unknowns ``0..count-1``.

    ``B[p, ids[p, k]] += weights[p, k]``. Returns ``x`` (count,).
    """
    renumber, n_components = _group_by_component(ids, count)
    if n_components == 1:
        return _solve_ordered(ids, weights, target, count, ridge)
    x = _solve_ordered(_apply_renumber(ids, renumber), weights, target, count, ridge)
    out = np.empty(count)
    for i in range(count):
        out[i] = x[renumber[i]]
    return out


@njit
def _solve_ordered(ids, weights, target, count, ridge):
    """Numba: :func:`_solve_normal_equations` in the given unknown order."""
    first = _envelope_first(ids, count)
    offset = np.empty(count + 1, np.int64)
    offset[0] = 0
    for i in range(count):
        offset[i + 1] = offset[i] + (i - first[i] + 1)
    env = np.zeros(offset[count])
    rhs = np.zeros(count)
    for p in range(ids.shape[0]):
        t = target[p]
        for a in range(4):
            ia = ids[p, a]
            wa = weights[p, a]
            rhs[ia] += wa * t
            base = offset[ia] - first[ia]
            for b in range(4):
                ib = ids[p, b]
                if ib <= ia:
                    env[base + ib] += wa * weights[p, b]
    for i in range(count):
        env[offset[i + 1] - 1] += ridge
    _envelope_cholesky_solve(env, offset, first, rhs, ridge)
    return rhs


@njit(inline="always")
def _floored_pivot(pivot, pivot_floor):
    """Numba: a Cholesky pivot of ``A + ridge I`` (``A`` positive semi-definite), raised to ``pivot_floor``.

    Every exact pivot of ``A + ridge I`` is at least ``ridge`` (a Schur complement of a positive semi-definite
    matrix plus ``ridge I``). Rounding can still take one below it, to zero or below when ``A`` is rank
    deficient (pixels of zero-UV-area faces all reading one point make rank-1 blocks) and its entries are
    large next to the ridge: the rounding error of a pivot grows with the row's length times its diagonal.
    A pivot at or below zero would make the square root NaN, and in a ``fastmath`` kernel numba's division
    check then raises ``ZeroDivisionError`` on the NaN divisor. Raising such a pivot to the ridge factorizes
    a positive definite matrix within rounding of ``A + ridge I``; the comparison is written so that a NaN
    pivot is replaced too.
    """
    return pivot if pivot >= pivot_floor else pivot_floor


@njit(fastmath=True)
def _envelope_cholesky_solve(env, offset, first, rhs, pivot_floor):
    """Numba: factorize the envelope matrix in place (``L L^T``) and overwrite ``rhs`` with the solution.

    Row ``i`` holds columns ``first[i]..i`` at ``env[offset[i]:offset[i + 1]]``. ``fastmath`` lets the dot
    products vectorize (their summation order changes at round-off level only). Every pivot is at least
    ``pivot_floor`` (:func:`_floored_pivot`).
    """
    _envelope_factorize(env, offset, first, pivot_floor)
    _envelope_substitute(env, offset, first, rhs)


@njit(fastmath=True)
def _envelope_factorize(env, offset, first, pivot_floor):
    """Numba: the factorization step of :func:`_envelope_cholesky_solve` alone (``env`` overwritten with
    ``L``)."""
    count = offset.shape[0] - 1
    # Row-oriented envelope Cholesky: L[i, j] lives at env[offset[i] + j - first[i]].
    for i in range(count):
        fi = first[i]
        bi = offset[i] - fi
        for j in range(fi, i):
            fj = first[j]
            bj = offset[j] - fj
            s = 0.0
            for k in range(max(fi, fj), j):
                s += env[bi + k] * env[bj + k]
            env[bi + j] = (env[bi + j] - s) / env[offset[j + 1] - 1]
        s = 0.0
        for k in range(fi, i):
            s += env[bi + k] * env[bi + k]
        env[bi + i] = np.sqrt(_floored_pivot(env[bi + i] - s, pivot_floor))


@njit(fastmath=True)
def _envelope_substitute(env, offset, first, rhs):
    """Numba: overwrite ``rhs`` with the solution of ``L L^T x = rhs``, ``env`` the envelope factor that
    :func:`_envelope_cholesky_solve` left: forward substitution ``L y = rhs``, then back substitution
    ``L^T x = y`` (column sweep). Further right-hand sides of one factorization take this alone."""
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


@njit(fastmath=True)
def _envelope_substitute_planes(env, offset, first, x):
    """Numba: :func:`_envelope_substitute` for the ``P`` right-hand sides in the columns of ``x`` (count, P) at
    once, every factor entry read once for all of them."""
    count, n_planes = x.shape
    s = np.empty(n_planes)
    for i in range(count):
        fi = first[i]
        bi = offset[i] - fi
        s[:] = 0.0
        for k in range(fi, i):
            u = env[bi + k]
            for q in range(n_planes):
                s[q] += u * x[k, q]
        d = env[bi + i]
        for q in range(n_planes):
            x[i, q] = (x[i, q] - s[q]) / d
    for i in range(count - 1, -1, -1):
        fi = first[i]
        bi = offset[i] - fi
        d = env[bi + i]
        for q in range(n_planes):
            x[i, q] /= d
        for k in range(fi, i):
            u = env[bi + k]
            for q in range(n_planes):
                x[k, q] -= u * x[i, q]


@njit(fastmath=True)
def _band_cholesky_solve(band, rhs, pivot_floor):
    """Numba: solve with a symmetric band matrix, ``band[j, d] = A[j + d, j]`` (lower band, column-major).

    Right-looking: after scaling column ``j`` its rank-1 update touches fixed-length contiguous rows, which
    vectorize better than the envelope's variable-length dot products when the envelope is nearly a full band.
    ``band`` is overwritten with ``L``; ``rhs`` with the solution. Every pivot is at least ``pivot_floor``
    (:func:`_floored_pivot`).
    """
    _band_factorize(band, pivot_floor)
    _band_substitute(band, rhs)


@njit(fastmath=True)
def _band_factorize(band, pivot_floor):
    """Numba: the factorization step of :func:`_band_cholesky_solve` alone (``band`` overwritten with
    ``L``)."""
    count, width = band.shape
    b = width - 1
    for j in range(count):
        d = np.sqrt(_floored_pivot(band[j, 0], pivot_floor))
        band[j, 0] = d
        m = min(b, count - 1 - j)
        inv = 1.0 / d
        for k in range(1, m + 1):
            band[j, k] *= inv
        for k1 in range(1, m + 1):
            l1 = band[j, k1]
            if l1 == 0.0:
                continue
            row = j + k1
            for k2 in range(k1, m + 1):
                band[row, k2 - k1] -= band[j, k2] * l1


@njit(fastmath=True)
def _band_substitute(band, rhs):
    """Numba: overwrite ``rhs`` with the solution of ``L L^T x = rhs``, ``band`` the factor that
    :func:`_band_cholesky_solve` left (forward, then back substitution). Further right-hand sides of one
    factorization take this alone."""
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
def _band_substitute_planes(band, x):
    """Numba: :func:`_band_substitute` for the ``P`` right-hand sides in the columns of ``x`` (count, P) at
    once, every factor entry read once for all of them."""
    count, width = band.shape
    n_planes = x.shape[1]
    b = width - 1
    s = np.empty(n_planes)
    for j in range(count):
        d = band[j, 0]
        for q in range(n_planes):
            x[j, q] /= d
        m = min(b, count - 1 - j)
        for k in range(1, m + 1):
            u = band[j, k]
            for q in range(n_planes):
                x[j + k, q] -= u * x[j, q]
    for j in range(count - 1, -1, -1):
        m = min(b, count - 1 - j)
        s[:] = 0.0
        for k in range(1, m + 1):
            u = band[j, k]
            for q in range(n_planes):
                s[q] += u * x[j + k, q]
        d = band[j, 0]
        for q in range(n_planes):
            x[j, q] = (x[j, q] - s[q]) / d


@njit
def _render_ids(ids, weights, values):
    """Numba: ``sum_k weights[p, k] * values[ids[p, k]]`` for every pixel."""
    out = np.empty(ids.shape[0])
    for p in range(ids.shape[0]):
        out[p] = (weights[p, 0] * values[ids[p, 0]] + weights[p, 1] * values[ids[p, 1]]
                  + weights[p, 2] * values[ids[p, 2]] + weights[p, 3] * values[ids[p, 3]])
    return out


def _check(texels, weights, target):
    texels = np.ascontiguousarray(texels)
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    target = np.ascontiguousarray(target, dtype=np.float64)
    if texels.ndim != 2 or texels.shape[1] != 4 or not np.issubdtype(texels.dtype, np.integer):
        raise ValueError(f"texels must be an integer array of shape (p, 4), got {texels.dtype} {texels.shape}")
    if weights.shape != texels.shape:
        raise ValueError(f"weights must have the shape of texels {texels.shape}, got {weights.shape}")
    if target.shape != texels.shape[:1]:
        raise ValueError(f"target must have shape ({len(texels)},), got {target.shape}")
    return texels.astype(np.int64), weights, target


def rebake(texels, weights, target, *, ridge=DEFAULT_RIDGE):
    """Least-squares texel values whose bilinear render matches ``target`` (Eq. 11).

    Parameters
    ----------
    texels : (p, 4) array_like of int
        Texel indices (any integer labels) each pixel reads.
    weights : (p, 4) array_like of float64
        Bilinear weights of those texels.
    target : (p,) array_like of float64
        Values the pixels should take (the reference render).
    ridge : float, optional
        Tikhonov weight (see the module notes); must be positive.

    Returns
    -------
    unique : (t,) ndarray of int64
        The distinct texels read, in order of first appearance.
    values : (t,) ndarray of float64
        Their re-baked values.

    References
    ----------
    Sun et al. 2022, Eq. 11.
    """
    texels, weights, target = _check(texels, weights, target)
    if not ridge > 0:
        raise ValueError(f"ridge must be positive, got {ridge}")
    if len(texels) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    ids, unique = _first_occurrence_ids(texels)
    return unique, _solve_normal_equations(ids, weights, target, len(unique), float(ridge))


def render_texels(texels, weights, unique, values):
    """Render pixels from the texel values returned by :func:`rebake`.

    Parameters
    ----------
    texels, weights : (p, 4) array_like
    unique, values : (t,) array_like
        Texel labels and their values; every label in ``texels`` must be in ``unique``.

    Returns
    -------
    (p,) ndarray of float64
    """
    texels = np.asarray(texels, dtype=np.int64)
    unique = np.asarray(unique, dtype=np.int64)
    order = np.argsort(unique)
    pos = np.searchsorted(unique[order], texels)
    if np.any(pos >= len(unique)) or np.any(unique[order][np.minimum(pos, len(unique) - 1)] != texels):
        raise ValueError("texels holds labels that are not in unique")
    return np.einsum("pk,pk->p", np.asarray(weights, dtype=np.float64), np.asarray(values)[order[pos]])


def _rebake_reference(texels, weights, target, *, ridge=DEFAULT_RIDGE):
    """Plain numpy/scipy version of :func:`rebake` (sparse normal equations, direct solve)."""
    import scipy.sparse
    import scipy.sparse.linalg

    texels, weights, target = _check(texels, weights, target)
    unique, inverse = np.unique(texels.reshape(-1), return_inverse=True)
    B = scipy.sparse.csr_matrix((weights.reshape(-1), (np.repeat(np.arange(len(texels)), 4), inverse.reshape(-1))),
                                shape=(len(texels), len(unique)))
    normal = (B.T @ B + ridge * scipy.sparse.identity(len(unique))).tocsc()
    values = scipy.sparse.linalg.spsolve(normal, B.T @ target)
    return unique, np.atleast_1d(values)
