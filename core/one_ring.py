"""One-ring neighbourhoods of triangles: the triangles that share a vertex with each triangle.

The triangle-wise render (Sec. 4.1, text after Eq. 6) draws the triangle together with its one-ring so the
pixels at its boundary are not ambiguous, and with every further face connected to it that reaches into its
view window (:func:`window_faces`). Vertices are welded by position first: glTF and OBJ files often
duplicate vertices along UV seams, and the render must not stop at a seam.
"""
import numpy as np

from ._jit import njit

__all__ = ["weld_vertices", "one_ring_faces", "window_faces", "WINDOW_FACE_LIMIT"]

#: Most faces drawn into one triangle's view (:func:`window_faces`).
WINDOW_FACE_LIMIT = 4096


def weld_vertices(V):
    """Ids that are equal exactly for vertices at the same position.

    Parameters
    ----------
    V : (n, 3) array_like of float64

    Returns
    -------
    (n,) ndarray of int64
        ``ids[i] == ids[j]`` iff ``V[i]`` and ``V[j]`` are bitwise-equal positions.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must have shape (n, 3), got {V.shape}")
    _, ids = np.unique(V + 0.0, axis=0, return_inverse=True)  # + 0.0 turns -0.0 into 0.0
    return ids.reshape(-1).astype(np.int64)


def one_ring_faces(F, *, V=None):
    """For every triangle, the triangles that share at least one vertex with it (itself included).

    Parameters
    ----------
    F : (m, 3) array_like of int64
        Triangles.
    V : (n, 3) array_like of float64, optional
        Positions; when given, vertices at the same position count as one vertex.

    Returns
    -------
    offsets : (m + 1,) ndarray of int64
    neighbours : (offsets[-1],) ndarray of int64
        The one-ring of face ``f`` is ``neighbours[offsets[f]:offsets[f + 1]]``, sorted ascending.
    """
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"F must be an integer array of shape (m, 3), got {F.dtype} {F.shape}")
    F = F.astype(np.int64)
    if V is not None:
        V = np.asarray(V)
        if F.size and F.max() >= len(V):
            raise ValueError("F refers to vertices outside V")
        F = weld_vertices(V)[F]
    m = len(F)
    if m == 0:
        return np.zeros(1, np.int64), np.zeros(0, np.int64)
    # The faces of every vertex (ascending: a stable sort of the corners), then each face's through its corners,
    # each face's list first given room for every face of its corners (repeats included), then compacted.
    corner_vertex = F.reshape(-1)
    order = np.argsort(corner_vertex, kind="stable")
    vertex_offsets = np.searchsorted(corner_vertex[order], np.arange(int(corner_vertex.max()) + 2))
    room = np.diff(vertex_offsets)[F].sum(axis=1)
    starts = np.concatenate([[0], np.cumsum(room)])
    counts, listed = _one_ring_kernel(np.ascontiguousarray(F), vertex_offsets.astype(np.int64), order // 3, starts)
    used = np.arange(starts[-1]) - np.repeat(starts[:-1], room) < np.repeat(counts, room)
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), listed[used]


@njit
def _one_ring_kernel(F, vertex_offsets, vertex_faces, starts):
    """Numba: every face's one-ring, sorted, at ``starts[f]`` of one array, and its length; a stamp per face marks
    the neighbours already listed, so no global sort of all (face, neighbour) pairs is needed."""
    m = F.shape[0]
    stamp = np.full(m, -1, np.int64)
    counts = np.zeros(m, np.int64)
    listed = np.empty(starts[m], np.int64)
    for f in range(m):
        at = starts[f]
        for c in range(3):
            v = F[f, c]
            for k in range(vertex_offsets[v], vertex_offsets[v + 1]):
                g = vertex_faces[k]
                if stamp[g] != f:
                    stamp[g] = f
                    listed[at] = g
                    at += 1
        listed[starts[f]:at].sort()
        counts[f] = at - starts[f]
    return counts, listed


def window_faces(V, F, adjacency, face, *, origin, right, up, normal, bounds, limit=WINDOW_FACE_LIMIT):
    """The faces drawn into a triangle's view: those connected to it that reach into its window.

    Breadth-first from ``face`` through the one-rings: a face joins when its projection's bounding box meets
    the window and its corners lie within half a window side of the triangle's plane; only joined faces are
    expanded. The paper renders the whole mesh (Eq. 6) into a window about the size of the triangle and notes
    that the one-ring then fills it. That holds for well-shaped triangles, not for slivers: a 1:200 sliver of
    a flat panel covers 2 % of its square window with its one-ring, so its loss saw a thin line instead of the
    panel around it. The distance to the plane keeps out parts of the model that would hide the triangle in
    an orthographic view from ``EYE_DISTANCE`` away.

    Parameters
    ----------
    V : (n, 3) array_like of float64
    F : (m, 3) array_like of int64
    adjacency : tuple
        ``(offsets, neighbours)`` from :func:`one_ring_faces` (with ``V``).
    face : int
    origin, right, up, normal : (3,) array_like
        The camera frame (:class:`.camera.TriangleCameras`).
    bounds : (4,) array_like
        ``(left, right, bottom, top)`` of the window in the ``(right, up)`` frame relative to ``origin``.
    limit : int, optional
        Most faces returned (the first ones reached).

    Returns
    -------
    (k,) ndarray of int64
        ``face`` first, then in breadth-first order; always contains ``face``.

    References
    ----------
    Sun et al. 2022, Sec. 4.1 (text after Eq. 6), App. A.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    offsets, neighbours = adjacency
    frame = np.ascontiguousarray(np.stack([origin, right, up, normal]), dtype=np.float64)
    if frame.shape != (4, 3):
        raise ValueError("origin, right, up and normal must be 3-vectors")
    if not 0 <= int(face) < len(F):
        raise ValueError(f"face {face} is outside F")
    if int(limit) < 1:
        raise ValueError(f"limit must be positive, got {limit}")
    return _window_faces_kernel(V, F, np.asarray(offsets, np.int64), np.asarray(neighbours, np.int64), int(face),
                                frame, np.asarray(bounds, np.float64), int(limit), np.zeros(len(F), np.int64), 1)


@njit
def _window_faces_kernel(V, F, offsets, neighbours, face, frame, bounds, limit, stamp, mark):
    """Numba: :func:`window_faces`; ``stamp[f] == mark`` marks faces already seen, so one ``stamp`` array
    serves many calls with increasing ``mark`` without clearing."""
    half = 0.5 * (bounds[1] - bounds[0])
    out = np.empty(limit, np.int64)
    out[0] = face
    stamp[face] = mark
    count = 1
    head = 0
    while head < count and count < limit:
        g = out[head]
        head += 1
        for k in range(offsets[g], offsets[g + 1]):
            q = neighbours[k]
            if stamp[q] == mark:
                continue
            stamp[q] = mark
            x_min = np.inf
            x_max = -np.inf
            y_min = np.inf
            y_max = -np.inf
            near = True
            for c in range(3):
                x = y = height = 0.0
                for axis in range(3):  # scalars: no array per corner in this per-face loop
                    d = V[F[q, c], axis] - frame[0, axis]
                    x += d * frame[1, axis]
                    y += d * frame[2, axis]
                    height += d * frame[3, axis]
                x_min = min(x_min, x)
                x_max = max(x_max, x)
                y_min = min(y_min, y)
                y_max = max(y_max, y)
                near = near and abs(height) <= half
            if near and x_max >= bounds[0] and x_min <= bounds[1] and y_max >= bounds[2] and y_min <= bounds[3]:
                out[count] = q
                count += 1
                if count == limit:
                    break
    return out[:count]
