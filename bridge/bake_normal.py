# SPDX-License-Identifier: GPL-3.0-or-later
"""Bake a tangent-space normal map onto a new UV map, in that map's tangent frame (Cycles, CPU).

A tangent-space normal map stores directions in the MikkTSpace frame of its UV map, which a new UV map changes, so
its values cannot be copied as colour and data maps are (:mod:`.bake`). Cycles bakes NORMAL (tangent space) from a
temporary copy of the original material: the shading normal the material shows, written in the frame of the new
UV map, as Blender and glTF viewers compute it.

Cycles writes only the texels whose centres lie in a triangle. The texels bilinear lookups read next to a triangle
but no triangle covers (seams, island borders, thin strips) get what the bake would write at the triangle's point
nearest to them: the source map read there through the source UV map, taken to object space through the source
map's tangent frame and back into the target map's (:mod:`..core.tangent_frame`), with the normals and tangents
each program uses (:func:`_corner_frames`). The margin extends from all of these texels. On the texels Cycles
covers, the same conversion gives Cycles' own values to a fraction of an 8-bit step (docs/DECISIONS.md), except on
a fold of the surface: a triangle whose geometric normal opposes its corner normals, which Cycles bakes as seen
from behind, with the negated shading normal. Its texels take the same conversion, what the material shows there.
"""
import bpy
import numpy as np

from ..core.footprint import footprint_texels
from ..core.raster import sample_bilinear
from ..core.tangent_frame import interpolate_frame, object_to_tangent, tangent_to_object
from .cycles_bake import bake_pass, extend_margin, footprints, temporary_ids
from .map_reads import _all_nodes, _reads, has_transform, localize_node_groups
from .mesh_io import read_image, read_mesh

__all__ = ["bake_tangent_normal", "normal_values"]

FLAT = (0.5, 0.5, 1.0)


def _upstream_node(socket):
    """The Image Texture node linked into ``socket`` (through reroutes), or None."""
    for link in socket.links:
        node = link.from_node
        if node.type == "REROUTE":
            return _upstream_node(node.inputs[0])
        if node.type == "TEX_IMAGE":
            return node
    return None


def _normal_map_node(tree, image):
    """The unmuted tangent-space Normal Map node at the top level of ``tree`` whose Color ``image`` feeds, or None."""
    for node in tree.nodes:
        if node.type == "NORMAL_MAP" and node.space == "TANGENT" and not node.mute:
            texture = _upstream_node(node.inputs["Color"])
            if texture is not None and texture.image == image:
                return node
    return None


def _normal_material(created, material, source_uv, target, image):
    """A temporary copy of ``material`` whose shading normal is the one ``image`` gives through its Normal Map
    node (tangents of ``source_uv``); an Image Texture node holding ``target`` is active.

    When the material's top level has a tangent-space Normal Map node fed by ``image``, the copy's output is a
    Diffuse BSDF with that node's normal, so a bump or another normal map chained after it is not baked in (the
    material copy keeps applying those); otherwise the whole material shades. None gives a plain material (the
    mesh's own normals).
    """
    if material is None:
        copy = bpy.data.materials.new("perceptual_uv_bake_normal")
        created.append(copy)
    else:
        copy = material.copy()
        created.append(copy)
        localize_node_groups(copy.node_tree, created)
        for node in _all_nodes(copy.node_tree):
            # An empty UV map means the render UV map; the bake's proxy makes that the source map, but the tangent
            # frame is named explicitly so it can never follow the target map.
            if node.type == "NORMAL_MAP" and node.space == "TANGENT" and node.uv_map in ("", source_uv):
                node.uv_map = source_uv
        tree = copy.node_tree
        normal_map = _normal_map_node(tree, image)
        if normal_map is not None:
            for node in [node for node in tree.nodes if node.type == "OUTPUT_MATERIAL"]:
                tree.nodes.remove(node)
            output = tree.nodes.new("ShaderNodeOutputMaterial")
            diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
            tree.links.new(normal_map.outputs["Normal"], diffuse.inputs["Normal"])
            tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])
            output.is_active_output = True
    tree = copy.node_tree
    target_node = tree.nodes.new("ShaderNodeTexImage")
    target_node.image = target
    tree.nodes.active = target_node
    return copy


def bake_tangent_normal(objects, record, *, source_uv, target_uv, resolution, margin, tiles):
    """Bake the shading normals of the slots that read ``record`` as a tangent-space normal map on ``target_uv``.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects sharing the new image.
    record : perceptual_uv.bridge.material_roles.MaterialMap
        A tangent-space normal map (``map_reads.bake_kind(record) == "normal"``).
    source_uv, target_uv : str
        The UV map the material reads the map through (its tangent frame) and the one the new image is drawn on.
    resolution : int or (int, int)
        Side of the new image, or its ``(width, height)``.
    margin : int
        Bake margin in pixels, extended from the written texels across the image edges.
    tiles : sequence of tuple of int
        The integer UV tiles of ``target_uv`` to bake (:func:`.cycles_bake.touched_tiles`), tile (0, 0) first.

    Returns
    -------
    (height, width, 4) ndarray of float32
        Stored values ``0.5 n + 0.5`` of the unit normal n in the MikkTSpace frame (+X, +Y, +Z) of ``target_uv``;
        alpha 1. Texels Cycles covers hold its bake; texels next to a triangle that it leaves empty hold
        :func:`normal_values` at the triangle's nearest point where that can be computed (not through a texture
        transform, a Normal Map node inside a node group, a linked Strength, or a polygon of more than four
        corners); the margin extends from these, and texels beyond it are flat (0.5, 0.5, 1).
    """
    reads = [_reads(obj, record, source_uv) for obj in objects]

    def baked_material(object_index, slot_index):
        slots = objects[object_index].material_slots
        return slots[slot_index].material if reads[object_index][slot_index] else None

    def material_for(created, object_index, slot_index, target):
        return _normal_material(created, baked_material(object_index, slot_index), source_uv, target, record.image)

    def material_key(object_index, slot_index):  # one copy per material, shared by the slots that use it
        material = baked_material(object_index, slot_index)
        return material.as_pointer() if material is not None else None

    pixels, covered = bake_pass(objects, material_for, material_key, source_uv=source_uv, target_uv=target_uv,
                                resolution=resolution, tiles=tiles, bake_type="NORMAL",
                                slots=[len(slot_reads) for slot_reads in reads])
    if not has_transform(record):  # the lookups below read the source UV map without the node's transform
        folds = _fold_texels(objects, covered, target_uv=target_uv)  # before the seam texels join ``covered``
        for obj, (mesh, rows, columns, face, bary) in zip(objects, folds):
            values, known = normal_values(obj, record, mesh, face, bary, source_uv=source_uv, target_uv=target_uv)
            pixels[rows[known], columns[known], :3] = values[known]
        for obj, (mesh, rows, columns, face, bary) in zip(objects, footprints(objects, covered,
                                                                                target_uv=target_uv)):
            values, known = normal_values(obj, record, mesh, face, bary, source_uv=source_uv, target_uv=target_uv)
            rows, columns = rows[known], columns[known]
            pixels[rows, columns, :3] = values[known]
            covered[rows, columns] = True
    pixels[~covered, :3] = FLAT  # where no triangle and no margin reaches
    pixels[..., 3] = 1.0
    extend_margin(pixels, covered, margin)
    return pixels


def _fold_texels(objects, covered, *, target_uv):
    """Per object, the texels Cycles wrote whose centres lie inside a fold: a triangle whose geometric normal (its
    winding, in object space) opposes the sum of its corner normals.

    Returns
    -------
    list of tuple
        Per object ``(mesh, rows, columns, face, bary)`` as :func:`.cycles_bake.footprints` gives them, for texels of
        ``covered`` strictly inside a fold on ``target_uv``; ``bary`` is the texel centre's.
    """
    found = []
    for obj in objects:
        mesh = read_mesh(obj, uv_name=target_uv)
        data = obj.data
        corners = _get(data.vertices, "co", (len(data.vertices), 3))[mesh.F]
        geometric = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals = _get(data.corner_normals, "vector", (len(data.loops), 3))[mesh.tri_loops].sum(axis=1)
        folds = np.flatnonzero(np.einsum("fd,fd->f", geometric, normals) < 0)
        if not len(folds):  # nearly every mesh: no search over an image-sized mask
            found.append((mesh, *(np.empty(0, np.int64),) * 3, np.empty((0, 3))))
            continue
        rows, columns, face, bary = footprint_texels(mesh.uv[folds], np.zeros_like(covered))
        # a centre outside the triangle has its nearest point on the border, where a coordinate is exactly 0
        inside = (bary > 0).all(axis=1) & covered[rows, columns]
        found.append((mesh, rows[inside], columns[inside], folds[face[inside]], bary[inside]))
    return found


def _corner_frames(obj, source_uv, target_uv):
    """Per loop of ``obj``'s mesh, the two tangent frames of a normal-map bake: the one Cycles' Normal Map node
    reads ``source_uv``'s values in, and the one Blender's bake writes ``target_uv``'s values in.

    Each frame is a tuple of the normals (n_loops, 3), the MikkTSpace unit tangents (n_loops, 3) and the bitangent
    signs (n_loops,). Blender's bake takes its corner normals and the tangents it computes from them. Cycles takes
    the same, except on a mesh with smooth and flat faces and neither custom normals nor sharp edges: there it
    shades the smooth faces with the vertex normals (the flat faces' corners are not split off), and computes its
    tangents from those normals. On the sphere of a measurement, with a third of its faces flat, the corner
    normals in both frames put the values of the smooth faces next to flat ones up to 20 8-bit steps off Cycles'
    bake; these frames 0.08. None for a polygon of more than four corners, which Blender's tangent computation
    refuses. Computed on temporary copies of the mesh.
    """
    if any(polygon.loop_total > 4 for polygon in obj.data.polygons):
        return None
    with temporary_ids() as created:
        mesh = obj.data.copy()
        created.append(mesh)
        normals = _get(mesh.corner_normals, "vector", (len(mesh.loops), 3))
        frames = {}
        for name in dict.fromkeys((source_uv, target_uv)):
            mesh.calc_tangents(uvmap=name)
            frames[name] = (normals, _get(mesh.loops, "tangent", (len(mesh.loops), 3)),
                            _get(mesh.loops, "bitangent_sign", (len(mesh.loops),)))
        mesh.free_tangents()
        forward = frames[source_uv]
        smooth = _get(mesh.polygons, "use_smooth", (len(mesh.polygons),), np.bool_)
        sharp_edge = mesh.attributes.get("sharp_edge")
        sharp_edges = sharp_edge is not None and _get(sharp_edge.data, "value", (len(mesh.edges),), np.bool_).any()
        if smooth.any() and not smooth.all() and not mesh.has_custom_normals and not sharp_edges:
            loop_smooth = np.repeat(smooth, _get(mesh.polygons, "loop_total", (len(mesh.polygons),), np.int64))
            vertex_normals = _get(mesh.vertex_normals, "vector", (len(mesh.vertices), 3))
            loop_vertex = _get(mesh.loops, "vertex_index", (len(mesh.loops),), np.int64)
            render_normals = np.where(loop_smooth[:, None], vertex_normals[loop_vertex], normals)
            # the copy's corner normals become Cycles' normals, and its tangents the ones Cycles computes from them
            mesh.normals_split_custom_set(render_normals.tolist())
            mesh.calc_tangents(uvmap=source_uv)
            forward = (render_normals, _get(mesh.loops, "tangent", (len(mesh.loops), 3)),
                       _get(mesh.loops, "bitangent_sign", (len(mesh.loops),)))
            mesh.free_tangents()
    return forward, frames[target_uv]


def _get(collection, attribute, shape, dtype=np.float64):
    """``collection``'s ``attribute`` as an array of ``shape`` (foreach_get)."""
    values = np.empty(int(np.prod(shape)), dtype=np.float32 if dtype == np.float64 else dtype)
    collection.foreach_get(attribute, values)
    return values.reshape(shape).astype(dtype)


def _stored_values(texture_node, points):
    """The values Cycles reads from ``texture_node``'s image at UV ``points`` (p, 2): REPEAT, Closest or
    bilinear, 8-bit sRGB decoded to linear; None for another colour space of an 8-bit image."""
    image = texture_node.image
    texture = read_image(image)
    texture = np.repeat(texture[..., :1], 3, axis=2) if texture.shape[2] < 3 else texture[..., :3]
    height, width = texture.shape[:2]
    texel_points = points * (width, height)
    if texture_node.interpolation == "Closest":
        columns = np.floor(texel_points[:, 0]).astype(np.int64) % width
        rows = np.floor(texel_points[:, 1]).astype(np.int64) % height
        values = texture[rows, columns].astype(np.float64)
    else:
        values = sample_bilinear(texture, texel_points)
    if image.is_float or image.colorspace_settings.is_data:
        return values
    if image.colorspace_settings.name != "sRGB":
        return None
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4)


def normal_values(obj, record, mesh, face, bary, *, source_uv, target_uv):
    """What the tangent-space NORMAL bake of ``record`` writes at points of ``obj``'s triangles.

    The point's material slot reads the source map through its Normal Map node (tangent frame of ``source_uv``,
    the node's Strength); the resulting object-space normal is written in the tangent frame of ``target_uv``
    (:mod:`..core.tangent_frame`). A slot that does not read ``record`` shades with the mesh's own normal (flat,
    (0.5, 0.5, 1), unless Cycles' normal differs from the bake's, see :func:`_corner_frames`).

    Parameters
    ----------
    obj : bpy.types.Object
    record : perceptual_uv.bridge.material_roles.MaterialMap
    mesh : perceptual_uv.bridge.mesh_io.MeshArrays
        ``obj`` read by ``read_mesh`` (its triangles and their loops).
    face : (p,) array_like of int
        Triangle of each point in ``mesh``.
    bary : (p, 3) array_like of float
        Barycentric coordinates of each point in its triangle.
    source_uv, target_uv : str

    Returns
    -------
    values : (p, 3) ndarray of float64
        Stored values ``0.5 n + 0.5`` in [0, 1].
    known : (p,) ndarray of bool
        False where the value cannot be computed here (see :func:`bake_tangent_normal`); ``values`` is flat there.
    """
    face = np.asarray(face, dtype=np.int64)
    bary = np.asarray(bary, dtype=np.float64)
    values = np.tile(FLAT, (len(face), 1))
    known = np.zeros(len(face), dtype=bool)
    if not len(face):
        return values, known
    slot_reads = _reads(obj, record, source_uv)
    frames = _corner_frames(obj, source_uv, target_uv)
    if frames is None:
        return values, known
    loops = mesh.tri_loops[face]
    (source_normals, source_tangents, source_signs), (target_normals, target_tangents, target_signs) = frames
    source_tangent, source_sign, source_normal = interpolate_frame(
        bary, source_tangents[loops], source_signs[loops], source_normals[loops])
    target_tangent, target_sign, target_normal = interpolate_frame(
        bary, target_tangents[loops], target_signs[loops], target_normals[loops])
    points = np.einsum("pk,pkd->pd", bary, read_mesh(obj, uv_name=source_uv).uv[face])
    # Blender clamps material indices beyond the last slot to the last slot
    slot = np.clip(mesh.material_index[face], 0, len(slot_reads) - 1)
    for index in np.unique(slot):
        here = slot == index
        if not slot_reads[index]:  # a plain material: the normal Cycles shades with
            values[here] = object_to_tangent(source_normal[here], target_tangent[here], target_sign[here],
                                             target_normal[here])
            known[here] = True
            continue
        material = obj.material_slots[index].material
        node = _normal_map_node(material.node_tree, record.image)
        if node is None or node.uv_map not in ("", source_uv) or node.inputs["Strength"].is_linked:
            continue
        stored = _stored_values(_upstream_node(node.inputs["Color"]), points[here])
        if stored is None:
            continue
        direction = tangent_to_object(stored, source_tangent[here], source_sign[here], source_normal[here],
                                      strength=node.inputs["Strength"].default_value)
        values[here] = object_to_tangent(direction, target_tangent[here], target_sign[here], target_normal[here])
        known[here] = True
    return values, known
