# SPDX-License-Identifier: GPL-3.0-or-later
"""A triangle mesh with per-corner UVs as plain arrays, and its validation (no bpy).

The bridge fills a :class:`MeshArrays` from Blender data; everything in ``core`` consumes it. The triangle
to loop map (``tri_loops``, ``tri_polygons``) lets results computed per triangle corner be written back onto
the original polygons' loops, so quads and n-gons keep their topology.
"""
import dataclasses

import numpy as np

__all__ = ["MeshArrays", "validate_mesh_arrays", "concatenate_meshes"]


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
