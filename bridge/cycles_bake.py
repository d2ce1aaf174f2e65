# SPDX-License-Identifier: GPL-3.0-or-later
"""One Cycles bake pass on temporary copies of the objects, and the texels it leaves out (DESIGN decision 6).

:func:`bake_pass` bakes ``objects`` in a temporary scene, on proxies whose material slots get the materials the
caller makes (an Emission shader for colour and data maps, :mod:`.bake`; the original material for a
tangent-space normal map, :mod:`.bake_normal`), and removes everything it created (:func:`temporary_ids`): the
objects, meshes, materials, images and the user's scene settings stay exactly as they were.

Cycles writes only texels whose centres lie in a target triangle inside [0, 1]^2. A target UV map that leaves the
unit square (renderers sample it with REPEAT) is baked once per integer tile it touches (:func:`touched_tiles`),
shifted into the unit square, and the tiles are composited into the one image. The texels bilinear lookups read
next to a triangle but whose centres no triangle covers are found per object (:func:`footprints`) for the caller to
fill, and the margin extends from all of these (:func:`extend_margin`).
"""
import contextlib

import bpy
import numpy as np
import scipy.ndimage

from ..core.footprint import footprint_texels
from .mesh_io import read_mesh

__all__ = ["target_size", "temporary_ids", "touched_tiles", "bake_pass", "footprints", "extend_margin"]


def target_size(resolution):
    """``(width, height)`` of a bake target given as its side (a square) or as ``(width, height)``."""
    width, height = (resolution, resolution) if np.ndim(resolution) == 0 else resolution
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise ValueError(f"a bake target needs at least one pixel each way, got {resolution}")
    return width, height


@contextlib.contextmanager
def temporary_ids():
    """Collects ID blocks created inside; removes them all on exit, whatever happens."""
    created = []
    try:
        yield created
    finally:
        for block in reversed(created):
            with contextlib.suppress(ReferenceError):
                collection = {bpy.types.Object: bpy.data.objects, bpy.types.Mesh: bpy.data.meshes,
                              bpy.types.Material: bpy.data.materials, bpy.types.Image: bpy.data.images,
                              bpy.types.Scene: bpy.data.scenes}.get(type(block), bpy.data.node_groups)
                collection.remove(block)


def touched_tiles(objects, target_uv, resolution):
    """Integer tiles (floor u, floor v) holding texel centres inside the polygons' target-UV bounding boxes.

    Counting centres, not areas, keeps a unit-square map (or one a float step past 1) on tile (0, 0) alone: the
    centres of tile t lie in [t + 0.5 / r, t + 1 - 0.5 / r], so a box reaching less than half a texel into a
    tile cannot cover any of them. ``resolution`` is the image's side or its ``(width, height)``.
    """
    half = 0.5 / np.array(target_size(resolution), dtype=np.float64)
    tiles = set()
    for obj in objects:
        mesh = obj.data
        if not len(mesh.polygons):
            continue
        uv = np.empty(2 * len(mesh.loops))
        mesh.uv_layers[target_uv].uv.foreach_get("vector", uv)
        uv = uv.reshape(-1, 2)
        starts = np.empty(len(mesh.polygons), dtype=np.int64)
        mesh.polygons.foreach_get("loop_start", starts)
        low = np.ceil(np.minimum.reduceat(uv, starts) + half) - 1
        high = np.floor(np.maximum.reduceat(uv, starts) - half)
        finite = np.isfinite(low).all(axis=1) & np.isfinite(high).all(axis=1)
        low, high = low[finite].astype(np.int64), high[finite].astype(np.int64)
        single = (low == high).all(axis=1)
        tiles.update(map(tuple, np.unique(low[single], axis=0).tolist()))
        for (u0, v0), (u1, v1) in zip(low[~single].tolist(), high[~single].tolist()):
            tiles.update((u, v) for u in range(u0, u1 + 1) for v in range(v0, v1 + 1))
    return sorted(tiles, key=lambda tile: (tile != (0, 0), tile))


def bake_pass(objects, material_for, material_key, *, source_uv, target_uv, resolution, tiles, bake_type,
               slots):
    """One Cycles bake of ``objects`` (proxies in a temporary scene) into (height, width, 4) pixels and the covered
    texels; ``resolution`` is the image's side or its ``(width, height)``.

    ``material_for(created, object_index, slot_index, target)`` gives a proxy slot its material, with an
    Image Texture node holding ``target`` active; it is called once per value of ``material_key(object_index,
    slot_index)``, and the slots with equal keys share that material (objects sharing a material would otherwise
    each hold a copy of its images, and Cycles a texture of each copy). ``bake_type`` "EMIT", or "NORMAL"
    (tangent space: the proxies' active UV map, whose tangents Blender uses, is the target map; the render UV map,
    which image nodes without coordinates read, is ``source_uv``).
    """
    with temporary_ids() as created:
        width, height = target_size(resolution)
        target = bpy.data.images.new("perceptual_uv_bake_target", width, height, alpha=False, float_buffer=True)
        created.append(target)
        target.colorspace_settings.name = "Non-Color"
        scene = bpy.data.scenes.new("perceptual_uv_bake")
        created.append(scene)
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = 1
        view_layer = scene.view_layers[0]
        proxies, materials = [], {}
        for object_index, obj in enumerate(objects):
            mesh = obj.data.copy()
            created.append(mesh)
            proxy = bpy.data.objects.new("perceptual_uv_bake", mesh)
            created.append(proxy)
            proxies.append(proxy)
            proxy.matrix_world = obj.matrix_world
            scene.collection.objects.link(proxy)
            proxy.select_set(True, view_layer=view_layer)
            if not mesh.materials:
                mesh.materials.append(None)
            for slot_index in range(min(slots[object_index], len(mesh.materials))):
                key = material_key(object_index, slot_index)
                if key not in materials:
                    materials[key] = material_for(created, object_index, slot_index, target)
                mesh.materials[slot_index] = materials[key]
        view_layer.objects.active = proxies[0]
        options = dict(normal_space="TANGENT") if bake_type == "NORMAL" else {}

        def bake(uv_layer):
            with bpy.context.temp_override(scene=scene, view_layer=view_layer, active_object=proxies[0],
                                           object=proxies[0], selected_objects=proxies,
                                           selected_editable_objects=proxies):
                bpy.ops.object.bake(type=bake_type, uv_layer=uv_layer, margin=0, use_clear=False,
                                    target="IMAGE_TEXTURES", **options)
            pixels = np.empty(width * height * 4, dtype=np.float32)
            target.pixels.foreach_get(pixels)
            return pixels.reshape(height, width, 4)

        return _bake_tiles(bake, target, [proxy.data for proxy in proxies], source_uv=source_uv,
                           target_uv=target_uv, tiles=tiles, tangent_from_target=bake_type == "NORMAL")


_TILE_UV = "perceptual_uv_bake_tile"
# Texels the bake does not write keep what was there before (use_clear=False); Cycles writes alpha 1, so an
# alpha of -1 marks "not covered by this tile".

_UNWRITTEN = -1.0


def _bake_tiles(bake, target, meshes, *, source_uv, target_uv, tiles, tangent_from_target=False):
    """Bake each tile of ``target_uv`` shifted into the unit square and composite the tiles (see :func:`bake_pass`).

    Returns the (height, width, 4) pixels, black and opaque where no tile wrote, and the (height, width) texels
    written.
    Coverage comes from Cycles itself (texels still holding the sentinel after a bake were not written) rather
    than from rasterising the triangles again in numpy: it is exactly the set of texels Cycles considers inside,
    whatever its rule for centres on an edge, and it works for any polygon Cycles triangulates.
    """
    bases = []
    for mesh in meshes:
        base = np.empty(2 * len(mesh.loops))
        mesh.uv_layers[target_uv].uv.foreach_get("vector", base)
        bases.append(base.reshape(-1, 2))
        # A layer of its own, so shifting it never moves the source lookup (source_uv may be target_uv); the
        # other layers of the copy are unused, and removing them keeps room under Blender's 8 UV maps.
        for name in [layer.name for layer in mesh.uv_layers if layer.name != source_uv]:
            mesh.uv_layers.remove(mesh.uv_layers[name])
        mesh.uv_layers.new(name=_TILE_UV)
        # Image nodes of a material copy without coordinates read the render UV map: the source map.
        mesh.uv_layers[source_uv].active_render = True
        if tangent_from_target:
            # Tangents (MikkTSpace) of the shifted target map are those of the target map: a shift keeps them.
            mesh.uv_layers.active = mesh.uv_layers[_TILE_UV]
    width, height = target.size
    pixels = np.zeros((height, width, 4), dtype=np.float32)
    pixels[..., 3] = 1.0  # what use_clear leaves outside the islands and the margin
    covered = np.zeros((height, width), dtype=bool)
    sentinel = np.full(width * height * 4, _UNWRITTEN, dtype=np.float32)
    for tile in tiles:
        for mesh, base in zip(meshes, bases):
            mesh.uv_layers[_TILE_UV].uv.foreach_set("vector", (base - tile).ravel())
        target.pixels.foreach_set(sentinel)
        baked = bake(_TILE_UV)
        # Tile (0, 0) comes first and keeps its texels; the other tiles only fill texels it left uncovered.
        new = (baked[..., 3] != _UNWRITTEN) & ~covered
        pixels[new] = baked[new]
        covered |= new
    return pixels, covered


def footprints(objects, covered, *, target_uv):
    """Per object, the texels next to its triangles that Cycles left empty (:func:`core.footprint.footprint_texels`
    over all objects' triangles on ``target_uv``, each texel given to the object of its nearest triangle).

    Returns
    -------
    list of tuple
        Per object ``(mesh, rows, columns, face, bary)``: its :class:`.mesh_io.MeshArrays` read on ``target_uv``;
        (p,) int64 rows and columns of its texels; (p,) int64 indices of their nearest triangles in ``mesh``;
        (p, 3) float64 barycentric coordinates of those triangles' points nearest to the texel centres.
    """
    meshes = [read_mesh(obj, uv_name=target_uv) for obj in objects]
    rows, columns, face, bary = footprint_texels(np.concatenate([mesh.uv for mesh in meshes]), covered)
    found, start = [], 0
    for mesh in meshes:
        mine = (face >= start) & (face < start + len(mesh.F))
        found.append((mesh, rows[mine], columns[mine], face[mine] - start, bary[mine]))
        start += len(mesh.F)
    return found


def extend_margin(pixels, covered, margin):
    """A margin like Cycles' EXTEND: uncovered texels within ``margin`` of a covered one take its value (in place).

    Distances wrap around the image borders: an island reaching an edge here continues on the other side under
    REPEAT, and bilinear lookups across the edge read the margin there (a margin stopping at the edges shows as
    dark pixels along islands that reach them).
    """
    if margin <= 0 or not covered.any() or covered.all():
        return
    height, width = covered.shape
    padded = np.pad(~covered, margin, mode="wrap")
    distance, (rows, columns) = scipy.ndimage.distance_transform_edt(padded, return_indices=True)
    inner = (slice(margin, margin + height), slice(margin, margin + width))
    rows = (rows[inner] - margin) % height
    columns = (columns[inner] - margin) % width
    fill = ~covered & (distance[inner] <= margin)
    pixels[fill] = pixels[rows[fill], columns[fill]]
