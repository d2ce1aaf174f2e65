"""One-ring neighbourhoods of triangles: the triangles that share a vertex with each triangle.

The triangle-wise render (Sec. 4.1, text after Eq. 6) draws the triangle together with its one-ring so the
pixels at its boundary are not ambiguous. Vertices are welded by position first: glTF and OBJ files often
duplicate vertices along UV seams, and the render must not stop at a seam.
"""
import numpy as np

__all__ = ["weld_vertices", "one_ring_faces"]


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
    # (face, vertex) incidences, then (face, neighbour face) pairs through each shared vertex.
    corner_vertex = F.reshape(-1)
    corner_face = np.repeat(np.arange(m, dtype=np.int64), 3)
    order = np.argsort(corner_vertex, kind="stable")
    sorted_vertex = corner_vertex[order]
    sorted_face = corner_face[order]
    starts = np.searchsorted(sorted_vertex, corner_vertex, side="left")
    stops = np.searchsorted(sorted_vertex, corner_vertex, side="right")
    counts = stops - starts
    pair_face = np.repeat(corner_face, counts)
    idx = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    pair_neighbour = sorted_face[idx]
    key = np.unique(pair_face * m + pair_neighbour)
    faces, neighbours = np.divmod(key, m)
    offsets = np.zeros(m + 1, np.int64)
    np.add.at(offsets, faces + 1, 1)
    return np.cumsum(offsets), neighbours.astype(np.int64)
