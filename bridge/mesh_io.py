# SPDX-License-Identifier: GPL-3.0-or-later
"""Read meshes, UV maps and images from Blender into arrays, and write new UV maps back (bpy <-> numpy).

Every transfer goes through ``foreach_get``/``foreach_set``; there is no Python loop over vertices, loops or
triangles. Reading never changes Blender data; writing only ever adds a new UV map.
"""
import contextlib
import os
import pathlib
import re
import sys
import tempfile

import bpy
import numpy as np

from ..core.mesh import MeshArrays, concatenate_meshes
from ..core.settings import MODEL_SUFFIXES, suffix_listing
from .material import base_color_image_node, loss_image_nodes

__all__ = ["import_model", "failures_in_one_line", "read_mesh", "read_image", "load_textured_mesh",
           "write_uv_layer", "image_triangle_mask"]


def import_model(path):
    """Load a model file into an empty scene (for scripts, the CLI and tests; it discards the open file).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.blend`` file (opened as the current file), or ``.obj``, ``.gltf``/``.glb``, ``.fbx``,
        ``.usd``/``.usda``/``.usdc``/``.usdz`` (imported with Blender's own importers, which convert glTF's, FBX's
        and USD's axes and glTF's flipped V to Blender's conventions; an FBX's textures embedded in it are packed,
        the others searched for by name in its folder; a USDZ's are packed).

    Returns
    -------
    list of bpy.types.Object
        The objects of the scene after loading, in name order.

    Raises
    ------
    ValueError
        If the file does not exist, has an unsupported suffix or the importer fails.
    """
    path = pathlib.Path(path).expanduser().resolve()
    suffix = path.suffix.lower()
    if suffix not in MODEL_SUFFIXES:
        raise ValueError(f"unsupported model type '{path.suffix}' for {path}; use {suffix_listing(MODEL_SUFFIXES)}")
    if not path.is_file():
        raise ValueError(f"model file not found: {path}")
    check = " (the Khronos glTF validator tells where)" if suffix in (".gltf", ".glb") else ""
    try:
        with failures_in_one_line(_LOADERS[suffix], cause=f"the file is probably invalid{check}"):
            if suffix == ".blend":
                bpy.ops.wm.open_mainfile(filepath=str(path))
            else:
                # read_homefile keeps the preferences (and so the enabled extensions), unlike
                # read_factory_settings
                bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
                if suffix == ".obj":
                    bpy.ops.wm.obj_import(filepath=str(path))
                elif suffix == ".fbx":
                    with _light_shadow_setting():
                        bpy.ops.import_scene.fbx(filepath=str(path))
                elif suffix.startswith(".usd"):
                    bpy.ops.wm.usd_import(filepath=str(path))
                else:
                    bpy.ops.import_scene.gltf(filepath=str(path))
    except RuntimeError as error:
        raise ValueError(f"could not load {path}: {error}{_load_hint(str(error))}") from error
    return sorted(bpy.context.scene.objects, key=lambda obj: obj.name)


def _load_hint(message):
    """What to do about an importer's failure ``message``, in parentheses, or "" when there is nothing to add."""
    if "ASCII FBX" in message:
        return (" (Blender reads binary FBX only: save the file as binary FBX, e.g. with Autodesk's FBX Converter or "
                "the program that wrote it, or export it as glTF)")
    missing = re.search(r"Extension (\S+) is not available", message)
    if missing is None:
        return ""
    if missing.group(1) == "EXT_meshopt_compression":
        return (" (Blender's glTF importer does not decode meshopt-compressed meshes: write the file without the "
                "compression first, e.g. `npx @gltf-transform/cli copy IN OUT`)")
    return (f" (the file requires the glTF extension {missing.group(1)}, which Blender's glTF importer does not "
            "read: export the model without it)")


@contextlib.contextmanager
def _light_shadow_setting():
    """Give Cycles' light settings a ``cast_shadow`` property meanwhile, where they lack it.

    Blender 5.0's FBX importer sets ``light.cycles.cast_shadow`` for every light of the file, a setting Cycles 5.0
    no longer has (shadows are ``light.use_shadow``, which the importer sets too): any FBX file with a light
    failed to load. The property only receives the value and is removed again afterwards.
    """
    probe = bpy.data.lights.new("perceptual_uv_probe", "POINT")
    settings = type(getattr(probe, "cycles", None))
    bpy.data.lights.remove(probe)
    missing = hasattr(settings, "bl_rna") and "cast_shadow" not in settings.bl_rna.properties
    if missing:
        settings.cast_shadow = bpy.props.BoolProperty()
    try:
        yield
    finally:
        if missing:
            del settings.cast_shadow


_LOADERS = {".blend": "Blender", ".obj": "the OBJ importer", ".gltf": "the glTF importer", ".glb": "the glTF importer",
            ".fbx": "the FBX importer", **dict.fromkeys((".usd", ".usda", ".usdc", ".usdz"), "the USD importer")}


@contextlib.contextmanager
def failures_in_one_line(program, *, cause):
    """Run a Blender operator with what the process prints held back, and its failure said in one line.

    Blender logs the traceback of an operator written in Python (its glTF and FBX importers, its glTF exporter) to
    both standard streams itself, and the operator's RuntimeError holds it too. Meanwhile the process's output
    goes to temporary files: written out again when the operator succeeds; when it raises, the RuntimeError is
    raised again as one line: Blender's own message as it is, or, where a traceback is in it, ``program``, the
    exception it ended with, ``cause`` and a file in the temporary folder that keeps what was printed.
    """
    with tempfile.TemporaryFile() as printed, tempfile.TemporaryFile() as errors:
        try:
            with _output_to(1, printed), _output_to(2, errors):
                yield
        except RuntimeError as error:
            raise RuntimeError(_failure_line(error, program, cause, _read_all(printed) + _read_all(errors))) from error
        _write_all(1, _read_all(printed))
        _write_all(2, _read_all(errors))


def _failure_line(error, program, cause, messages):
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    if not any("Traceback (most recent call last)" in line for line in lines):
        return " ".join(lines)
    raised = [line for line in lines if not line.startswith(("Location:", "File ", "^", "~", "[Previous line"))]
    handle, kept = tempfile.mkstemp(prefix="perceptual_uv-blender-", suffix=".txt")
    with os.fdopen(handle, "wb") as out:
        out.write(messages or str(error).encode())
    return f"{program} failed on it ({raised[-1]}): {cause}; its messages are in {kept}"


@contextlib.contextmanager
def _output_to(descriptor, file):
    """Send what the process writes to ``descriptor`` (1 or 2: Blender logs a failing importer's traceback to
    both itself) to ``file`` meanwhile; nothing is redirected where the process has no such stream (Blender's
    interface on Windows)."""
    stream = sys.stdout if descriptor == 1 else sys.stderr
    if stream is not None:
        stream.flush()
    try:
        saved = os.dup(descriptor)
    except OSError:
        yield
        return
    try:
        os.dup2(file.fileno(), descriptor)
        try:
            yield
        finally:
            if stream is not None:
                stream.flush()
            os.dup2(saved, descriptor)
    finally:
        os.close(saved)


def _read_all(file):
    file.seek(0)
    return file.read()


def _write_all(descriptor, data):
    """Write ``data`` (bytes) to the process's ``descriptor`` as it was captured."""
    stream = sys.stdout if descriptor == 1 else sys.stderr
    if stream is not None:
        stream.flush()
    view = memoryview(data)
    while view:
        view = view[os.write(descriptor, view):]


def _mesh_of(obj):
    if obj is None or obj.type != "MESH":
        raise ValueError(f"'{getattr(obj, 'name', obj)}' is not a mesh object")
    if obj.mode == "EDIT":
        # in Edit Mode the mesh data is stale and anything written to it is lost when the mode is left
        raise ValueError(f"'{obj.name}' is in Edit Mode; switch to Object Mode first")
    return obj.data


def _resolve_uv_name(obj, uv_name):
    mesh = _mesh_of(obj)
    if uv_name is None:
        if mesh.uv_layers.active is None:
            raise ValueError(f"'{obj.name}' has no UV map")
        return mesh.uv_layers.active.name
    if uv_name not in mesh.uv_layers:
        raise ValueError(f"'{obj.name}' has no UV map '{uv_name}' (it has: "
                         f"{', '.join(layer.name for layer in mesh.uv_layers) or 'none'})")
    return uv_name


def _get(collection, attribute, count, dtype, width=1):
    buffer = np.empty(count * width, dtype=dtype)
    collection.foreach_get(attribute, buffer)
    return buffer if width == 1 else buffer.reshape(count, width)


def read_mesh(obj, *, uv_name=None):
    """Triangulated world-space geometry and per-corner UVs of a mesh object.

    Parameters
    ----------
    obj : bpy.types.Object
        A mesh object. Its original (unmodified) mesh is read, so every triangle corner maps to a loop of
        the mesh a new UV map is written to; modifiers such as an armature pose are ignored.
    uv_name : str, optional
        UV map to read; the active one by default.

    Returns
    -------
    MeshArrays
        ``V`` (n, 3) float64 with ``obj.matrix_world`` applied, ``F`` (m, 3) int64 from Blender's own
        triangulation (``mesh.loop_triangles``), ``uv`` (m, 3, 2) float64, ``tri_loops`` (m, 3) int64,
        ``tri_polygons`` (m,) int64, ``material_index`` (m,) int64, ``object_index`` all 0.
        With a mirroring ``matrix_world`` (negative determinant) the world-space winding is reversed.

    Raises
    ------
    ValueError
        If ``obj`` is not a mesh, has no faces, lacks the UV map, or has NaN or infinite positions or UVs.
    """
    mesh = _mesh_of(obj)
    uv_name = _resolve_uv_name(obj, uv_name)
    mesh.calc_loop_triangles()
    n_vertices, n_loops, n_triangles = len(mesh.vertices), len(mesh.loops), len(mesh.loop_triangles)
    if n_triangles == 0:
        raise ValueError(f"'{obj.name}' has no faces (only loose vertices or edges, or an empty mesh): there is "
                         "nothing to optimize")
    local = _get(mesh.vertices, "co", n_vertices, np.float32, 3).astype(np.float64)
    matrix = np.array(obj.matrix_world, dtype=np.float64)
    V = local @ matrix[:3, :3].T + matrix[:3, 3]
    triangles = mesh.loop_triangles
    F = _get(triangles, "vertices", n_triangles, np.int32, 3).astype(np.int64)
    tri_loops = _get(triangles, "loops", n_triangles, np.int32, 3).astype(np.int64)
    tri_polygons = _get(triangles, "polygon_index", n_triangles, np.int32).astype(np.int64)
    material_index = _get(triangles, "material_index", n_triangles, np.int32).astype(np.int64)
    loop_uv = _get(mesh.uv_layers[uv_name].uv, "vector", n_loops, np.float32, 2).astype(np.float64)
    bad_vertices = ~np.isfinite(V).all(axis=1)
    if bad_vertices.any():
        raise ValueError(f"'{obj.name}' has {int(bad_vertices.sum())} vertices with NaN or infinite coordinates "
                         "(after its object transform); fix or delete them first")
    bad_loops = ~np.isfinite(loop_uv).all(axis=1)
    if bad_loops.any():
        raise ValueError(f"UV map '{uv_name}' of '{obj.name}' has NaN or infinite coordinates on "
                         f"{int(bad_loops.sum())} face corners; re-unwrap those faces first")
    return MeshArrays(V=V, F=F, uv=loop_uv[tri_loops], tri_loops=tri_loops, tri_polygons=tri_polygons,
                      material_index=material_index, object_index=np.zeros(n_triangles, dtype=np.int64),
                      object_names=(obj.name,), uv_name=uv_name)


def read_image(image):
    """Pixels of an image as stored, bottom row first, ``(h, w, image.channels)`` float32:
    :func:`.image_file.iter_read_image` (see there for the values and errors) run to its end."""
    from ..core.progress import run_generator
    from .image_file import iter_read_image

    return run_generator(iter_read_image(image))


def image_triangle_mask(obj, mesh_arrays, image):
    """Which triangles of ``mesh_arrays`` (read from ``obj``) show ``image``: their material's base colour, or
    when none of ``obj``'s materials has a base-colour image, their material's largest map
    (:func:`.material.loss_image_nodes`).

    Parameters
    ----------
    obj : bpy.types.Object
    mesh_arrays : MeshArrays
        As returned by :func:`read_mesh` for ``obj``.
    image : bpy.types.Image

    Returns
    -------
    (m,) bool ndarray
    """
    slot_images = loss_image_nodes(slot.material for slot in obj.material_slots)
    slot_uses = np.array([node is not None and node.image == image for node in slot_images] or [False])
    # Blender clamps material indices beyond the last slot to the last slot
    return slot_uses[np.clip(mesh_arrays.material_index, 0, len(slot_uses) - 1)]


def _base_color_images(obj):
    return [node.image for node in map(base_color_image_node, (s.material for s in obj.material_slots)) if node]


def load_textured_mesh(path, *, object_name=None, uv_name=None):
    """Import a model and return the triangles textured by its base-colour image, with that image.

    Parameters
    ----------
    path : str or os.PathLike
        Model file, see :func:`import_model`.
    object_name : str, optional
        Read only this object. By default every mesh object whose material base colour is the model's
        main image (the one that textures the most triangles) is read and the arrays are joined in world
        space, e.g. the ten objects of a tea set sharing one atlas.
    uv_name : str, optional
        UV map to read from each object; the active one by default.

    Returns
    -------
    mesh : MeshArrays
        Only the triangles whose material base colour is the chosen image; ``object_names`` lists the
        objects in ``object_index`` order.
    texture : (h, w, c) float32 ndarray
        The image's stored pixels, row 0 at the bottom.
    image_name : str
        Name of the image data block.

    Raises
    ------
    ValueError
        If the file cannot be loaded, the named object is missing or not a mesh, or no mesh object has an
        image feeding its base colour.
    """
    objects = import_model(path)
    if object_name is not None:
        matches = [obj for obj in objects if obj.name == object_name]
        if not matches:
            raise ValueError(f"no object '{object_name}' in {path} (objects: "
                             f"{', '.join(obj.name for obj in objects) or 'none'})")
        _mesh_of(matches[0])
        objects = matches
    candidates = [obj for obj in objects if obj.type == "MESH" and _base_color_images(obj)]
    if not candidates:
        if object_name is not None:
            raise ValueError(f"'{object_name}' has no image texture feeding its material's base colour")
        raise ValueError(f"no mesh object in {path} has an image texture feeding its material's base colour")
    per_object = [(obj, read_mesh(obj, uv_name=uv_name)) for obj in candidates]
    triangles_per_image = {}
    for obj, arrays in per_object:
        for image in set(_base_color_images(obj)):
            count = int(image_triangle_mask(obj, arrays, image).sum())
            triangles_per_image[image] = triangles_per_image.get(image, 0) + count
    image = max(triangles_per_image, key=lambda block: (triangles_per_image[block], block.name))
    selected = []
    for obj, arrays in per_object:
        keep = image_triangle_mask(obj, arrays, image)
        if keep.any():
            selected.append(_subset_triangles(arrays, keep))
    return concatenate_meshes(selected), read_image(image), image.name


def _subset_triangles(arrays, keep):
    if keep.all():
        return arrays
    return MeshArrays(V=arrays.V, F=arrays.F[keep], uv=arrays.uv[keep], tri_loops=arrays.tri_loops[keep],
                      tri_polygons=arrays.tri_polygons[keep], material_index=arrays.material_index[keep],
                      object_index=arrays.object_index[keep], object_names=arrays.object_names,
                      uv_name=arrays.uv_name)


def write_uv_layer(obj, name, uv_per_corner, tri_loops):
    """Add a new UV map holding per-corner UVs; existing UV maps stay untouched.

    Parameters
    ----------
    obj : bpy.types.Object
        The mesh object the corners were read from.
    name : str
        Name of the new UV map; it must not exist yet.
    uv_per_corner : (m, 3, 2) array_like
        UV of each triangle corner.
    tri_loops : (m, 3) array_like of int
        Loop index of each corner (``MeshArrays.tri_loops`` of this object). A loop shared by several
        triangles (inside an n-gon) gets the mean of their values; loops not listed keep the values of the
        active UV map, which Blender copies into a new layer.

    Returns
    -------
    bpy.types.MeshUVLoopLayer
        The new layer. The active and render-active UV maps are unchanged.

    Raises
    ------
    ValueError
        On a name clash, shape mismatch, loop indices out of range, non-finite UVs, or when the mesh already
        has the maximum number of UV maps.
    """
    mesh = _mesh_of(obj)
    if not name:
        raise ValueError("the new UV map needs a name")
    if name in mesh.uv_layers:
        raise ValueError(f"'{obj.name}' already has a UV map '{name}'; choose another name")
    uv_per_corner = np.asarray(uv_per_corner, dtype=np.float64)
    tri_loops = np.asarray(tri_loops)
    if uv_per_corner.ndim != 3 or uv_per_corner.shape[1:] != (3, 2):
        raise ValueError(f"uv_per_corner must have shape (m, 3, 2), got {uv_per_corner.shape}")
    if tri_loops.shape != uv_per_corner.shape[:2]:
        raise ValueError(f"tri_loops must have shape {uv_per_corner.shape[:2]}, got {tri_loops.shape}")
    if not np.issubdtype(tri_loops.dtype, np.integer):
        raise ValueError(f"tri_loops must hold integers, got {tri_loops.dtype}")
    if not np.isfinite(uv_per_corner).all():
        raise ValueError("uv_per_corner contains NaN or infinite values")
    n_loops = len(mesh.loops)
    if tri_loops.size and (tri_loops.min() < 0 or tri_loops.max() >= n_loops):
        raise ValueError(f"tri_loops indexes loops outside [0, {n_loops}) of '{obj.name}'")
    active_name = mesh.uv_layers.active.name if mesh.uv_layers.active else None
    render_names = [layer.name for layer in mesh.uv_layers if layer.active_render]
    layer = mesh.uv_layers.new(name=name, do_init=True)
    if layer is None:
        raise ValueError(f"'{obj.name}' cannot take another UV map (Blender allows at most 8)")
    if active_name is not None:
        mesh.uv_layers.active = mesh.uv_layers[active_name]
    for layer_name in render_names:
        mesh.uv_layers[layer_name].active_render = True
    layer = mesh.uv_layers[name]
    loop_uv = _get(layer.uv, "vector", n_loops, np.float32, 2).astype(np.float64)
    loops = tri_loops.ravel()
    counts = np.bincount(loops, minlength=n_loops)
    written = counts > 0
    for axis in range(2):
        sums = np.bincount(loops, weights=uv_per_corner[..., axis].ravel(), minlength=n_loops)
        loop_uv[written, axis] = sums[written] / counts[written]
    layer.uv.foreach_set("vector", loop_uv.astype(np.float32).ravel())
    mesh.update()
    return layer
