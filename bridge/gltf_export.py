# SPDX-License-Identifier: GPL-3.0-or-later
"""Write a finished run as a .glb: the whole scene of the input, with the optimized meshes on their new UV map.

What the file keeps: every object of the scene (armatures and their skins, other meshes, empties, lights and
cameras), the animations, joints and weights, shape keys, and the input's own vertex colours. On the optimized
meshes, TEXCOORD_0 is the new UV map (the only texture coordinates, but for UV maps through which a map the run
left as it is is still read, exported after it), the materials are the run's copies that
read the new image through it, and, when a material of the file has a tangent-space normal map, tangents are
exported (computed in the new UV map) so that a normal map baked in that frame shades the same in a viewer (without
one they would add 16 bytes to every vertex and shade nothing; a vertex whose triangles all have zero area in the UV
map, where MikkTSpace finds no tangent, gets a unit one orthogonal to its normal: :mod:`..core.gltf_tangents`, so
the file stays valid). The per-face loss overlay (``perceptual_loss``,
``perceptual_loss_color``) is for Blender's viewport and is not exported.

The exporter writes every UV map and colour attribute of a mesh it exports, so each optimized mesh is exported
through a temporary copy that has only the new UV map and no overlay; the objects get their own mesh back
afterwards and the copies are removed. The user's data is never changed.
"""
import contextlib

import bpy
import numpy as np

from ..core.gltf_tangents import repair_tangents
from .loss_overlay import LOSS_ATTRIBUTE, LOSS_COLOR_ATTRIBUTE
from .material import material_maps, read_material, render_uv_name
from .mesh_io import failures_in_one_line

__all__ = ["export_glb", "meshes_for_export", "EXPORT_OPTIONS"]

# Blender 5.0's glTF exporter, spelled out where its default would drop part of the input (lights, cameras,
# custom properties as extras) or where this tool needs it (tangents for normal maps baked in the new UV map, set
# per file by :func:`export_glb`).
EXPORT_OPTIONS = dict(
    export_format="GLB",
    use_selection=False,        # the whole scene, not just the optimized meshes
    use_visible=False,
    use_renderable=False,
    use_active_collection=False,
    use_active_scene=False,
    export_image_format="AUTO",  # the baked PNG stays PNG, the input's JPEGs stay JPEG
    export_texcoords=True,
    export_normals=True,
    export_tangents=True,       # export_glb keeps it only when a material has a tangent-space normal map
    export_materials="EXPORT",
    export_unused_images=False,
    export_unused_textures=False,
    export_vertex_color="MATERIAL",
    export_attributes=False,
    export_skins=True,
    export_animations=True,
    export_morph=True,
    export_lights=True,
    export_cameras=True,
    export_extras=True,
    export_apply=False,         # modifiers (the armature) stay live: skinning is exported as a skin
    export_yup=True,
    check_existing=False,
    will_save_settings=False,
)


def _optimized_meshes(objects, uv_map, materials):
    """The meshes that carry ``uv_map``, with the objects that use them and the material remapping.

    The pipeline gives the first object of each mesh an object-linked slot with the material copy; objects that
    share the mesh keep the original material on the mesh. In the export every user of the mesh gets the copy.
    """
    users, copy_of = {}, {}
    copies = set(materials)
    for obj in objects:
        if obj.type != "MESH" or uv_map not in obj.data.uv_layers:
            continue
        users.setdefault(obj.data, []).append(obj)
        for index, slot in enumerate(obj.material_slots):
            if slot.link == "OBJECT" and slot.material in copies and index < len(obj.data.materials):
                original = obj.data.materials[index]
                if original is not None:
                    copy_of[original] = slot.material
    return users, copy_of


def _has_tangent_normal_map():
    """Whether a material some mesh object of the file shows reads a tangent-space normal map."""
    shown = {slot.material for obj in bpy.data.objects if obj.type == "MESH" and obj.users_scene
             for slot in obj.material_slots if slot.material is not None}
    return any(record.role == "normal_tangent" for material in shown for record in material_maps(material))


def _uv_maps_read_as_they_are(mesh, users, uv_map, copy_of):
    """The UV maps of ``mesh`` other than ``uv_map`` through which the materials its users are exported with
    (``copy_of`` maps an original to its copy) read a map the run left as it is (an occlusion map on a second UV
    map, say), in the mesh's order."""
    render = render_uv_name(mesh)
    read = set()
    for material in {copy_of.get(slot.material, slot.material) for obj in users for slot in obj.material_slots}:
        reading = read_material(material, source_uv=uv_map, render_uv=render)
        read.update(record.uv_map for record in reading.left_as_is if record.uv_map is not None)
    return [layer.name for layer in mesh.uv_layers if layer.name in read and layer.name != uv_map]


def _export_mesh(mesh, uv_map, copy_of, keep=()):
    """A copy of ``mesh`` with ``uv_map`` as its first UV map (TEXCOORD_0), then the UV maps ``keep`` (the next
    TEXCOORD_n, for the maps still read through them) and no other, no loss overlay, and the material copies."""
    copy = mesh.copy()
    order = [uv_map, *keep]
    corners = np.empty(2 * len(copy.loops), dtype=np.float32)
    kept = {}
    for name in order:
        copy.uv_layers[name].uv.foreach_get("vector", corners)
        kept[name] = corners.copy()
    for name in [layer.name for layer in copy.uv_layers]:
        copy.uv_layers.remove(copy.uv_layers[name])  # removal invalidates other layer references: go by name
    for name in order:  # the exporter numbers TEXCOORD_n in the mesh's order
        copy.uv_layers.new(name=name).uv.foreach_set("vector", kept[name])
    layer = copy.uv_layers[uv_map]
    layer.active = True
    layer.active_render = True
    for name in (LOSS_ATTRIBUTE, LOSS_COLOR_ATTRIBUTE):
        if name in copy.attributes:
            copy.attributes.remove(copy.attributes[name])
    for index, material in enumerate(copy.materials):
        if material in copy_of:
            copy.materials[index] = copy_of[material]
    return copy


@contextlib.contextmanager
def _lights_normalized():
    """Meanwhile, every light of the file whose power is not normalized by its size gets the same power normalized.

    A light's ``normalize`` off means its power is ``energy`` times its area (USD's lights come in so); Blender
    5.0's glTF exporter computes that area with a keyword ``Light.area`` does not take, and fails. With ``energy``
    set to that product and ``normalize`` on, the exporter writes the intensity it meant to. A light's data shared
    by objects of different sizes takes its first object's area.
    """
    changed = []  # (light data, energy)
    for obj in bpy.data.objects:  # the exporter writes every scene
        light = obj.data if obj.type == "LIGHT" else None
        if light is None or light.normalize or any(light is data for data, _ in changed):
            continue
        changed.append((light, light.energy))
        light.energy = light.energy * light.area(matrix_world=obj.matrix_world)
        light.normalize = True
    try:
        yield
    finally:
        for light, energy in changed:
            light.normalize = False
            light.energy = energy


def export_glb(runs, path):
    """Export the scene to ``path`` (.glb) with each run's objects on its new UV map, images and materials.

    Parameters
    ----------
    runs : sequence of (sequence of bpy.types.Object, perceptual_uv.bridge.pipeline.PipelineResult)
        Each run's optimized mesh objects (those that share a mesh included) and its result: ``uv_map`` (the new
        UV map's name) and ``materials`` (the material copies). One run per texture of the file; a mesh whose
        slots show several textures is in several runs, with one new UV map.
    path : str or os.PathLike

    Raises
    ------
    RuntimeError
        Blender's exporter failed (an I/O error, for instance).
    """
    with meshes_for_export(runs):
        options = dict(EXPORT_OPTIONS, export_tangents=_has_tangent_normal_map())
        with _lights_normalized(), failures_in_one_line("Blender's glTF exporter", cause="the run is not at fault"):
            bpy.ops.export_scene.gltf(filepath=str(path), **options)
        repair_tangents(path)


@contextlib.contextmanager
def meshes_for_export(runs):
    """Meanwhile, each optimized object shows an export copy of its mesh (:func:`_export_mesh`: the new UV map
    first, no loss overlay, the material copies) under the mesh's name; afterwards the objects get their own mesh
    back and the copies are removed. ``runs`` as :func:`export_glb` takes them."""
    meshes, copy_of = {}, {}  # mesh: (its new UV map, the objects that use it); original material: its copy
    for objects, result in runs:
        users, copies = _optimized_meshes(objects, result.uv_map, result.materials)
        copy_of.update(copies)
        for mesh, mesh_users in users.items():
            uv_map, known = meshes.setdefault(mesh, (result.uv_map, []))
            if uv_map != result.uv_map:
                raise ValueError(f"mesh '{mesh.name}' has two new UV maps, '{uv_map}' and '{result.uv_map}'")
            known.extend(obj for obj in mesh_users if obj not in known)
    swapped = []  # (mesh, its name, export copy, objects)
    try:
        for mesh, (uv_map, mesh_users) in meshes.items():
            copy = _export_mesh(mesh, uv_map, copy_of,
                                keep=_uv_maps_read_as_they_are(mesh, mesh_users, uv_map, copy_of))
            name = mesh.name
            swapped.append((mesh, name, copy, mesh_users))
            mesh.name = f"{name}.perceptual_export_source"
            copy.name = name  # the exported mesh keeps the input's name
            for obj in mesh_users:
                obj.data = copy
        yield
    finally:
        for mesh, name, copy, mesh_users in reversed(swapped):
            for obj in mesh_users:
                obj.data = mesh
            bpy.data.meshes.remove(copy)
            mesh.name = name
