# SPDX-License-Identifier: GPL-3.0-or-later
"""The maps a run moves: which images the materials read and through which UV map, the planes the loss sees,
each new image's size, the material copies that read the new images, and the report's entry per map.

Every map of the material moves (DESIGN decision 6): each image the materials read through the source UV map
(:mod:`.material`) is re-baked onto the new UV map (:func:`.bake.bake_maps`) at the same relative cost as the
base colour (or its role's), each relative to its own input size, and the material copies read every new image
through the new UV map. A copy carries :data:`COPY_PROPERTY`, so a run on the result of an earlier one reads what
it shows.
"""
import contextlib
import os

import bpy
import numpy as np

from .image_file import image_is_float, image_size
from .material import material_maps, read_material, read_object_materials, render_uv_name

__all__ = ["COPY_PROPERTY", "MIN_RESOLUTION", "original_materials", "resolve_source_uv", "read_maps", "loss_planes_of",
           "iter_loss_planes_of", "image_side", "image_stem", "map_scale", "scaled_size",
           "memory_resolution", "copy_aspects", "slots_aspect",
           "material_copies", "map_report", "file_bytes"]

MIN_RESOLUTION = 8  # the smallest side of a new image
MAX_RESOLUTION = 16384  # the largest

COPY_PROPERTY = "perceptual_uv_source"


def _copy_slots(objects):
    """``(object, slot number, slot)`` for each slot of ``objects`` holding a material copy made by a run."""
    for obj in objects:
        for number, slot in enumerate(obj.material_slots, start=1):
            if slot.material is not None and COPY_PROPERTY in slot.material:
                yield obj, number, slot


def _copies_read(objects):
    """{UV map: [(object, slot number, copy)]} for the slots holding a material copy made by an earlier run."""
    found = {}
    for obj, number, slot in _copy_slots(objects):
        for record in material_maps(slot.material, render_uv=render_uv_name(obj.data)):
            found.setdefault(record.uv_map, []).append((obj, number, slot.material))
    return found


@contextlib.contextmanager
def original_materials(objects):
    """Within the block, every slot of ``objects`` that holds a material copy made by a run holds its original.

    After a run the slots show copies that read the new images through the new UV map; an evaluation of that UV
    map has to re-bake and compare the material the run read, not the copy. The slots get their copies back
    afterwards, whatever happens in the block.

    Raises
    ------
    ValueError
        A copy's original is no longer in the file.
    """
    swapped = []
    try:
        for obj, number, slot in list(_copy_slots(objects)):
            material = slot.material
            original = bpy.data.materials.get(material[COPY_PROPERTY])
            if original is None:
                raise ValueError(f"slot {number} of '{obj.name}' holds '{material.name}', made by an Optimize UVs run "
                                 f"from '{material[COPY_PROPERTY]}', which is no longer in the file: evaluate the file "
                                 "the run started from, with the new UV map added")
            swapped.append((slot, material))
            slot.material = original
        yield
    finally:
        for slot, material in reversed(swapped):
            slot.material = material


def copy_aspects(objects, uv_name):
    """Width over height of the image each Optimize UVs material copy in the slots of ``objects`` reads through
    ``uv_name`` (its base colour's, else its first map's), by the name of the copy's original material: the image
    shape the run that made the copy packed ``uv_name`` for (``core.packing``).

    Returns
    -------
    dict of str to float
    """
    aspects = {}
    for _, _, slot in _copy_slots(objects):
        maps = [record for record in read_material(slot.material, source_uv=uv_name).maps
                if record.image is not None and min(record.image.size) > 0]
        if maps:
            image = next((record.image for record in maps if record.role == "base_color"), maps[0].image)
            aspects.setdefault(slot.material[COPY_PROPERTY], float(image.size[0]) / float(image.size[1]))
    return aspects


def slots_aspect(objects, aspects):
    """The aspect of :func:`copy_aspects` for the first slot of ``objects`` showing one of its originals, else None
    (a UV map no run packed: the evaluation's default, ``bridge.evaluate.image_aspect``)."""
    for obj in objects:
        for slot in obj.material_slots:
            if slot.material is not None and slot.material.name in aspects:
                return aspects[slot.material.name]
    return None


def resolve_source_uv(objects, source_uv):
    """The UV map to read the maps through, for a first run or a run on the result of an earlier one.

    After a run the slots hold object-linked copies (marked with :data:`COPY_PROPERTY`) that read the new images
    through the new UV map, while the active UV map is still the old one. A second run optimizes what the
    material shows: with no ``source_uv`` given, the UV map the copies read; given another one, it is refused.
    """
    copies = _copies_read(objects)
    if not copies:
        return source_uv if source_uv is not None else objects[0].data.uv_layers.active.name
    if len(copies) > 1:
        listing = "; ".join(f"'{material.name}' on '{obj.name}' reads UV map '{uv}'"
                            for uv, users in sorted(copies.items(), key=lambda item: str(item[0]))
                            for obj, _, material in users[:1])
        raise ValueError(f"the material copies of earlier Optimize UVs runs read different UV maps ({listing}): "
                         "optimize the objects of each run separately")
    uv = next(iter(copies))
    if source_uv is None or source_uv == uv:
        return uv
    obj, number, material = copies[uv][0]
    original = material[COPY_PROPERTY]
    raise ValueError(f"slot {number} of '{obj.name}' holds '{material.name}', made by an earlier Optimize UVs run "
                     f"from '{original}': it reads its images through UV map '{uv}', not '{source_uv}'. Make "
                     f"'{uv}' the active UV map (or pass --uv {uv}) to optimize the result again, or undo the "
                     f"earlier run (or put '{original}' back in the slot) to start from the original")


def uv_maps_reading(objects, image):
    """The UV maps through which the objects' materials read ``image`` (None for coordinates that are no UV
    map's)."""
    return {record.uv_map for obj in objects for slot in obj.material_slots
            for record in material_maps(slot.material, render_uv=render_uv_name(obj.data)) if record.image == image}


def read_maps(objects, source_uv, loss_image):
    """Every map the objects' materials read through ``source_uv``: one record per new image, the loss image's
    first; notes on images left as they are. Refuses (ValueError) maps that cannot be re-baked."""
    from .map_reads import bake_kind, transform_problem

    records, notes = {}, []
    for obj in objects:
        for number, reading in enumerate(read_object_materials(obj, source_uv=source_uv), start=1):
            for record in reading.maps:
                image = record.image
                where = f"the {record.role} map '{image.name}' of material '{reading.material.name}'"
                if image.source in ("TILED", "MOVIE", "SEQUENCE"):
                    kind = {"TILED": "a UDIM tiled image", "MOVIE": "a movie", "SEQUENCE": "an image sequence"}
                    raise ValueError(f"{where} is {kind[image.source]}; only single still images can be re-baked "
                                     "(bake it into one image first)")
                if 0 in image_size(image):
                    path = bpy.path.abspath(image.filepath) if image.filepath else "(no file path)"
                    raise ValueError(f"{where} has no pixels: its file {path} is missing or unreadable; fix the path "
                                     "(Image > Replace) or pack the image")
                if (problem := transform_problem(record)) is not None:
                    raise ValueError(f"{where} cannot be re-baked: {problem}")
                others = [drives for drives in record.drives if drives != "normal_tangent"]
                if "normal_tangent" in record.drives and others:
                    # A tangent-space normal map is re-expressed in the new UV map's frame; the other uses need the
                    # values as they are: one new image cannot be both.
                    raise ValueError(f"image '{image.name}' of material '{reading.material.name}' is read both as a "
                                     f"tangent-space normal map and as {', '.join(others)}: one new image cannot hold "
                                     "both; give the normal map an image of its own")
                records.setdefault((image.as_pointer(), bake_kind(record)), record)
            for record in reading.left_as_is:
                name = reading.material.name if reading.material else "(none)"
                notes.append(f"the {record.role} map '{record.image.name}' of material '{name}' (slot {number} of "
                             f"'{obj.name}') stays as it is, not re-baked: " + "; ".join(record.notes))
    # The loss image's record (its base-colour read when the image is also read another way) comes first.
    key = min((key for key in records if key[0] == loss_image.as_pointer()), key=lambda key: key[1] != "emit",
              default=None)
    if key is None:
        read_through = sorted(map(str, uv_maps_reading(objects, loss_image)))
        where = f" (it is read through {', '.join(repr(uv) for uv in read_through)})" if read_through else ""
        usable = len(read_through) == 1 and all(read_through[0] in obj.data.uv_layers for obj in objects)
        hint = (f"pass --uv {read_through[0]} on the command line, or make '{read_through[0]}' the active UV map in "
                "Blender" if usable else "make the UV map its Image Texture node reads the active one")
        raise ValueError(f"the image '{loss_image.name}' is not read through UV map '{source_uv}'{where}: {hint}")
    ordered = [records.pop(key)] + list(records.values())
    return ordered, list(dict.fromkeys(notes))


def loss_planes_of(records, texture):
    """The planes the triangle-wise loss sees (``core.loss_planes``), one map after the other: the loss image
    (``texture``, already read) first, so its texel grid is the parameters' frame; colour maps as luma (and
    alpha), tangent-space normals as their shading, data maps per channel their material reads.

    :func:`iter_loss_planes_of` is the same as a generator that hands control back while it runs."""
    from ..core.progress import run_generator

    return run_generator(iter_loss_planes_of(records, texture))


def iter_loss_planes_of(records, texture):
    """Generator form of :func:`loss_planes_of`: yields ``(done, total)`` maps and returns the planes.

    It yields ``(0, len(records))`` while and after reading each further map's pixels
    (:func:`.image_file.iter_read_image`), then the steps of :func:`.core.loss_planes.iter_loss_planes`, a band
    of rows of a map at a time.
    """
    from ..core.loss_planes import PlaneStack, iter_loss_planes
    from ..core.progress import report_while_waiting
    from .image_file import iter_read_image

    maps = []
    for index, record in enumerate(records):
        if index:
            pixels = yield from report_while_waiting(iter_read_image(record.image), (0, len(records)))
            yield 0, len(records)
        else:
            pixels = texture
        if record.kind == "color":
            maps.append({"role": "color", "pixels": pixels, "name": record.role})
        elif record.kind == "tangent_normal":
            maps.append({"role": "normal", "pixels": pixels[..., :3], "name": record.role})
        else:
            channels = tuple("RGBA".index(c) for c in record.channels if "RGBA".index(c) < pixels.shape[-1])
            maps.append({"role": "data", "pixels": pixels, "channels": channels or None, "name": record.role})
    # The first plane stays whatever it holds: its texel grid is the parameters' frame (and the mesh-wise
    # stage's). Later planes with one value over the whole image (an opaque base colour's alpha, a flat map) are
    # left out: they cannot raise E, and with the loss image alone the single-plane path runs.
    stack = yield from iter_loss_planes(maps, drop_constant=False, clip=True)  # float maps may exceed 1
    keep = [0] + [index for index in range(1, len(stack)) if stack[index].min() < stack[index].max()]
    return PlaneStack([stack[index] for index in keep], [stack.names[index] for index in keep])


def image_side(image):
    """An image's side for sizing: ``sqrt(width * height)``, so a non-square map keeps its pixel count's share."""
    width, height = image_size(image)
    return float(np.sqrt(width * height))


def map_scale(input_side, reference_side, *, role_cost=None, reference_cost=None):
    """How many times the base colour's new side a map's new side is: the base colour's relative cost (or
    ``role_cost``), relative to its own size.

    Parameters
    ----------
    input_side, reference_side : float
        The map's and the base colour's input sides (``sqrt(width * height)``).
    role_cost, reference_cost : float, optional
        A relative cost set for the map's role, and the base colour's measured one: the scale is multiplied by
        ``sqrt(role_cost / reference_cost)``.

    Returns
    -------
    float
        ``input_side / reference_side [* sqrt(role_cost / reference_cost)]`` (:func:`scaled_size` applies it).
    """
    scale = input_side / reference_side
    if role_cost is not None and reference_cost:
        scale *= np.sqrt(role_cost / reference_cost)
    return float(scale)


def scaled_size(size, scale):
    """``(width, height)`` scaled by ``scale`` and rounded, each side in [8, 16384]: a map's new image in the shape
    of the base colour's."""
    return tuple(int(min(MAX_RESOLUTION, max(MIN_RESOLUTION, round(side * scale)))) for side in size)


def memory_resolution(input_size, cost):
    """Side of a map's new image when the cost is image memory (``OptimizeSettings.cost_measure`` "memory").

    Parameters
    ----------
    input_size : (int, int)
        The map's input image's width and height.
    cost : float
        The memory share the map gets: its role's cost, or the run's.

    Returns
    -------
    int
        ``round(sqrt(cost * width * height))`` in [8, 16384]: the new square image has ``cost`` times the input's
        pixels. Unlike the texel cost (Eq. 20-21, ``core.cost``) this does not depend on the UV maps: the charts
        are packed to fill the image.
    """
    width, height = input_size
    if not cost > 0:
        raise ValueError(f"memory cost must be positive, got {cost}")
    return int(min(MAX_RESOLUTION, max(MIN_RESOLUTION, round(np.sqrt(cost * float(width) * float(height))))))


def image_stem(image):
    """The image's name without extension and without a ``_perceptual`` an earlier run appended."""
    stem = os.path.splitext(image.name)[0]
    return stem[:-len("_perceptual")] if stem.endswith("_perceptual") else stem


def _raw_bytes(width, height, alpha, is_float):
    """Pixels x channels (3, or 4 with alpha) x bytes per channel (1, or 2 for 16-bit/float: saved as 16-bit PNG)."""
    return int(width * height * (4 if alpha else 3) * (2 if is_float else 1))


def file_bytes(image):
    """Bytes of ``image``'s packed data or file on disk; None when it has neither."""
    if image.packed_file is not None:
        return int(image.packed_file.size)
    path = bpy.path.abspath(image.filepath_raw or image.filepath) if (image.filepath_raw or image.filepath) else ""
    return int(os.path.getsize(path)) if path and os.path.isfile(path) else None


_COORDINATE_NODES = frozenset({"UVMAP", "TEX_COORD", "MAPPING", "VECT_MATH", "VECTOR_ROTATE", "SEPXYZ", "COMBXYZ",
                               "MATH", "MAP_RANGE", "CLAMP", "REROUTE", "VALUE"})


def _remove_unused_coordinates(tree, node):
    """Remove ``node`` and the coordinate nodes feeding it once nothing reads them (the new image already holds
    a texture transform the old coordinates applied)."""
    if node.type not in _COORDINATE_NODES or any(output.links for output in node.outputs):
        return
    upstream = list(dict.fromkeys(link.from_node.name for socket in node.inputs for link in socket.links))
    tree.nodes.remove(node)
    for name in upstream:
        if (source := tree.nodes.get(name)) is not None:
            _remove_unused_coordinates(tree, source)


def _repoint(node, image, uv_name):
    """Make an Image Texture node read ``image`` through a UV Map node on ``uv_name``, nothing else."""
    tree = node.id_data
    vector = node.inputs["Vector"]
    for link in list(vector.links):
        source = link.from_node
        tree.links.remove(link)
        _remove_unused_coordinates(tree, source)
    node.image = image
    uv_node = tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = uv_name
    uv_node.location = node.location[0] - 200, node.location[1]
    uv_node.parent = node.parent
    tree.links.new(uv_node.outputs["UV"], vector)


def material_copies(objects, baked, uv_name, source_uv, created):
    """Copies of the objects' materials that read every re-baked image through ``uv_name``, linked per object.

    ``baked`` maps (image pointer, bake kind) to the new image. In each copy every Image Texture node of a baked
    map reads its new image through a UV Map node on ``uv_name``, and tangent-space Normal Map nodes on the
    source UV map take their tangents from ``uv_name``: no node of the copy reads ``source_uv``. Node groups
    holding such nodes are copied with the material. Each copy carries :data:`COPY_PROPERTY`.
    """
    from .map_reads import _all_nodes, bake_kind, localize_node_groups

    copies = {}
    for obj in objects:
        render_uv = render_uv_name(obj.data)
        readings = read_object_materials(obj, source_uv=source_uv)
        for index, (slot, reading) in enumerate(zip(obj.material_slots, readings)):
            material = slot.material
            if not any((record.image.as_pointer(), bake_kind(record)) in baked for record in reading.maps):
                continue
            if material not in copies:
                copy = material.copy()
                original = material.get(COPY_PROPERTY, material.name)
                copy.name = f"{original}_perceptual"
                copy[COPY_PROPERTY] = original
                created.materials.append(copy)
                localize_node_groups(copy.node_tree, created.node_groups)
                for record in read_material(copy, source_uv=source_uv, render_uv=render_uv).maps:
                    new = baked.get((record.image.as_pointer(), bake_kind(record)))
                    if new is not None:
                        for node in record.nodes:
                            _repoint(node, new, uv_name)
                for node in _all_nodes(copy.node_tree):
                    if node.type == "NORMAL_MAP" and node.space == "TANGENT" and (
                            node.uv_map == source_uv or (not node.uv_map and render_uv == source_uv)):
                        node.uv_map = uv_name
                copies[material] = copy
            created.slot_links.append((obj, index, slot.material, slot.link))
            slot.link = "OBJECT"  # the mesh's own material list (shared with other objects) stays as it was
            slot.material = copies[material]
    return list(copies.values())


def map_report(result, path):
    """One entry of the report's "maps": role, sizes, raw and file bytes before and after."""
    source, image = result.record.image, result.image
    width, height = image_size(source)
    return {
        "role": result.record.role,
        "kind": result.kind,
        "channels": result.record.channels,
        "colorspace": result.record.colorspace,
        "image": source.name,
        "new_image": image.name,
        "new_image_file": path,
        "input_size": [int(width), int(height)],
        "new_size": [int(image.size[0]), int(image.size[1])],
        "raw_bytes_before": _raw_bytes(width, height, result.alpha, image_is_float(source)),
        "raw_bytes_after": _raw_bytes(image.size[0], image.size[1], result.alpha, image.is_float),
        "file_bytes_before": file_bytes(source),
        "file_bytes_after": file_bytes(image),
    }
