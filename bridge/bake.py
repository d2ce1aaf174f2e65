# SPDX-License-Identifier: GPL-3.0-or-later
"""Bake a material's maps from one UV map into new images on another (Cycles, CPU; DESIGN decision 6).

Colour and data maps (base colour, emissive, metallic-roughness / ORM, occlusion, object- and world-space normal
maps, any other data) are copied value for value: an Emission shader emits the stored values of the original
image (a Non-Color float copy) through the original UV map and Cycles bakes EMIT. A tangent-space normal map is
expressed in its UV map's tangent frame, which the new UV map changes: :mod:`.bake_normal` bakes it as NORMAL into
the frame of the new UV map. Both bake on :func:`.cycles_bake.bake_pass`. Which material slots read a map, and what
the others contribute, comes from :mod:`.map_reads`.

Everything happens on temporary copies in a temporary scene: the object, its mesh, materials, images and the
user's scene settings are left exactly as they were; the only thing that stays is the new image.

Texels that bilinear lookups read next to a triangle but whose centres no triangle covers (thin strips, charts
smaller than a texel) get the source value of the triangle's nearest point (:func:`_fill_footprints`), and the
margin extends from all of these (:mod:`.cycles_bake`).
"""
import contextlib
import dataclasses
import functools

import bpy
import numpy as np

from ..core.progress import InThread, report_while_waiting, run_generator
from ..core.raster import sample_bilinear
from .bake_normal import bake_tangent_normal
from .cycles_bake import bake_pass, extend_margin, footprints, target_size, touched_tiles
from .image_file import image_is_float
from .map_reads import _map_sources, _reading_records, _slot_sources, bake_kind, has_transform, transform_problem
from .mesh_io import read_image, read_mesh

__all__ = ["bake_base_color", "bake_maps", "iter_bake_maps", "bake_map_pixels", "BakeResult", "MAX_TILES"]

MAX_TILES = 64


def _raw_copy(image):
    """A float, Non-Color copy of ``image``'s stored values, so the bake reads them without a colour transform.

    Works the same for file, packed and generated images; the user's image keeps its colour space.
    """
    width, height = image.size
    if width == 0 or height == 0:
        raise ValueError(f"image '{image.name}' has no pixels (missing file '{image.filepath}'?)")
    pixels = np.empty(width * height * image.channels, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    if image.channels != 4:
        pixels = _to_rgba(pixels.reshape(-1, image.channels)).ravel()
    raw = bpy.data.images.new("perceptual_uv_bake_source", width, height, alpha=True, float_buffer=True)
    raw.colorspace_settings.name = "Non-Color"
    raw.pixels.foreach_set(pixels)
    raw.pack()  # keeps the pixels through the render's image reload
    return raw


def _to_rgba(pixels):
    rgba = np.ones((len(pixels), 4), dtype=np.float32)
    rgba[:, :3] = pixels[:, :3] if pixels.shape[1] >= 3 else pixels[:, :1]
    if pixels.shape[1] in (2, 4):
        rgba[:, 3] = pixels[:, -1]
    return rgba


def _emission_material(created, source_uv, image, constant, channel, target):
    """A material that emits ``image`` (read raw, through ``source_uv``) or ``constant``; target node active."""
    material = bpy.data.materials.new("perceptual_uv_bake")
    created.append(material)
    tree = material.node_tree
    tree.nodes.clear()
    emission = _emission_output(tree, target)
    if image is None:
        value = constant[3] if channel == "ALPHA" else constant[:3]
        emission.inputs["Color"].default_value = (value,) * 3 + (1.0,) if channel == "ALPHA" else (*value, 1.0)
    else:
        raw = _raw_copy(image)
        created.append(raw)
        uv_node = tree.nodes.new("ShaderNodeUVMap")
        uv_node.uv_map = source_uv
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image, texture.interpolation, texture.extension = raw, "Linear", "REPEAT"
        tree.links.new(uv_node.outputs["UV"], texture.inputs["Vector"])
        tree.links.new(texture.outputs["Alpha" if channel == "ALPHA" else "Color"], emission.inputs["Color"])
    return material


def _emission_key(image, constant):
    """What an emission material of :func:`_emission_material` depends on within one bake pass (the image, or the
    constant where there is none): slots with the same key share the material and its raw copy of the image."""
    return ("image", image.as_pointer()) if image is not None else ("constant", tuple(constant))


def _emission_output(tree, target):
    """An Emission shader feeding a new active Material Output, and an active Image Texture node holding the bake
    target ``target``; returns the Emission node (what it emits is the caller's)."""
    emission = tree.nodes.new("ShaderNodeEmission")
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    output.is_active_output = True
    tree.links.new(emission.outputs["Emission"], output.inputs["Surface"])
    target_node = tree.nodes.new("ShaderNodeTexImage")
    target_node.image = target
    tree.nodes.active = target_node
    return emission


def _has_alpha(image):
    if image.channels < 4 or image.alpha_mode == "NONE":
        return False
    pixels = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(pixels)
    return bool(pixels[3::4].min() < 1.0)


def _bake_channel(objects, *, source_uv, target_uv, resolution, margin, channel, tiles=((0, 0),), sources=None):
    """Bake one channel group ("COLOR" or "ALPHA") of ``objects`` into a float (r, r, 4) array.

    ``sources`` gives, per object and material slot, (image or None, constant RGBA) to emit; by default each
    slot's base-colour image. ``tiles`` lists the integer UV tiles of ``target_uv`` to bake, tile (0, 0) first
    when present. Cycles writes the covered texels; the texels bilinear lookups read next to a triangle get the
    source colour of the triangle's nearest point (:func:`_fill_footprints`), and the margin extends from both
    (:func:`.cycles_bake.extend_margin`).
    """
    if sources is None:
        sources = [_slot_sources(obj) for obj in objects]

    def material_for(created, object_index, slot_index, target):
        image, constant = sources[object_index][slot_index]
        return _emission_material(created, source_uv, image, constant, channel, target)

    def material_key(object_index, slot_index):
        return _emission_key(*sources[object_index][slot_index])

    pixels, covered = bake_pass(objects, material_for, material_key, source_uv=source_uv, target_uv=target_uv,
                                resolution=resolution, tiles=tiles, bake_type="EMIT",
                                slots=[len(slot_sources) for slot_sources in sources])
    _fill_footprints(pixels, covered, objects, source_uv=source_uv, target_uv=target_uv, channel=channel,
                     sources=sources)
    extend_margin(pixels, covered, margin)
    return pixels


def _fill_footprints(pixels, covered, objects, *, source_uv, target_uv, channel, sources=None):
    """Give the texels bilinear lookups read next to a triangle, but Cycles left empty, their source colour.

    Cycles writes a texel only if its centre lies in a triangle, so a strip narrower than a texel, or a chart
    packed smaller than one, is drawn from texels nobody wrote: dark seams, or the colour of whatever chart the
    margin reached first. Each such texel takes the source value at the point of the nearest triangle closest
    to its centre (:func:`core.footprint.footprint_texels`), read as the bake reads it (bilinear, REPEAT, stored
    values; the constant Base Color for slots without an image). ``pixels`` and ``covered`` are updated.
    """
    if sources is None:
        sources = [_slot_sources(obj) for obj in objects]
    for obj, (mesh, rows, columns, local, bary), object_sources in zip(
            objects, footprints(objects, covered, target_uv=target_uv), sources):
        if not len(local):
            continue
        source = read_mesh(obj, uv_name=source_uv).uv
        points = np.einsum("pk,pkd->pd", bary, source[local])
        # Blender clamps material indices beyond the last slot to the last slot
        slot = np.clip(mesh.material_index[local], 0, len(object_sources) - 1)
        values = np.empty((len(local), 4), dtype=np.float32)
        for index in np.unique(slot):
            image, constant = object_sources[index]
            here = slot == index
            if image is None:
                values[here] = constant
            else:
                texture = read_image(image)
                texture = _to_rgba(texture.reshape(-1, texture.shape[2])).reshape(*texture.shape[:2], 4)
                values[here] = sample_bilinear(texture, points[here] * np.array(texture.shape[1::-1]))
        if channel == "ALPHA":
            values[:, :3] = values[:, 3:]
        values[:, 3] = 1.0  # as Cycles writes
        pixels[rows, columns] = values
        covered[rows, columns] = True


def bake_base_color(objects, *, source_uv, target_uv, resolution, margin, image_name):
    """Bake the base-colour texture(s) of ``objects`` through ``source_uv`` into one new image on ``target_uv``.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects whose material slots feed their Base Color from image textures (slots without an image
        bake their constant Base Color); several objects share the new image (an atlas).
    source_uv, target_uv : str
        Names of the UV maps the original texture is read through and the new one is written on.
    resolution : int or (int, int)
        Side of the new image, or its ``(width, height)``.
    margin : int
        Bake margin in pixels (extended from the island borders).
    image_name : str
        Name of the new image data block (Blender makes it unique).

    Returns
    -------
    bpy.types.Image
        A new image whose stored values are the bilinear samples of the source's stored values, clipped to
        [0, 1]: 8-bit sRGB for 8-bit sources, float (linear) when a source is a float image (16-bit PNG,
        EXR), so the colours mean the same; alpha is baked too when a source image uses it. Where
        ``target_uv`` leaves [0, 1]^2 the image is meant to be sampled with REPEAT: each integer tile the map
        touches is baked into the image (one Cycles bake per tile), texels of tile (0, 0) winning where tiles
        overlap. Texels that bilinear lookups read next to a triangle but that no triangle covers hold the
        source value at the triangle's nearest point, and the margin extends from all these texels, across the
        image edges.

    Raises
    ------
    ValueError
        A missing UV map, a non-mesh object, or a target map spanning more than :data:`MAX_TILES` tiles.
    """
    objects = list(objects)
    tiles = _check_objects(objects, source_uv, target_uv, resolution)
    common = dict(source_uv=source_uv, target_uv=target_uv, resolution=resolution, margin=margin, tiles=tiles)
    pixels = _bake_channel(objects, channel="COLOR", **common)
    sources = [image for obj in objects for image, _ in _slot_sources(obj) if image is not None]
    use_alpha = any(_has_alpha(image) for image in sources)
    if use_alpha:
        pixels[..., 3] = _bake_channel(objects, channel="ALPHA", **common)[..., 0]
    else:
        pixels[..., 3] = 1.0
    # Float sources (16-bit PNG, EXR) hold linear values in ``pixels``; a byte image would read those numbers as
    # sRGB and darken them, so the result is a float image too (saved as a 16-bit PNG).
    use_float = any(image.is_float for image in sources)
    image = bpy.data.images.new(image_name, *target_size(resolution), alpha=use_alpha, float_buffer=use_float)
    image.pixels.foreach_set(_clip_to_unit(pixels).ravel())
    image.update()
    return image


# ---- every map of a material -----------------------------------------------------------------------------------

@dataclasses.dataclass
class BakeResult:
    """One baked map: the new ``image``, the source map ``record`` it replaces, and how it was baked.

    Attributes
    ----------
    image : bpy.types.Image
    record : perceptual_uv.bridge.material_roles.MaterialMap
    kind : str
        ``"emit"`` or ``"normal"`` (:func:`bake_kind`).
    alpha : bool
        True when the alpha channel was baked too (the source uses alpha).
    """

    image: object
    record: object
    kind: str
    alpha: bool


def _transformed_emission(created, material, node_name, channel, target):
    """A copy of ``material`` that emits what its Image Texture node ``node_name`` reads (stored values, through
    the node's own coordinates, texture transform included); the target node active."""
    copy = material.copy()
    created.append(copy)
    tree = copy.node_tree
    node = tree.nodes[node_name]
    raw = _raw_copy(node.image)
    created.append(raw)
    node.image = raw
    for output in [output for output in tree.nodes if output.type == "OUTPUT_MATERIAL"]:
        tree.nodes.remove(output)
    emission = _emission_output(tree, target)
    tree.links.new(node.outputs["Alpha" if channel == "ALPHA" else "Color"], emission.inputs["Color"])
    return copy


def _bake_transformed(objects, record, sources, *, source_uv, target_uv, resolution, margin, channel, tiles):
    """:func:`_bake_channel` for a map read through a texture transform: each slot that reads it emits through a
    copy of its material's own node and coordinates. The texels next to a triangle that Cycles leaves empty are
    covered by the margin (the footprint fill reads untransformed coordinates)."""
    per_slot = [_reading_records(obj, record, source_uv) for obj in objects]

    def material_for(created, object_index, slot_index, target):
        own = per_slot[object_index][slot_index]
        if own is None:
            image, constant = sources[object_index][slot_index]
            return _emission_material(created, source_uv, image, constant, channel, target)
        material = objects[object_index].material_slots[slot_index].material
        return _transformed_emission(created, material, own.nodes[0].name, channel, target)

    def material_key(object_index, slot_index):
        own = per_slot[object_index][slot_index]
        if own is None:
            return _emission_key(*sources[object_index][slot_index])
        material = objects[object_index].material_slots[slot_index].material
        return "node", material.as_pointer(), own.nodes[0].name

    pixels, covered = bake_pass(objects, material_for, material_key, source_uv=source_uv, target_uv=target_uv,
                                resolution=resolution, tiles=tiles, bake_type="EMIT",
                                slots=[len(slot_records) for slot_records in per_slot])
    extend_margin(pixels, covered, margin)
    return pixels


def _check_objects(objects, source_uv, target_uv, resolution):
    for obj in objects:
        if obj.type != "MESH":
            raise ValueError(f"'{obj.name}' is not a mesh")
        for name in (source_uv, target_uv):
            if name not in obj.data.uv_layers:
                raise ValueError(f"'{obj.name}' has no UV map '{name}'")
    tiles = touched_tiles(objects, target_uv, resolution)
    if len(tiles) > MAX_TILES:
        raise ValueError(f"UV map '{target_uv}' spans {len(tiles)} texture tiles (at most {MAX_TILES} are baked, one "
                         f"Cycles bake each): bake onto a UV map inside [0, 1], e.g. a packed copy")
    return tiles


def _clip_to_unit(pixels):
    """``pixels`` clipped to [0, 1] in place (numpy lets other threads run meanwhile)."""
    return np.clip(pixels, 0.0, 1.0, out=pixels)


def _new_image(name, pixels, *, alpha, use_float, like=None):
    """A new image holding ``pixels`` (height, width, 4), already in [0, 1] (:func:`_clip_to_unit`); the colour space
    follows ``like`` (a source image).

    The colour space is set before the pixels: setting it afterwards reloads a generated image's buffer.
    """
    height, width = pixels.shape[:2]
    image = bpy.data.images.new(name, width, height, alpha=alpha, float_buffer=use_float)
    if like is not None and like.colorspace_settings.is_data:
        image.colorspace_settings.name = "Non-Color"
    elif like is not None and not use_float:
        with contextlib.suppress(TypeError):
            image.colorspace_settings.name = like.colorspace_settings.name
    image.pixels.foreach_set(pixels.ravel())
    image.update()
    return image


def bake_maps(objects, maps, *, source_uv, target_uv, resolutions, margin, names):
    """Bake every map in ``maps`` from ``source_uv`` into a new image on ``target_uv``.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects whose materials read the maps (several objects share each new image: an atlas).
    maps : sequence of perceptual_uv.bridge.material_roles.MaterialMap
        One record per new image (``bridge.material.read_object_materials``); every slot whose material reads
        the record's image the same way (tangent-space normal map, or not) contributes to that image. Slots that
        do not read it bake a neutral value (their constant Base Color for a base-colour map, white for alpha and
        occlusion, flat for normal maps, black otherwise).
    source_uv, target_uv : str
        The UV map the maps are read through, and the one the new images are written on.
    resolutions : sequence of int or (int, int)
        Side of each new (square) image, or its ``(width, height)``.
    margin : int or sequence of int
        Bake margin in pixels of each new image (extended from the island borders, across the image edges).
    names : sequence of str
        Name of each new image (Blender makes names unique).

    Returns
    -------
    list of BakeResult
        In the order of ``maps``. Colour and data maps (``kind`` "emit"): the bilinear samples of the source's
        stored values (read Non-Color, without a colour transform), clipped to [0, 1]; 8-bit for 8-bit sources
        (a re-bake on the same layout is exact within one 8-bit step per channel), float for 16-bit and float
        sources, in the source's colour space; alpha baked when the source uses it; a packed
        occlusion-roughness-metallic image stays one image with all its channels. Tangent-space normal maps
        (``kind`` "normal"): Cycles' NORMAL bake in tangent space (+X, +Y, +Z) of the shading normal of a
        temporary copy of the original material (its Normal Map node reads the tangents of ``source_uv``), in
        the MikkTSpace frame of ``target_uv``, the texels next to triangles that Cycles leaves empty converted
        from the source into that frame (:func:`.bake_normal.bake_tangent_normal`); Non-Color, 8-bit or float as
        the source.

    Raises
    ------
    ValueError
        A missing UV map, a non-mesh object, a target map spanning more than :data:`MAX_TILES` tiles, or lengths
        that do not match.
    """
    return run_generator(iter_bake_maps(objects, maps, source_uv=source_uv, target_uv=target_uv,
                                        resolutions=resolutions, margin=margin, names=names))


def iter_bake_maps(objects, maps, *, source_uv, target_uv, resolutions, margin, names, in_background=False):
    """Generator form of :func:`bake_maps`: yields ``(done, total)`` maps, returns the list of BakeResult.

    In this process each map's Cycles bake is one uninterrupted call (about a second for a 1-2k map), so the
    generator yields once per map. With ``in_background`` the bakes run in a background Blender process
    (:mod:`.bake_process`) on a copy of the objects, and the generator yields every 0.1 s while it works; the
    pixels are the same, and the new images are made here from them exactly as in this process. Closing the
    generator stops the background process. On an error or a close, the images made so far are removed again.
    """
    objects, maps = list(objects), list(maps)
    resolutions, names = [target_size(resolution) for resolution in resolutions], list(names)
    margins = [int(value) for value in margin] if np.ndim(margin) else [int(margin)] * len(maps)
    if not len(maps) == len(resolutions) == len(names) == len(margins):
        raise ValueError(f"{len(maps)} maps need as many resolutions, names and margins (got {len(resolutions)}, "
                         f"{len(names)}, {len(margins)})")
    for resolution in dict.fromkeys(resolutions):  # refused before anything is baked or a process started
        _check_objects(objects, source_uv, target_uv, resolution)
    total, results = len(maps), []
    try:
        if in_background:
            from .bake_process import iter_bake_in_background

            baked = yield from iter_bake_in_background(objects, maps, source_uv=source_uv, target_uv=target_uv,
                                                       resolutions=resolutions, margins=margins)
        else:
            baked = None
        for number, (record, resolution, name, map_margin) in enumerate(zip(maps, resolutions, names, margins)):
            progress = (number if baked is None else total), total  # from the child: every map is baked already
            yield progress
            if baked is None:
                pixels, use_alpha = bake_map_pixels(objects, record, source_uv=source_uv, target_uv=target_uv,
                                                    resolution=resolution, margin=map_margin)
            else:
                pixels, use_alpha = baked[number]
                baked[number] = None  # the image holds the pixels from here on
            # Clipping a 2-4k map reads and writes tens of megabytes: a thread does it while the stage yields.
            pixels = yield from report_while_waiting(InThread(_clip_to_unit, pixels).wait(), progress)
            image = _new_image(name, pixels, alpha=use_alpha, use_float=image_is_float(record.image),
                               like=record.image)
            results.append(BakeResult(image=image, record=record, kind=bake_kind(record), alpha=use_alpha))
    except BaseException:
        for result in results:
            with contextlib.suppress(ReferenceError):
                bpy.data.images.remove(result.image)
        raise
    return results


def bake_map_pixels(objects, record, *, source_uv, target_uv, resolution, margin):
    """The pixels of one map of :func:`bake_maps`, before they become an image (see there).

    Returns
    -------
    pixels : (height, width, 4) ndarray of float32
        Not yet clipped to [0, 1].
    use_alpha : bool
        True when the alpha channel was baked (the source uses alpha); otherwise alpha is 1.
    """
    tiles = _check_objects(objects, source_uv, target_uv, resolution)
    common = dict(source_uv=source_uv, target_uv=target_uv, resolution=resolution, margin=int(margin), tiles=tiles)
    if bake_kind(record) == "normal":
        return bake_tangent_normal(objects, record, **common), False
    sources = _map_sources(objects, record, source_uv)
    if has_transform(record):
        problem = transform_problem(record)
        if problem:
            raise ValueError(f"map '{record.image.name}' cannot be baked: {problem}")
        bake = functools.partial(_bake_transformed, objects, record, sources, **common)
    else:
        bake = functools.partial(_bake_channel, objects, sources=sources, **common)
    pixels = bake(channel="COLOR")
    use_alpha = _has_alpha(record.image)
    if use_alpha:
        pixels[..., 3] = bake(channel="ALPHA")[..., 0]
    else:
        pixels[..., 3] = 1.0
    return pixels, use_alpha
