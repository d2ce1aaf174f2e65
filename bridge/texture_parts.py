# SPDX-License-Identifier: GPL-3.0-or-later
"""Objects whose material slots show several textures: one temporary part per texture for the runs, and the
runs' results moved back onto the object.

A run gives the objects it optimizes one new UV map laid out for one image, and reads, writes and bakes whole
meshes. An object whose slots show several textures (a character's body, head and clothes in one mesh) is
therefore split for the runs: :func:`split_by_texture` makes one temporary object per texture, a copy of the
object with only the faces of the slots that show it and only those slots, remembering which corner, face and slot
of the object each of its corners, faces and slots is. After the runs, :func:`merge_parts` writes each part's new
UV map into one new UV map of the object (the corners of faces that show no texture keep the source UV map's
coordinates), gives the object's slots the parts' material copies, fills the loss overlay per face and corner,
and removes the parts. The object's mesh ends as a single run leaves one: its own data untouched, plus the new UV
map and the overlay.

A slot's texture is what frames a run on its material alone (:func:`.material.loss_image_nodes`): the base
colour's image, else the material's largest map.
"""
import contextlib
import dataclasses

import bmesh
import bpy
import numpy as np

from ..core.progress import report_while_waiting, run_generator
from .loss_overlay import LOSS_ATTRIBUTE, write_polygon_losses
from .material import loss_image_nodes
from .pipeline import Progress

__all__ = ["TexturePart", "slot_textures", "split_by_texture", "iter_split_by_texture", "merge_parts",
           "remove_parts"]

_CORNER = "perceptual_uv_part_corner"
_FACE = "perceptual_uv_part_face"


@dataclasses.dataclass
class TexturePart:
    """One texture's faces of an object, as a temporary object of their own."""

    part: "bpy.types.Object"
    original: "bpy.types.Object"
    image: "bpy.types.Image"
    slots: np.ndarray    # (s,) the object's slot of each of the part's slots
    corners: np.ndarray  # (c,) the object's corner (loop) of each of the part's corners
    faces: np.ndarray    # (f,) the object's face (polygon) of each of the part's faces


def slot_textures(obj):
    """The texture each of ``obj``'s material slots shows (:func:`.material.loss_image_nodes` of its material
    alone), None for a slot that shows none."""
    return [None if node is None else node.image
            for node in (loss_image_nodes([slot.material])[0] for slot in obj.material_slots)]


def split_by_texture(obj):
    """One temporary part per texture ``obj``'s faces show, or [] when they show one texture or none (a slot no
    face uses does not count).

    Each part is a copy of the object (modifiers, transform and parent included) linked to the scene, whose mesh
    keeps the faces of the slots that show its texture and those slots alone (their materials on the mesh, in
    the object's order). Faces whose slot shows no texture are in no part.

    Returns
    -------
    list of TexturePart
        In the order of the textures' first slots.

    See Also
    --------
    iter_split_by_texture : the same, one part per step.
    """
    return run_generator(iter_split_by_texture(obj))


def iter_split_by_texture(obj):
    """Generator: :func:`split_by_texture`, yielding a :class:`.pipeline.Progress` of the ``read`` stage a few
    times while it makes each part (a part copies the whole mesh: about 3 microseconds per face of the object on
    this project's machine, in four steps of at most a third of it) and once after it.

    Returns
    -------
    list of TexturePart
        As :func:`split_by_texture`; closing the generator removes the parts made so far.
    """
    textures = slot_textures(obj)
    mesh = obj.data
    if len(textures) < 2 or not len(mesh.polygons):
        return []
    material_index = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("material_index", material_index)
    material_index = np.clip(material_index, 0, len(textures) - 1)  # Blender clamps to the last slot
    used = np.unique(material_index)
    images = list(dict.fromkeys(textures[index] for index in used if textures[index] is not None))
    if len(images) < 2:
        return []
    # The parts shade as the object does at every corner they keep (the tangent-space normal maps are baked in
    # their frame): without faces beyond a texture border, the smooth normals there would lean away.
    normals = np.empty((len(mesh.loops), 3), dtype=np.float32)
    mesh.corner_normals.foreach_get("vector", normals.ravel())
    parts = []

    def progress():
        done = f"{len(parts)}/{len(images)}"
        return Progress("read", len(parts), len(images), f"Splitting '{obj.name}' by texture: {done}")

    try:
        for image in images:
            slots = np.array([index for index in used if textures[index] == image])
            making = _iter_part(obj, image, slots, ~np.isin(material_index, slots), normals)
            try:
                parts.append((yield from report_while_waiting(making, progress())))
            finally:
                making.close()  # removes what a part cut off made; nothing once it has returned
            yield progress()
    except BaseException:
        remove_parts(parts)
        raise
    return parts


def _iter_part(obj, image, slots, drop, normals):
    """Generator: one part (:class:`TexturePart`), yielding None between the steps that copy the mesh, read it into
    a BMesh, drop the other textures' faces, and set the part's normals, slots and object. Closing it removes what
    it made."""
    mesh = obj.data.copy()
    try:
        mesh.name = f"{obj.data.name}.{image.name}.part"
        mesh.attributes.new(_CORNER, "INT", "CORNER").data.foreach_set("value", np.arange(len(mesh.loops)))
        mesh.attributes.new(_FACE, "INT", "FACE").data.foreach_set("value", np.arange(len(mesh.polygons)))
        materials = [obj.material_slots[int(index)].material for index in slots]
        yield
        bm = bmesh.new()
        try:
            bm.from_mesh(mesh)
            yield
            bm.faces.ensure_lookup_table()
            bmesh.ops.delete(bm, geom=[bm.faces[int(index)] for index in np.flatnonzero(drop)], context="FACES")
            bm.to_mesh(mesh)
        finally:
            bm.free()
        yield
        corners = _take_attribute(mesh, _CORNER, len(mesh.loops))
        faces = _take_attribute(mesh, _FACE, len(mesh.polygons))
        mesh.normals_split_custom_set(normals[corners])
        old_index = np.empty(len(mesh.polygons), dtype=np.int32)
        mesh.polygons.foreach_get("material_index", old_index)
        old_index = np.clip(old_index, 0, len(obj.material_slots) - 1)  # as the faces were chosen
        new_index = np.zeros(len(obj.material_slots), dtype=np.int32)
        new_index[slots] = np.arange(len(slots))
        mesh.materials.clear()
        for material in materials:
            mesh.materials.append(material)
        mesh.polygons.foreach_set("material_index", new_index[old_index])
        part = obj.copy()
        part.data = mesh
        part.name = f"{obj.name}.{image.name}.part"
        for slot in part.material_slots:
            slot.link = "DATA"
        bpy.context.scene.collection.objects.link(part)
    except BaseException:
        bpy.data.meshes.remove(mesh)
        raise
    return TexturePart(part=part, original=obj, image=image, slots=slots, corners=corners, faces=faces)


def _take_attribute(mesh, name, count):
    values = np.empty(count, dtype=np.int32)
    mesh.attributes[name].data.foreach_get("value", values)
    mesh.attributes.remove(mesh.attributes[name])
    return values.astype(np.int64)


def merge_parts(parts, uv_maps, materials, *, source_uv, epsilon):
    """Move the runs' results from ``parts`` onto their objects, then remove the parts.

    Parameters
    ----------
    parts : sequence of TexturePart
        Every part of the objects, each optimized by one run.
    uv_maps : sequence of str
        The new UV map's name on each part (its run's ``uv_map``). The parts of one object are copies of one mesh,
        so their runs chose the same name; the object's new UV map gets it.
    materials : collection of bpy.types.Material
        The runs' material copies: a part slot that shows one gives the object's slot it came from that copy,
        linked to the object as a run links it.
    source_uv : str
        The UV map whose coordinates the corners of faces in no part keep.
    epsilon : float
        The loss bound, for the overlay's colours (:func:`.loss_overlay.write_polygon_losses`; faces in no part
        have loss 0).
    """
    copies = set(materials)
    by_object = {}
    for part, uv_map in zip(parts, uv_maps):
        by_object.setdefault(part.original, []).append((part, uv_map))
    for obj, object_parts in by_object.items():
        (uv_map,) = {name for _, name in object_parts}
        mesh = obj.data
        corners = np.empty(2 * len(mesh.loops), dtype=np.float32)
        mesh.uv_layers[source_uv].uv.foreach_get("vector", corners)
        uv = corners.reshape(-1, 2)
        face_loss = np.zeros(len(mesh.polygons), dtype=np.float32)
        for part, _ in object_parts:
            part_mesh = part.part.data
            values = np.empty(2 * len(part_mesh.loops), dtype=np.float32)
            part_mesh.uv_layers[uv_map].uv.foreach_get("vector", values)
            uv[part.corners] = values.reshape(-1, 2)
            if LOSS_ATTRIBUTE in part_mesh.attributes:
                losses = np.empty(len(part_mesh.polygons), dtype=np.float32)
                part_mesh.attributes[LOSS_ATTRIBUTE].data.foreach_get("value", losses)
                face_loss[part.faces] = losses
            for part_slot, slot in zip(part.part.material_slots, part.slots):
                if part_slot.material in copies:
                    target = obj.material_slots[int(slot)]
                    target.link = "OBJECT"
                    target.material = part_slot.material
        layer = mesh.uv_layers.get(uv_map) or mesh.uv_layers.new(name=uv_map, do_init=False)
        layer.uv.foreach_set("vector", uv.ravel())
        write_polygon_losses(mesh, face_loss, epsilon, [])
    remove_parts(parts)


def remove_parts(parts):
    """Remove the parts' objects and meshes (after the runs, or when a run failed)."""
    for part in parts:
        with contextlib.suppress(ReferenceError):  # removed already
            mesh = part.part.data
            bpy.data.objects.remove(part.part)
            if mesh.users == 0:
                bpy.data.meshes.remove(mesh)
