# SPDX-License-Identifier: GPL-3.0-or-later
"""Which material slots read a map, and how: what a bake of that map takes from each slot.

A map record (:class:`.material_roles.MaterialMap`) names one image; an object's slots may read it, read it another
way (as a tangent-space normal map or as data: :func:`bake_kind`), through a texture transform, inside node
groups, or not at all. The colour and data bake (:mod:`.bake`), the normal-map bake (:mod:`.bake_normal`), the
material copies that read the new images (:mod:`.material_copy`) and the shaded evaluation
(:mod:`.evaluate_shaded`) must agree on these answers, so they all take them from here: which slots read a record
(:func:`_reads`), what a slot that does not read it contributes (:func:`_map_sources`, :func:`_slot_sources`),
whether a transform stops the bake (:func:`transform_problem`), and how to walk and copy the node groups a material
copy changes (:func:`localize_node_groups`, :func:`_all_nodes`). Nothing here bakes or changes the user's data.
"""
from .material import base_color_image_node, read_object_materials

__all__ = ["bake_kind", "has_transform", "transform_problem", "localize_node_groups", "TRANSFORM_NOTE"]


def bake_kind(record):
    """How a map is baked: ``"normal"`` (a tangent-space normal map, Cycles NORMAL) or ``"emit"`` (values copied)."""
    return "normal" if record.kind == "tangent_normal" else "emit"


# What a slot that does not read a map contributes to that map's image, per role (a slot without a base-colour
# image bakes its constant Base Color instead, as :func:`.bake.bake_base_color` does).
_NEUTRAL = {"alpha": (1.0, 1.0, 1.0, 1.0), "occlusion": (1.0, 1.0, 1.0, 1.0),
            "normal_object": (0.5, 0.5, 1.0, 1.0), "normal_world": (0.5, 0.5, 1.0, 1.0)}


def _slot_sources(obj):
    """Per material slot: (image or None, constant RGBA used when there is no image)."""
    sources = []
    for slot in obj.material_slots or [None]:
        material = slot.material if slot else None
        node = base_color_image_node(material)
        constant = (0.8, 0.8, 0.8, 1.0)
        if node is None and material is not None and material.node_tree is not None:
            for principled in (n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED"):
                constant = tuple(principled.inputs["Base Color"].default_value)
                break
        sources.append((node.image if node else None, constant))
    return sources


def _reading_records(obj, record, source_uv):
    """Per material slot of ``obj``: the slot's own record of ``record.image`` baked the same way, or None."""
    readings = read_object_materials(obj, source_uv=source_uv) if obj.material_slots else []
    kind = bake_kind(record)
    return [next((other for other in reading.maps if other.image == record.image and bake_kind(other) == kind),
                 None) for reading in readings] or [None]


def _reads(obj, record, source_uv):
    """Per material slot of ``obj``: True when the slot's material reads ``record.image`` the way it is baked."""
    return [other is not None for other in _reading_records(obj, record, source_uv)]


TRANSFORM_NOTE = "(a texture transform)"


def has_transform(record):
    """True when the map's coordinates pass through a texture transform (a Mapping node, vector math, ...)."""
    return any(TRANSFORM_NOTE in note for note in record.notes)


def _coordinates_of(node):
    """What an Image Texture node's coordinates are, comparable between nodes: None without a Vector link, a
    Mapping node's type and values with what feeds it, or the feeding node itself."""
    links = node.inputs["Vector"].links
    if not links:
        return None
    source = links[0].from_node
    if source.type != "MAPPING":
        return ("node", source.as_pointer(), links[0].from_socket.identifier)
    values = tuple(tuple(socket.default_value) if hasattr(socket.default_value, "__len__") else socket.default_value
                   for socket in source.inputs if socket.identifier != "Vector" and not socket.is_linked)
    linked = tuple(socket.identifier for socket in source.inputs if socket.is_linked)
    upstream = source.inputs["Vector"].links
    feed = None if not upstream else (upstream[0].from_node.type, getattr(upstream[0].from_node, "uv_map", None),
                                      upstream[0].from_socket.identifier)
    return ("mapping", source.vector_type, values, linked, feed)


def transform_problem(record):
    """Why a map read through a texture transform cannot be baked (a sentence), or None.

    Such a map is baked through its own Image Texture node and coordinates in a copy of its material, which
    needs the node at the material's top level (not inside a node group), and one new image holds one layout: the
    image's nodes must all read it through the same transform (the glTF importer gives each slot a Mapping node of
    its own, so equal values count as the same).
    """
    if not has_transform(record):
        return None
    if not all(node.id_data.is_embedded_data for node in record.nodes):
        return ("its coordinates pass through a texture transform inside a node group; move its Image Texture node "
                "and coordinates out of the group, or bake the transform into the image first")
    layouts = {_coordinates_of(node) for node in record.nodes}
    if len(layouts) > 1:
        return (f"{len(record.nodes)} Image Texture nodes read it through {len(layouts)} different texture "
                "transforms, and one new image holds one layout; give each transform an image of its own, or bake "
                "the transforms into the images first")
    return None


def _map_sources(objects, record, source_uv):
    """(image or None, constant RGBA) per object and slot, for the EMIT bake of ``record``."""
    sources = []
    for obj in objects:
        defaults = _slot_sources(obj) if record.role == "base_color" else None
        neutral = _NEUTRAL.get(record.role, (0.0, 0.0, 0.0, 1.0))
        sources.append([(record.image, None) if reads else (None, defaults[index][1] if defaults else neutral)
                        for index, reads in enumerate(_reads(obj, record, source_uv))])
    return sources


def localize_node_groups(tree, created, *, wanted=("TEX_IMAGE", "NORMAL_MAP", "UVMAP", "TEX_COORD")):
    """Give every Group node of ``tree`` whose group holds a node of a ``wanted`` type its own copy of the group.

    Material copies share their node groups with the original; a node changed inside a shared group would change
    the original too. Nested groups are localized the same way. The new groups are appended to ``created``.

    Returns
    -------
    bool
        True when ``tree`` (or a group inside it) holds a node of a ``wanted`` type.
    """
    found = False
    for node in tree.nodes:
        if node.type in wanted:
            found = True
        elif node.type == "GROUP" and node.node_tree is not None and _holds(node.node_tree, wanted):
            group = node.node_tree.copy()
            created.append(group)
            node.node_tree = group
            localize_node_groups(group, created, wanted=wanted)
            found = True
    return found


def _holds(tree, wanted):
    return any(node.type in wanted or (node.type == "GROUP" and node.node_tree is not None
                                       and _holds(node.node_tree, wanted)) for node in tree.nodes)


def _all_nodes(tree):
    for node in tree.nodes:
        yield node
        if node.type == "GROUP" and node.node_tree is not None:
            yield from _all_nodes(node.node_tree)
