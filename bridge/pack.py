# SPDX-License-Identifier: GPL-3.0-or-later
"""Pack the islands of a UV map with translations and 90-degree rotations only, on the new image's pixel grid."""
import bpy
import numpy as np

__all__ = ["pack_uv_layer", "uv_operator_on_copies"]


def pack_uv_layer(objects, uv_name, *, margin, resolution=None, texels_per_unit=None, face_stack=None,
                  aspects=(1.0,)):
    """Pack the islands of the UV map ``uv_name`` of ``objects`` together into one image, in place.

    The islands (charts: triangles joined by edges whose UVs agree) move by translations and quarter turns
    and all scale by one factor (:func:`perceptual_uv.core.packing.pack_charts`); the objects' other UV maps,
    modes and selections stay as they were.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects whose islands share one texture (one atlas).
    uv_name : str
        The UV map to pack (a map the caller owns, e.g. the new ``PerceptualUV``).
    margin : int
        Smallest gap between islands, in pixels of the packed image.
    resolution : int, optional
        Side of the square whose pixel count the image keeps; the islands fill it (the densest packing that
        fits).
    texels_per_unit : float, optional
        Pixels per unit of the UV map as it is: the islands keep this density and the image is as large as the
        packing needs. Exactly one of ``resolution`` and ``texels_per_unit`` is given.
    face_stack : (m,) array_like of int, optional
        Per triangle in the order of :func:`perceptual_uv.bridge.mesh_io.read_mesh` over ``objects``: a stack
        number (:func:`perceptual_uv.core.stacks.stacked_faces`), the triangles of one stack moving as one
        island, or -1 for a triangle that moves with its island. Default: every island alone.
    aspects : sequence of float, optional
        Width-to-height ratios the image may take (:func:`perceptual_uv.core.packing.iter_pack_charts`); a
        square by default.

    Returns
    -------
    perceptual_uv.core.packing.Packing
        With ``uv`` in the order of :func:`perceptual_uv.bridge.mesh_io.read_mesh` over ``objects``.
    """
    from ..core.charts import uv_topology
    from ..core.packing import pack_charts
    from ..core.stacks import packing_islands
    from .mesh_io import read_mesh

    objects = list(objects)
    for obj in objects:
        if obj.type != "MESH" or uv_name not in obj.data.uv_layers:
            raise ValueError(f"'{obj.name}' has no UV map '{uv_name}'")
    arrays = [read_mesh(obj, uv_name=uv_name) for obj in objects]
    offsets = np.cumsum([0] + [len(a.V) for a in arrays])
    F = np.concatenate([a.F + offset for a, offset in zip(arrays, offsets)])
    uv = np.concatenate([a.uv for a in arrays])
    islands = uv_topology(F, uv).face_chart
    if face_stack is not None:
        islands = packing_islands(islands, face_stack)
    packing = pack_charts(uv, islands, margin=margin, resolution=resolution, texels_per_unit=texels_per_unit,
                          aspects=aspects)
    start = 0
    for obj, a in zip(objects, arrays):
        layer = obj.data.uv_layers[uv_name]
        loop_uv = np.empty(2 * len(obj.data.loops), dtype=np.float32)
        layer.uv.foreach_get("vector", loop_uv)
        loop_uv = loop_uv.reshape(-1, 2)
        loop_uv[a.tri_loops.ravel()] = packing.uv[start:start + len(a.F)].reshape(-1, 2)
        layer.uv.foreach_set("vector", loop_uv.ravel())
        obj.data.update()
        start += len(a.F)
    return packing


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
