# SPDX-License-Identifier: GPL-3.0-or-later
"""Pack the islands of a UV map with translations, one uniform scale and 90-degree rotations only."""
import bpy
import numpy as np

__all__ = ["pack_uv_layer", "uv_operator_on_copies"]


def pack_uv_layer(objects, uv_name, *, margin_fraction, shape_method="CONCAVE"):
    """Pack the islands of the UV map ``uv_name`` of ``objects`` together into the unit square.

    Blender's ``uv.pack_islands`` runs on temporary copies of the meshes in a temporary scene, so the objects'
    modes, selections, active UV maps and every other UV map stay as they were; only the packed coordinates of
    ``uv_name`` are written back.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects whose islands share one texture (one atlas).
    uv_name : str
        The UV map to pack (a map the caller owns, e.g. the new ``PerceptualUV``).
    margin_fraction : float
        Space between islands as a fraction of the unit square (``margin_pixels / resolution``).
    shape_method : {"CONCAVE", "CONVEX", "AABB"}
        Island shape approximation: tighter is slower.

    Notes
    -----
    Rotation is limited to ``CARDINAL`` (multiples of 90 degrees): any other rotation or a shear would undo
    the orientation the mesh-wise stage chose relative to the texel grid (paper Sec. 5.1, "Texture packing").
    """
    def pack():
        bpy.ops.uv.pack_islands(udim_source="CLOSEST_UDIM", rotate=True, rotate_method="CARDINAL", scale=True,
                                merge_overlap=False, margin_method="FRACTION", margin=margin_fraction, pin=False,
                                shape_method=shape_method)

    for obj, packed in zip(objects, uv_operator_on_copies(objects, uv_name, pack)):
        obj.data.uv_layers[uv_name].uv.foreach_set("vector", packed.ravel())
        obj.data.update()


def uv_operator_on_copies(objects, uv_name, operator):
    """Run ``operator()`` (``bpy.ops.uv`` calls) in Edit Mode on temporary copies; return the copies' new UVs.

    The copies live in a temporary scene with every face and UV selected and ``uv_name`` active, and the
    context is overridden so the operators see only them: the objects' modes, selections and data stay as they
    were, and everything temporary is removed, whatever happens.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects, all with a UV map ``uv_name``.
    uv_name : str
        The UV map the operators act on.
    operator : callable
        Called once without arguments inside the Edit Mode context.

    Returns
    -------
    list of (loops, 2) float64 ndarray
        ``uv_name`` of each copy afterwards, one per object in loop order.
    """
    objects = list(objects)
    for obj in objects:
        if obj.type != "MESH" or uv_name not in obj.data.uv_layers:
            raise ValueError(f"'{obj.name}' has no UV map '{uv_name}'")
    scene = bpy.data.scenes.new("perceptual_uv_uv_edit")
    proxies = []
    try:
        view_layer = scene.view_layers[0]
        for obj in objects:
            mesh = obj.data.copy()
            mesh.uv_layers.active = mesh.uv_layers[uv_name]
            proxy = bpy.data.objects.new("perceptual_uv_uv_edit", mesh)
            proxies.append(proxy)
            scene.collection.objects.link(proxy)
            proxy.select_set(True, view_layer=view_layer)
        view_layer.objects.active = proxies[0]
        with bpy.context.temp_override(scene=scene, view_layer=view_layer, active_object=proxies[0],
                                       object=proxies[0], edit_object=proxies[0], selected_objects=proxies,
                                       selected_editable_objects=proxies, objects_in_mode=proxies):
            bpy.ops.object.mode_set(mode="EDIT")
            try:
                bpy.ops.mesh.reveal()
                bpy.ops.mesh.select_all(action="SELECT")
                bpy.ops.uv.select_all(action="SELECT")
                operator()
            finally:
                bpy.ops.object.mode_set(mode="OBJECT")
        results = []
        for proxy in proxies:
            values = np.empty(2 * len(proxy.data.loops), dtype=np.float64)
            # Layer references go stale across mode switches: look the layer up again by name.
            proxy.data.uv_layers[uv_name].uv.foreach_get("vector", values)
            results.append(values.reshape(-1, 2))
        return results
    finally:
        for proxy in proxies:
            mesh = proxy.data
            bpy.data.objects.remove(proxy)
            bpy.data.meshes.remove(mesh)
        bpy.data.scenes.remove(scene)
