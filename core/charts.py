"""UV topology of a textured triangle mesh: chart vertices, charts (UV islands), seams and orientation.

A textured mesh stores one UV per face corner. Two faces are glued in UV space across a 3D edge when both
endpoints carry the same UV in both faces; corners of one 3D vertex that are glued this way (directly or
through a chain of glued edges) are one *chart vertex*. Charts are the connected components of faces over
glued edges; a 3D edge shared by faces that are not glued across it is a *seam*. The mesh-wise stage
(Sec. 4.2) moves chart vertices, so seams stay seams and vertices shared inside a chart stay shared.

UVs are compared exactly: loaders store one float per UV corner (Blender keeps float32 per loop, OBJ and glTF
index shared UVs), so equal UVs of one vertex are bit-identical.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

__all__ = ["UVTopology", "uv_topology", "signed_uv_areas", "texel_areas", "validate_faces_and_uv"]


def validate_faces_and_uv(F, uv):
    """Check and convert faces and per-corner UVs.

    Parameters
    ----------
    F : (m, 3) array_like of int
        Triangle vertex indices (3D vertices), non-negative.
    uv : (m, 3, 2) array_like of float
        UV coordinates per face corner.

    Returns
    -------
    F : (m, 3) int64 ndarray
    uv : (m, 3, 2) float64 ndarray

    Raises
    ------
    ValueError
        On wrong shapes, negative indices or non-finite UVs.
    """
    F = np.asarray(F)
    uv = np.asarray(uv, dtype=np.float64)
    if F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"F must have shape (m, 3), got {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    F = F.astype(np.int64, copy=False)
    if uv.shape != (F.shape[0], 3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2) = ({F.shape[0]}, 3, 2) to match F, got {uv.shape}")
    if F.shape[0] == 0:
        raise ValueError("the mesh has no faces")
    if F.min() < 0:
        raise ValueError("F holds negative vertex indices")
    if not np.all(np.isfinite(uv)):
        raise ValueError("uv holds NaN or infinite coordinates")
    return F, uv


def signed_uv_areas(uv):
    """Signed areas of UV triangles (positive when the corners run counter-clockwise).

    Parameters
    ----------
    uv : (m, 3, 2) array_like of float
        UV coordinates per face corner.

    Returns
    -------
    (m,) float64 ndarray
    """
    uv = np.asarray(uv, dtype=np.float64)
    e1 = uv[:, 1] - uv[:, 0]
    e2 = uv[:, 2] - uv[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def texel_areas(uv, w, h):
    """Areas of UV triangles in texels of a ``w`` x ``h`` texture.

    Parameters
    ----------
    uv : (m, 3, 2) array_like of float
    w, h : int

    Returns
    -------
    (m,) float64 ndarray
    """
    return np.abs(signed_uv_areas(uv)) * w * h


@dataclass(frozen=True)
class UVTopology:
    """Chart structure of per-corner UVs (see :func:`uv_topology`).

    Attributes
    ----------
    corner_vertex : (m, 3) int64 ndarray
        Chart-vertex index of every face corner.
    vertex_uv : (k, 2) float64 ndarray
        UV of every chart vertex (all its corners carry exactly this UV).
    vertex_position : (k,) int64 ndarray
        3D vertex (row of V) of every chart vertex.
    vertex_chart : (k,) int64 ndarray
        Chart of every chart vertex.
    face_chart : (m,) int64 ndarray
        Chart of every face; charts are numbered in order of their first face.
    n_charts : int
    face_orientation : (m,) int8 ndarray
        Sign of the signed UV area of each face (0 for zero area).
    chart_orientation : (n_charts,) int8 ndarray
        Sign of the chart's total signed UV area: -1 for a mirrored chart, 0 if it has no area.
    edge_glued : (m, 3) bool ndarray
        Whether face edge j (corner j to corner j+1 mod 3) is glued in UV to another face.
    edge_seam : (m, 3) bool ndarray
        Whether face edge j is shared in 3D with another face but not glued to it in UV.
    seam_edges : (s, 2) int64 ndarray
        Seams as sorted pairs of 3D vertex indices, unique, lexicographically sorted.
    """

    corner_vertex: np.ndarray
    vertex_uv: np.ndarray
    vertex_position: np.ndarray
    vertex_chart: np.ndarray
    face_chart: np.ndarray
    n_charts: int
    face_orientation: np.ndarray
    chart_orientation: np.ndarray
    edge_glued: np.ndarray
    edge_seam: np.ndarray
    seam_edges: np.ndarray

    @property
    def n_vertices(self):
        """Number of chart vertices."""
        return self.vertex_uv.shape[0]

    def corner_uv(self, vertex_uv=None):
        """Per-corner UVs from chart-vertex UVs.

        Parameters
        ----------
        vertex_uv : (k, 2) array_like of float, optional
            New chart-vertex UVs; the stored ones when omitted.

        Returns
        -------
        (m, 3, 2) float64 ndarray
        """
        vertex_uv = self.vertex_uv if vertex_uv is None else np.asarray(vertex_uv, dtype=np.float64)
        if vertex_uv.shape != (self.n_vertices, 2):
            raise ValueError(f"vertex_uv must have shape ({self.n_vertices}, 2), got {vertex_uv.shape}")
        return vertex_uv[self.corner_vertex]

    def chart_faces(self, chart):
        """Indices of the faces of one chart, ascending."""
        if not 0 <= chart < self.n_charts:
            raise ValueError(f"chart must be in [0, {self.n_charts}), got {chart}")
        return np.flatnonzero(self.face_chart == chart)


def _relabel_by_first_occurrence(labels):
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first)
    new_label = np.empty(order.size, dtype=np.int64)
    new_label[order] = np.arange(order.size)
    return new_label[labels]


def uv_topology(F, uv):
    """Chart vertices, charts, seams and orientations of a mesh with per-corner UVs.

    Parameters
    ----------
    F : (m, 3) array_like of int
        Triangle vertex indices (3D vertices).
    uv : (m, 3, 2) array_like of float
        UV coordinates per face corner.

    Returns
    -------
    UVTopology

    Notes
    -----
    Two faces sharing the 3D edge (a, b) are glued when a carries the same UV in both faces and so does b;
    non-manifold edges glue every pair of their faces that agree. Corners meeting only at a vertex (no glued
    edge path around it) stay separate chart vertices even when their UVs coincide, so charts are
    edge-connected. Gluing ignores orientation: a chart folded over a glued edge (both sides mirrored onto
    the same UVs) stays one chart; ``face_orientation`` keeps each face's own sign, and the mesh-wise solver
    preserves orientation per face. A face with a repeated vertex index glues nothing across its degenerate
    edge.

    Examples
    --------
    Two triangles of a unit square sharing the diagonal, glued in UV:

    >>> F = [[0, 1, 2], [0, 2, 3]]
    >>> uv = [[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]]
    >>> topo = uv_topology(F, uv)
    >>> topo.n_vertices, topo.n_charts
    (4, 1)
    """
    F, uv = validate_faces_and_uv(F, uv)
    m = F.shape[0]
    corner = np.arange(3 * m, dtype=np.int64).reshape(m, 3)

    # One record per face edge (corner j -> j+1), keyed by its sorted 3D endpoints and the UVs at them.
    j0 = np.tile(np.arange(3), m).reshape(m, 3)
    j1 = (j0 + 1) % 3
    face = np.repeat(np.arange(m, dtype=np.int64), 3).reshape(m, 3)
    va, vb = F, np.take_along_axis(F, j1, axis=1)
    swap = va > vb
    lo_corner = np.where(swap, j1, j0).ravel()
    hi_corner = np.where(swap, j0, j1).ravel()
    face = face.ravel()
    lo = F[face, lo_corner]
    hi = F[face, hi_corner]
    uv_lo = uv[face, lo_corner]
    uv_hi = uv[face, hi_corner]
    proper = lo != hi

    keys_3d = np.stack([lo, hi], axis=1)
    keys = np.concatenate([keys_3d.astype(np.float64), uv_lo, uv_hi], axis=1)
    # np.lexsort sorts by the last key first; int64 vertex ids fit a float64 exactly below 2**53.
    order = np.lexsort(keys[:, ::-1].T)
    order = order[proper[order]]
    sorted_keys = keys[order]
    same_as_next = np.all(sorted_keys[1:] == sorted_keys[:-1], axis=1)
    first, second = order[:-1][same_as_next], order[1:][same_as_next]

    glued = np.zeros(3 * m, dtype=bool)
    glued[first] = True
    glued[second] = True

    shared_3d = np.zeros(3 * m, dtype=bool)
    sorted_3d = keys_3d[order]
    same_edge = np.all(sorted_3d[1:] == sorted_3d[:-1], axis=1)
    shared_3d[order[:-1][same_edge]] = True
    shared_3d[order[1:][same_edge]] = True
    seam = shared_3d & ~glued

    # Chart vertices: connected components of corners linked through glued edges.
    rows = np.concatenate([corner[face[first], lo_corner[first]], corner[face[first], hi_corner[first]]])
    cols = np.concatenate([corner[face[second], lo_corner[second]], corner[face[second], hi_corner[second]]])
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(3 * m, 3 * m))
    _, corner_label = connected_components(graph, directed=False)
    corner_label = _relabel_by_first_occurrence(corner_label)
    corner_vertex = corner_label.reshape(m, 3).astype(np.int64)
    k = int(corner_vertex.max()) + 1
    vertex_uv = np.empty((k, 2))
    vertex_uv[corner_vertex.ravel()] = uv.reshape(-1, 2)
    vertex_position = np.empty(k, dtype=np.int64)
    vertex_position[corner_vertex.ravel()] = F.ravel()

    face_graph = sp.coo_matrix((np.ones(first.size), (face[first], face[second])), shape=(m, m))
    n_charts, face_label = connected_components(face_graph, directed=False)
    face_chart = _relabel_by_first_occurrence(face_label)
    vertex_chart = np.empty(k, dtype=np.int64)
    vertex_chart[corner_vertex.ravel()] = np.repeat(face_chart, 3)

    area = signed_uv_areas(uv)
    face_orientation = np.sign(area).astype(np.int8)
    chart_orientation = np.sign(np.bincount(face_chart, weights=area, minlength=n_charts)).astype(np.int8)

    seam_edges = np.unique(keys_3d[seam], axis=0) if seam.any() else np.empty((0, 2), dtype=np.int64)
    return UVTopology(
        corner_vertex=corner_vertex,
        vertex_uv=vertex_uv,
        vertex_position=vertex_position,
        vertex_chart=vertex_chart,
        face_chart=face_chart,
        n_charts=int(n_charts),
        face_orientation=face_orientation,
        chart_orientation=chart_orientation,
        # Records were built face-major, edge-minor, so a reshape restores the (m, 3) layout.
        edge_glued=glued.reshape(m, 3),
        edge_seam=seam.reshape(m, 3),
        seam_edges=seam_edges.astype(np.int64),
    )

