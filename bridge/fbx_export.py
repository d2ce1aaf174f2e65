# SPDX-License-Identifier: GPL-3.0-or-later
"""Write a finished run as an .fbx: the whole scene of the input, with the optimized meshes on their new UV map.

The counterpart of :mod:`.gltf_export` for engines and tools that take FBX (Unity, Unreal, most DCC tools): the
same export copies of the optimized meshes (:func:`.gltf_export.meshes_for_export`: the new UV map as the first
UV set, which engines read textures through, no loss overlay, the run's material copies), written by Blender's
FBX exporter with every object type, the armature as it is (its modifiers live, so skinning is exported as a
skin, without leaf bones), the animations, and the images embedded in the file; the bone shapes Blender's glTF
importer makes are left out, as its glTF exporter leaves them out. FBX materials carry the maps that Blender's
exporter recognizes on a Principled BSDF (WaterBottle's base colour, normal and emission maps come through); an
occlusion-roughness-metallic image read through Separate Color is not one of them, and stays in the image file
saved beside the output.
"""
import contextlib

import bpy

from .gltf_export import meshes_for_export
from .mesh_io import failures_in_one_line

__all__ = ["export_fbx", "EXPORT_OPTIONS", "GLTF_NOT_EXPORTED"]

#: The collection in which Blender's glTF importer keeps the objects it makes for its own display (the bones'
#: shapes); its glTF exporter leaves it out, and so does :func:`export_fbx`.
GLTF_NOT_EXPORTED = "glTF_not_exported"

# Blender 5.0's FBX exporter, spelled out where its default would not keep the scene as it is.
EXPORT_OPTIONS = dict(
    use_selection=False,        # the whole scene, not just the optimized meshes
    use_visible=False,
    use_active_collection=False,
    object_types={"ARMATURE", "CAMERA", "EMPTY", "LIGHT", "MESH", "OTHER"},
    use_mesh_modifiers=False,   # the armature stays a skin, shape keys stay shape keys
    mesh_smooth_type="FACE",    # smoothing groups from the normals, for engines that read them
    use_custom_props=True,
    add_leaf_bones=False,       # no extra bones the input did not have
    bake_anim=True,
    path_mode="COPY",
    embed_textures=True,        # one file, as a .glb is
    check_existing=False,
)


def export_fbx(runs, path):
    """Export the scene to ``path`` (.fbx) with each run's objects on its new UV map, images and materials.

    Parameters
    ----------
    runs : sequence of (sequence of bpy.types.Object, perceptual_uv.bridge.pipeline.PipelineResult)
        As :func:`.gltf_export.export_glb` takes them.
    path : str or os.PathLike

    Raises
    ------
    RuntimeError
        Blender's exporter failed (in one line, :func:`.mesh_io.failures_in_one_line`).
    """
    with meshes_for_export(runs), _without_collection(GLTF_NOT_EXPORTED), \
            failures_in_one_line("Blender's FBX exporter", cause="the run is not at fault"):
        bpy.ops.export_scene.fbx(filepath=str(path), **EXPORT_OPTIONS)


@contextlib.contextmanager
def _without_collection(name):
    """Meanwhile, the collection ``name`` is unlinked from the scene's collections (linked back afterwards, at the
    end of its parents' children)."""
    collection = bpy.data.collections.get(name)
    parents = [] if collection is None else [
        parent for parent in (bpy.context.scene.collection, *bpy.data.collections)
        if parent.children.get(name) == collection]
    for parent in parents:
        parent.children.unlink(collection)
    try:
        yield
    finally:
        for parent in parents:
            parent.children.link(collection)
