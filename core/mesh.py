# SPDX-License-Identifier: GPL-3.0-or-later
"""A triangle mesh with per-corner UVs as plain arrays, and its validation (no bpy).

The bridge fills a :class:`MeshArrays` from Blender data; everything in ``core`` consumes it. The triangle
to loop map (``tri_loops``, ``tri_polygons``) lets results computed per triangle corner be written back onto
the original polygons' loops, so quads and n-gons keep their topology. :func:`read_obj` reads the same arrays
from a triangulated Wavefront OBJ file (tests, benchmarks, scripts outside Blender).
"""
import dataclasses

import numpy as np

__all__ = ["MeshArrays", "validate_mesh_arrays", "check_mesh", "concatenate_meshes", "read_obj"]


@dataclasses.dataclass(frozen=True, eq=False)
class MeshArrays:
    """Triangulated mesh data as arrays.

    Attributes
    ----------
    V : (n, 3) float64
        Vertex positions in world space.
    F : (m, 3) int64
        Triangles as vertex indices into ``V``; counter-clockwise seen from the front.
    uv : (m, 3, 2) float64
        UV coordinates of each triangle corner (``uv[i, k]`` belongs to vertex ``F[i, k]``).
    tri_loops : (m, 3) int64
        Index of the mesh loop each triangle corner comes from (Blender's ``loop_triangles[i].loops``).
    tri_polygons : (m,) int64
        Index of the polygon each triangle belongs to.
    material_index : (m,) int64
        Material slot of each triangle.
    object_index : (m,) int64
        Which source object each triangle comes from (all 0 for one object); ``tri_loops`` and
        ``tri_polygons`` index into that object's mesh.
    object_names : tuple of str
        Names of the source objects, indexed by ``object_index``.
    uv_name : str
        Name of the UV map the UVs were read from.
    """

    V: np.ndarray
    F: np.ndarray
    uv: np.ndarray
    tri_loops: np.ndarray
    tri_polygons: np.ndarray
    material_index: np.ndarray
    object_index: np.ndarray
    object_names: tuple = ()
    uv_name: str = ""

    def __post_init__(self):
        validate_mesh_arrays(self)

    @property
    def n_vertices(self):
        """Number of vertices ``n``."""
        return int(self.V.shape[0])

    @property
    def n_faces(self):
        """Number of triangles ``m``."""
        return int(self.F.shape[0])


def _check_array(name, array, dtype, shape):
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(array).__name__}")
    if array.dtype != dtype:
        raise ValueError(f"{name} must have dtype {np.dtype(dtype).name}, got {array.dtype}")
    expected = tuple("?" if size is None else size for size in shape)
    if array.ndim != len(shape) or any(size is not None and size != got for size, got in zip(shape, array.shape)):
        raise ValueError(f"{name} must have shape {expected}, got {array.shape}")


def validate_mesh_arrays(mesh):
    """Check shapes, dtypes, index ranges and finiteness of a :class:`MeshArrays`.

    Parameters
    ----------
    mesh : MeshArrays

    Raises
    ------
    ValueError
        With a message naming the offending field.
    """
    _check_array("V", mesh.V, np.float64, (None, 3))
    m = mesh.F.shape[0] if isinstance(mesh.F, np.ndarray) else None
    _check_array("F", mesh.F, np.int64, (None, 3))
    _check_array("uv", mesh.uv, np.float64, (m, 3, 2))
    _check_array("tri_loops", mesh.tri_loops, np.int64, (m, 3))
    _check_array("tri_polygons", mesh.tri_polygons, np.int64, (m,))
    _check_array("material_index", mesh.material_index, np.int64, (m,))
    _check_array("object_index", mesh.object_index, np.int64, (m,))
    if not np.isfinite(mesh.V).all():
        raise ValueError("V contains NaN or infinite coordinates")
    if not np.isfinite(mesh.uv).all():
        raise ValueError("uv contains NaN or infinite coordinates")
    if m and (mesh.F.min() < 0 or mesh.F.max() >= mesh.V.shape[0]):
        raise ValueError(f"F indexes vertices outside [0, {mesh.V.shape[0]})")
    if m and (mesh.object_index.min() < 0 or mesh.object_index.max() >= max(len(mesh.object_names), 1)):
        raise ValueError("object_index points outside object_names")


def check_mesh(V, F):
    """Check and convert the vertex and triangle arrays of a mesh given as plain arrays.

    Parameters
    ----------
    V : (n, 3) array_like of float
        Vertex positions.
    F : (m, 3) array_like of int
        Triangles as vertex indices into ``V``; ``m = 0`` passes.

    Returns
    -------
    V : (n, 3) float64 ndarray, C-contiguous
    F : (m, 3) int64 ndarray, C-contiguous

    Raises
    ------
    ValueError
        On wrong shapes, a non-integer ``F`` or indices outside ``[0, n)``. Values of ``V`` are not checked
        (callers that need finite positions test that themselves).
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must have shape (n, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"F must be an integer array of shape (m, 3), got {F.dtype} {F.shape}")
    F = np.ascontiguousarray(F, dtype=np.int64)
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        raise ValueError("F refers to vertices outside V")
    return V, F


def concatenate_meshes(meshes):
    """Join several meshes (e.g. objects sharing one texture atlas) into one.

    Parameters
    ----------
    meshes : sequence of MeshArrays
        Each with its own ``object_names``; vertex indices are offset, ``object_index`` renumbered.

    Returns
    -------
    MeshArrays
        ``V`` stacked, ``F`` offset by the vertex counts before it; ``tri_loops`` and ``tri_polygons`` stay
        relative to each source object's mesh (use ``object_index`` to tell them apart).
    """
    meshes = list(meshes)
    if not meshes:
        raise ValueError("concatenate_meshes needs at least one mesh")
    uv_names = {mesh.uv_name for mesh in meshes}
    vertex_offsets = np.cumsum([0] + [mesh.n_vertices for mesh in meshes[:-1]])
    object_offsets = np.cumsum([0] + [max(len(mesh.object_names), 1) for mesh in meshes[:-1]])
    names = []
    for mesh in meshes:
        names.extend(mesh.object_names or ("",))
    return MeshArrays(
        V=np.concatenate([mesh.V for mesh in meshes]),
        F=np.concatenate([mesh.F + offset for mesh, offset in zip(meshes, vertex_offsets)]),
        uv=np.concatenate([mesh.uv for mesh in meshes]),
        tri_loops=np.concatenate([mesh.tri_loops for mesh in meshes]),
        tri_polygons=np.concatenate([mesh.tri_polygons for mesh in meshes]),
        material_index=np.concatenate([mesh.material_index for mesh in meshes]),
        object_index=np.concatenate([mesh.object_index + offset for mesh, offset in zip(meshes, object_offsets)]),
        object_names=tuple(names),
        uv_name=uv_names.pop() if len(uv_names) == 1 else "",
    )


def read_obj(path):
    """Read vertices, triangles and per-corner UVs from a triangulated Wavefront OBJ file.

    Reads ``v x y z``, ``vt u v`` and ``f a/ta b/tb c/tc`` lines (``a/ta/na`` too); indices are 1-based, as
    the format has them. Every other line (normals, groups, materials, comments) is ignored, and so is a
    third texture coordinate ``w``. Objects and groups are not told apart: all faces form one mesh.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    V : (n, 3) float64 ndarray
        Vertex positions, in file order.
    F : (m, 3) int64 ndarray
        Triangles as 0-based indices into ``V``, corners in file order.
    uv : (m, 3, 2) float64 ndarray
        Texture coordinates of each triangle corner (``uv[i, k]`` belongs to vertex ``F[i, k]``).

    Raises
    ------
    ValueError
        On a face that is not a triangle, a face corner without a texture coordinate index, an index that is
        not a positive integer or points past the ``v``/``vt`` lines, a file without faces or without ``vt``
        lines; the message names the file (and the line where there is one).
    """
    positions, texcoords, corners = [], [], []
    with open(path) as lines:
        for number, line in enumerate(lines, 1):
            parts = line.split()
            if not parts:
                continue
            where = f"{path}, line {number}"
            if parts[0] == "v":
                positions.append([float(x) for x in parts[1:4]])
                if len(positions[-1]) != 3:
                    raise ValueError(f"{where}: a vertex needs three coordinates, got {line.strip()!r}")
            elif parts[0] == "vt":
                texcoords.append([float(x) for x in parts[1:3]])
                if len(texcoords[-1]) != 2:
                    raise ValueError(f"{where}: a texture coordinate needs u and v, got {line.strip()!r}")
            elif parts[0] == "f":
                if len(parts) != 4:
                    raise ValueError(f"{where}: a face with {len(parts) - 1} corners; read_obj reads "
                                     "triangulated OBJ files only")
                corners.append([_obj_corner(corner, where) for corner in parts[1:]])
    if not corners:
        raise ValueError(f"{path}: no faces")
    if not texcoords:
        raise ValueError(f"{path}: no texture coordinates (vt lines); the mesh needs UVs")
    corners = np.array(corners, dtype=np.int64) - 1  # (m, 3, 2): vertex and texture coordinate, 0-based
    for column, count, kind in ((0, len(positions), "vertex"), (1, len(texcoords), "texture coordinate")):
        if corners[..., column].max() >= count:
            raise ValueError(f"{path}: a face refers to {kind} {corners[..., column].max() + 1} of {count}")
    V = np.array(positions, dtype=np.float64).reshape(-1, 3)
    uv = np.array(texcoords, dtype=np.float64).reshape(-1, 2)[corners[..., 1]]
    return V, np.ascontiguousarray(corners[..., 0]), uv


def _obj_corner(corner, where):
    """``(vertex, texture coordinate)`` 1-based indices of one ``f`` corner ``a/ta[/na]``."""
    ids = corner.split("/")
    if len(ids) < 2 or not ids[1]:
        raise ValueError(f"{where}: face corner {corner!r} has no texture coordinate index (the mesh needs UVs)")
    try:
        vertex, texcoord = int(ids[0]), int(ids[1])
    except ValueError:
        raise ValueError(f"{where}: face corner {corner!r} is not of the form a/ta[/na]") from None
    if vertex < 1 or texcoord < 1:
        raise ValueError(f"{where}: face corner {corner!r}: indices must be positive (relative indices are "
                         "not supported)")
    return vertex, texcoord
