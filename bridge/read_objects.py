# SPDX-License-Identifier: GPL-3.0-or-later
"""The pipeline's read stage: which objects and which image a run takes, why an object cannot be optimized, and
reading and checking the mesh and the texture one step at a time (:func:`.pipeline.optimize_objects` drives it).
"""
import contextlib

import bpy
import numpy as np

from ..core.progress import InThread, report_while_waiting
from .image_file import image_channels, image_size, iter_read_image
from .material import loss_image_nodes

__all__ = ["READ_STEPS", "STAGE_MODULES", "target_problem", "source_image", "notes_for_objects", "one_object_per_mesh",
           "iter_import_stages", "iter_read_objects"]


def target_problem(obj):
    """Why ``obj`` cannot be optimized (a sentence for the user), or None when it can."""
    if obj is None or obj.type != "MESH":
        return "Select a mesh object"
    if obj.data.library is not None or obj.library is not None:
        block = obj.data if obj.data.library is not None else obj
        return (f"'{block.name}' is linked from the library '{block.library.filepath}' and cannot be changed: make it "
                "local first (Object > Relations > Make Local)")
    if not obj.data.uv_layers:
        mesh = "" if obj.data.name == obj.name else f" (mesh '{obj.data.name}')"
        return f"Object '{obj.name}'{mesh} has no UV map: unwrap it first"
    if not any(loss_image_nodes(slot.material for slot in obj.material_slots)):
        return (f"Object '{obj.name}' has no material that reads an image texture through a UV map: there is no "
                "texture to optimize for")
    return None


def source_image(objects):
    """The one image that frames a run on ``objects`` (:func:`.material.loss_image_nodes`: their base colour's,
    or when none has one their largest map's), or a ValueError that says which images were found where."""
    slot_materials = [(obj, index, slot.material) for obj in objects for index, slot in enumerate(obj.material_slots)]
    per_object = {}
    for (obj, index, _), node in zip(slot_materials, loss_image_nodes(material for _, _, material in slot_materials)):
        if node is not None:
            per_object.setdefault(obj.name, {}).setdefault(node.image, []).append(index)
    images = {image for slots in per_object.values() for image in slots}
    for name, slots in per_object.items():
        if len(slots) > 1:
            listing = "; ".join(f"'{image.name}' on slot{'s' if len(indices) > 1 else ''} "
                                f"{', '.join(str(i + 1) for i in indices)}"
                                for image, indices in sorted(slots.items(), key=lambda item: item[0].name))
            raise ValueError(f"object '{name}' uses {len(slots)} different images as its texture ({listing}); "
                             "one run optimizes one texture: separate the object by material (Edit Mode, Mesh > "
                             "Separate > By Material) and optimize the part with the texture you want")
    if not images:
        raise ValueError("none of the objects' materials reads an image texture through a UV map: there is no "
                         "texture to optimize for")
    if len(images) > 1:
        names = ", ".join(sorted(image.name for image in images))
        raise ValueError(f"the objects use {len(images)} different textures ({names}); optimize objects that "
                         "share one texture together, or each material's objects separately")
    (image,) = images
    if image.source == "TILED":
        raise ValueError(f"image '{image.name}' is a UDIM tiled image; only single images are supported (bake the "
                         "tiles into one image first)")
    if image.source in {"SEQUENCE", "MOVIE"}:
        raise ValueError(f"image '{image.name}' is an image sequence or movie; use a single still image")
    if 0 in image_size(image):
        where = bpy.path.abspath(image.filepath) if image.filepath else "(no file path)"
        raise ValueError(f"image '{image.name}' has no pixels: its file {where} is missing or unreadable; "
                         "fix the path (Image > Replace) or pack the image")
    return image


def notes_for_objects(objects):
    """What the user should know about the objects themselves (modifiers: the base mesh is optimized)."""
    notes = []
    for obj in objects:
        if obj.modifiers:
            names = ", ".join(f"{modifier.name} ({modifier.type.lower()})" for modifier in obj.modifiers)
            notes.append(f"object '{obj.name}' has modifiers ({names}): its base mesh is optimized, the modifiers "
                         "still apply on top of the new UV map")
    return notes


def one_object_per_mesh(objects):
    """Objects that share mesh data (linked duplicates) are optimized once, through the first of them."""
    kept, notes, first = [], [], {}
    for obj in objects:
        if obj.data in first:
            notes.append(f"object '{obj.name}' shares mesh '{obj.data.name}' with '{first[obj.data].name}': the mesh "
                         f"is optimized once and gets one new UV map; only '{first[obj.data].name}' gets the "
                         "material copy")
            continue
        first[obj.data] = obj
        kept.append(obj)
    return kept, notes

# The parts of the "read" stage, each one step of the pipeline generator.
READ_STEPS = 6
# The stages' modules (relative to this package): their first import in a session loads scipy and numba (about a
# second).
STAGE_MODULES = ("..core.chartfit", "..core.loss", "..core.loss_passes", "..core.result_cache", "..core.ssp",
                  "..core.trianglewise", ".bake")


def iter_import_stages(step):
    """Import :data:`STAGE_MODULES` and load the kernels a run executes here (:func:`..core.warm_up.load_kernels`,
    which compiles them after an install or update) in a thread, yielding ``step("read", 0, ...)`` every 0.1 s
    until it is done (nothing when they are imported already). A module whose import fails is left to the
    pipeline's own import, which raises the error. (Importing ``.bake`` runs no bpy call: its module code only
    defines.)"""
    import importlib
    import importlib.util
    import sys

    names = [importlib.util.resolve_name(name, __package__) for name in STAGE_MODULES]
    if all(name in sys.modules for name in names):
        return

    def load():
        for name in names:
            with contextlib.suppress(Exception):
                importlib.import_module(name)
        with contextlib.suppress(Exception):
            importlib.import_module("..core.warm_up", __package__).load_kernels()

    for _ in InThread(load).wait():
        yield step("read", 0, READ_STEPS, "Loading the optimizer")


def iter_read_objects(objects, source_uv, settings, step):
    """Read, then validate, one part per step: yields ``step("read", ...)`` before each part and returns the
    image block, the validated input (mesh, texture for the loss, what to skip) and notes.

    An 8-bit PNG or JPEG is sized from its file's header and decoded in a thread (:mod:`.image_file`): Blender
    does not load it here. Any other image's load is a single bpy call, one step however large the image is.
    """
    from ..core.mesh import concatenate_meshes
    from ..core.validate import check_memory_budget, validate_inputs
    from .mesh_io import image_triangle_mask, read_mesh

    per_object = [read_mesh(obj, uv_name=source_uv) for obj in objects]
    mesh = concatenate_meshes(per_object)
    yield step("read", 1, READ_STEPS, "Loading the texture")
    image = source_image(objects)
    width, height = image_size(image)
    what = ", ".join(f"'{obj.name}'" for obj in objects)
    # Refused before the pixels are read when the run would not fit.
    check_memory_budget(mesh.n_vertices, mesh.n_faces, (height, width, image_channels(image)), workers=settings.workers,
                        screen_pixels=settings.max_screen_pixels, what=what)
    uses_image = np.concatenate([image_triangle_mask(obj, arrays, image) for obj, arrays in zip(objects, per_object)])
    reading = step("read", 2, READ_STEPS, "Reading the texture's pixels")
    yield reading
    pixels = yield from report_while_waiting(iter_read_image(image), reading)
    yield step("read", 3, READ_STEPS, "Checking the mesh and texture")
    validated = validate_inputs(mesh, pixels, shows_texture=uses_image, workers=settings.workers,
                                screen_pixels=settings.max_screen_pixels, uv_name=source_uv, image_name=image.name)
    return image, validated, notes_for_objects(objects) + list(validated.notes)
