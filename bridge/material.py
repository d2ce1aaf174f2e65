# SPDX-License-Identifier: GPL-3.0-or-later
"""Read a material: every image its output depends on, with the role each plays (DESIGN decision 6).

The walk starts at the active Material Output's Surface, Volume and Displacement inputs and at the glTF
importer's "glTF Material Output" group (its Occlusion input), and follows links upstream through any node:
mix, math, colour adjustments, reroutes, muted nodes (their internal links) and node groups (into the group's
tree and back out through its Group Input). What an image drives is set by the socket the walk crossed last on
the way to it (see :mod:`.material_roles`); Separate Color / Separate XYZ outputs record which channel it reads.

Reading never changes Blender data.
"""
import math

from .material_roles import MaterialReading, build_map, socket_drives

__all__ = ["read_material", "material_maps", "read_object_materials", "base_color_image_node", "loss_image_nodes",
           "render_uv_name"]

GLTF_OUTPUT_GROUP_PREFIXES = ("glTF Material Output", "glTF Settings")
# A colour linked straight into a shader socket renders as emission; shader nodes on the way set their own labels.
_ROOT_DRIVES = {"Surface": "emission", "Volume": "volume", "Displacement": "displacement"}
_NORMAL_MAP_SPACES = {"TANGENT": "normal_tangent", "OBJECT": "normal_object", "BLENDER_OBJECT": "normal_object",
                      "WORLD": "normal_world", "BLENDER_WORLD": "normal_world"}
_SEPARATE_CHANNELS = {"Red": "R", "Green": "G", "Blue": "B", "X": "R", "Y": "G", "Z": "B"}
_COMBINE_INPUTS = {"R": ("Red", "X"), "G": ("Green", "Y"), "B": ("Blue", "Z")}
# Nodes that work on each colour channel alone: a channel picked downstream reads the same channel upstream.
_PER_CHANNEL_NODES = frozenset({"MIX", "MIX_RGB", "INVERT", "GAMMA", "BRIGHTCONTRAST", "CURVE_RGB"})
# Nodes that move texture coordinates without leaving them (a texture transform): the map stays bakeable.
_COORDINATE_TRANSFORMS = frozenset({"MAPPING", "VECT_MATH", "VECTOR_ROTATE", "SEPXYZ", "COMBXYZ", "MATH", "MIX",
                                    "MAP_RANGE", "CLAMP"})
_CONSTANT_NODES = frozenset({"VALUE", "RGB"})
# Images that are more than one still picture: still maps (the caller decides whether it can move them).
_MULTI_FRAME_SOURCES = {"TILED": "a tiled (UDIM) image: one image per UV tile", "MOVIE": "a movie image",
                        "SEQUENCE": "an image sequence"}


def _links(socket):
    return [link for link in socket.links if link.is_valid and not link.is_muted]


def _enabled_inputs(node):
    return [socket for socket in node.inputs if getattr(socket, "enabled", True)]


def _active(nodes, node_type):
    candidates = [node for node in nodes if node.type == node_type]
    return next((node for node in candidates if node.is_active_output), candidates[0] if candidates else None)


def _by_identifier(sockets, identifier):
    return next((socket for socket in sockets if socket.identifier == identifier), None)


def _is_shader_node(node):
    return any(socket.type == "SHADER" for socket in node.outputs)


class _Reader:
    """One walk over one material; collects uses per (image, UV map, reason to leave it as is)."""

    def __init__(self, source_uv, render_uv):
        self.source_uv = source_uv
        self.render_uv = render_uv if render_uv is not None else source_uv
        self.found = {}  # key -> {"image", "nodes", "uses", "notes", "uv_map", "left_as_is"}
        self.visited = set()
        self.volume = False

    # ---- the walk from the output to the images -------------------------------------------------------------
    def follow_input(self, socket, drives, channel, groups, notes):
        for link in _links(socket):
            self.follow_output(link.from_node, link.from_socket, drives, channel, groups, notes)

    def follow_output(self, node, socket, drives, channel, groups, notes):
        key = (node.as_pointer(), socket.identifier, drives, channel, groups, notes, self.volume)
        if key in self.visited:
            return
        self.visited.add(key)
        if node.mute:
            for internal in node.internal_links:
                if internal.to_socket.identifier == socket.identifier:
                    self.follow_input(internal.from_socket, drives, channel, groups, notes)
            return
        node_type = node.type
        if node_type == "TEX_IMAGE":
            self.record(node, socket, drives, channel, groups, notes)
        elif node_type == "REROUTE":
            self.follow_input(node.inputs[0], drives, channel, groups, notes)
        elif node_type == "GROUP":
            inner = _active(node.node_tree.nodes, "GROUP_OUTPUT") if node.node_tree else None
            inner_socket = inner and _by_identifier(inner.inputs, socket.identifier)
            if inner_socket is not None:
                self.follow_input(inner_socket, drives, channel, groups + (node,), notes)
        elif node_type == "GROUP_INPUT":
            outer_socket = groups and _by_identifier(groups[-1].inputs, socket.identifier)
            if outer_socket:
                self.follow_input(outer_socket, drives, channel, groups[:-1], notes)
        elif node_type in ("SEPARATE_COLOR", "SEPXYZ"):
            picked = _SEPARATE_CHANNELS.get(socket.name)
            if node_type == "SEPARATE_COLOR" and node.mode != "RGB":
                picked = None  # hue, saturation, value or lightness mix all three channels
            self.follow_input(node.inputs[0], drives, picked, groups, notes)
        elif node_type in ("COMBINE_COLOR", "COMBXYZ"):
            one_channel = channel is not None and (node_type == "COMBXYZ" or node.mode == "RGB")
            for upstream in _enabled_inputs(node):
                if not one_channel or upstream.name in _COMBINE_INPUTS[channel]:
                    self.follow_input(upstream, drives, None, groups, notes)
        elif node_type == "NORMAL_MAP":
            space = _NORMAL_MAP_SPACES.get(node.space, "normal_tangent")
            tangent_uv = node.uv_map or self.render_uv  # an empty name means the render UV map
            if space == "normal_tangent" and tangent_uv and self.source_uv and tangent_uv != self.source_uv:
                notes = notes + (f"its tangent frame comes from UV map '{tangent_uv}' (Normal Map node "
                                 f"'{node.name}')",)
            self.follow_input(node.inputs["Color"], space, None, groups, notes)
            self.follow_input(node.inputs["Strength"], "normal_strength", None, groups, notes)
        elif node_type in ("BUMP", "DISPLACEMENT", "VECTOR_DISPLACEMENT"):
            prefix = {"BUMP": "bump", "DISPLACEMENT": "displacement", "VECTOR_DISPLACEMENT": "vector_displacement"}
            for upstream in _enabled_inputs(node):
                if upstream.name == "Normal":
                    upstream_drives = drives  # a normal map chained below the bump keeps what it drives
                elif upstream.name == "Vector":
                    upstream_drives = "vector_displacement"
                else:
                    upstream_drives = f"{prefix[node_type]}_{socket_drives('', upstream.name)}"
                self.follow_input(upstream, upstream_drives, None, groups, notes)
        elif _is_shader_node(node):
            for upstream in _enabled_inputs(node):
                upstream_drives = drives if upstream.type == "SHADER" else socket_drives(node_type, upstream.name,
                                                                                          volume=self.volume)
                self.follow_input(upstream, upstream_drives, None, groups, notes)
        else:
            per_channel = node_type in _PER_CHANNEL_NODES
            for upstream in _enabled_inputs(node):
                keep = per_channel and upstream.type == "RGBA"
                self.follow_input(upstream, drives, channel if keep else None, groups, notes)

    # ---- one image: what it reads and how ---------------------------------------------------------------------
    def record(self, node, socket, drives, channel, groups, notes):
        image = node.image
        if image is None:
            return
        use = ("A" if socket.name == "Alpha" else channel or "RGB", drives)
        uv_map, reason, coordinate_notes = self.coordinates(node, groups)
        if image.source in _MULTI_FRAME_SOURCES:
            coordinate_notes.append(_MULTI_FRAME_SOURCES[image.source])
        key = (image.as_pointer(), uv_map, reason)
        entry = self.found.setdefault(key, {"image": image, "nodes": [], "uses": [], "notes": [], "uv_map": uv_map,
                                            "left_as_is": reason is not None})
        entry["nodes"].append(node)
        entry["uses"].append(use)
        entry["notes"] += ([reason] if reason else []) + list(coordinate_notes) + list(notes)

    def coordinates(self, node, groups):
        """(UV map name or None, reason to leave the image as is or None, notes) for an Image Texture node."""
        vector = node.inputs["Vector"]
        sources, transforms = set(), []
        if _links(vector):
            self.coordinate_sources(vector, groups, sources, transforms, set())
        else:
            sources.add(("uv", ""))
        # "" is the mesh's render UV map: the same map as its name, when that is known
        uv_names = {name or self.render_uv or "" for kind, name in sources if kind == "uv"}
        others = sorted((kind, name) for kind, name in sources if kind != "uv")
        notes = [f"its UV coordinates pass through {', '.join(dict.fromkeys(transforms))} (a texture transform)"
                 ] if transforms else []
        if len(uv_names) == 1 and not others:
            uv_map = next(iter(uv_names)) or None
            if self.source_uv is not None and uv_map != self.source_uv:
                return uv_map, f"left as is: reads UV map '{uv_map}', not the source UV map '{self.source_uv}'", notes
            return uv_map, None, notes
        if not sources:
            return None, "left as is: its texture coordinates are constant", notes
        described = [f"{kind} '{name}'" if kind in ("image", "node", "attribute") else f"{name} coordinates"
                     for kind, name in others]
        described += [f"UV map '{name}'" if name else "the render UV map" for name in sorted(uv_names)]
        return None, f"left as is: its texture coordinates come from {' and '.join(described)}", notes

    def coordinate_sources(self, socket, groups, sources, transforms, seen):
        for link in _links(socket):
            node, output = link.from_node, link.from_socket
            key = (node.as_pointer(), output.identifier, groups)
            if key in seen:
                continue
            seen.add(key)
            node_type = node.type
            if node.mute:
                for internal in node.internal_links:
                    if internal.to_socket.identifier == output.identifier:
                        self.coordinate_sources(internal.from_socket, groups, sources, transforms, seen)
            elif node_type == "REROUTE":
                self.coordinate_sources(node.inputs[0], groups, sources, transforms, seen)
            elif node_type == "UVMAP":
                sources.add(("uv", node.uv_map))
            elif node_type == "TEX_COORD":
                sources.add(("uv", "") if output.name == "UV" else ("coordinates", output.name))
            elif node_type == "ATTRIBUTE":
                geometry = node.attribute_type == "GEOMETRY" and output.name == "Vector"
                sources.add(("uv" if geometry else "attribute", node.attribute_name))
            elif node_type == "GROUP":
                inner = _active(node.node_tree.nodes, "GROUP_OUTPUT") if node.node_tree else None
                inner_socket = inner and _by_identifier(inner.inputs, output.identifier)
                if inner_socket is not None:
                    self.coordinate_sources(inner_socket, groups + (node,), sources, transforms, seen)
            elif node_type == "GROUP_INPUT":
                outer_socket = groups and _by_identifier(groups[-1].inputs, output.identifier)
                if outer_socket:
                    self.coordinate_sources(outer_socket, groups[:-1], sources, transforms, seen)
            elif node_type == "TEX_IMAGE":
                sources.add(("image", node.image.name if node.image else node.name))
            elif node_type in _COORDINATE_TRANSFORMS:
                transforms.append(f"{node.bl_label} node '{node.name}'")
                for upstream in _enabled_inputs(node):
                    self.coordinate_sources(upstream, groups, sources, transforms, seen)
            elif node_type not in _CONSTANT_NODES:
                sources.add(("node", node.name))

    # ---- the result ----------------------------------------------------------------------------------------------
    def reading(self, material):
        maps, left_as_is = [], []
        for entry in self.found.values():
            image = entry["image"]
            settings = image.colorspace_settings
            record = build_map(image, entry["nodes"], entry["uses"], colorspace=settings.name,
                               is_data=settings.is_data, uv_map=entry["uv_map"], notes=entry["notes"])
            (left_as_is if entry["left_as_is"] else maps).append(record)
        return MaterialReading(material=material, maps=tuple(maps), left_as_is=tuple(left_as_is))


def read_material(material, *, source_uv=None, render_uv=None):
    """Every image the material's output depends on, with its role, channels, colour space and UV map.

    Parameters
    ----------
    material : bpy.types.Material or None
    source_uv : str, optional
        The UV map being replaced. An image read through any other UV map, or through coordinates that are not
        a UV map (Generated, Object, Window, ..., or computed from another texture), is left as is with a note.
        None accepts every UV map (only non-UV coordinates are left as is).
    render_uv : str, optional
        The mesh's active render UV map, which an Image Texture node with no Vector link (or fed by a Texture
        Coordinate node's UV output, or a UV Map node with no map set) reads. Defaults to ``source_uv``.

    Returns
    -------
    MaterialReading
        ``maps`` (read through ``source_uv``: they move to the new UV map) and ``left_as_is``, each a tuple of
        :class:`~.material_roles.MaterialMap` in the order the walk from the output first met them (Principled
        BSDF inputs in socket order). One map per image and UV map: the glTF importer's two nodes reading an
        occlusion-roughness-metallic image give one map with uses R->occlusion, G->roughness, B->metallic.

    Notes
    -----
    Roots: the active Material Output's Surface, Volume and Displacement, and every input of the glTF
    importer's "glTF Material Output" (formerly "glTF Settings") group. The records hold references to nodes and
    images; read them again after editing the material.
    """
    reader = _Reader(source_uv, render_uv)
    tree = getattr(material, "node_tree", None)
    if tree is None:
        return MaterialReading(material=material)
    output = _active(tree.nodes, "OUTPUT_MATERIAL")
    for name, drives in _ROOT_DRIVES.items():
        if output is not None and name in output.inputs:
            reader.volume = name == "Volume"
            reader.follow_input(output.inputs[name], drives, None, (), ())
    reader.volume = False
    for node in tree.nodes:
        if node.type == "GROUP" and node.node_tree and node.node_tree.name.startswith(GLTF_OUTPUT_GROUP_PREFIXES):
            for socket in _enabled_inputs(node):
                reader.follow_input(socket, socket_drives("", socket.name), None, (), ())
    return reader.reading(material)


def material_maps(material, *, source_uv=None, render_uv=None):
    """The maps of ``material`` to move to a new UV map: ``read_material(...).maps`` as a list.

    Parameters are those of :func:`read_material`.

    Returns
    -------
    list of MaterialMap
    """
    return list(read_material(material, source_uv=source_uv, render_uv=render_uv).maps)


def read_object_materials(obj, *, source_uv=None):
    """:func:`read_material` for each material slot of a mesh object, with its UV maps filled in.

    Parameters
    ----------
    obj : bpy.types.Object
        A mesh object.
    source_uv : str, optional
        The UV map being replaced; the mesh's active UV map by default.

    Returns
    -------
    list of MaterialReading
        One per material slot, in slot order (an empty slot gives a reading with ``material=None``).

    Raises
    ------
    ValueError
        If ``obj`` is not a mesh object or has no UV map.
    """
    if obj is None or obj.type != "MESH":
        raise ValueError(f"'{getattr(obj, 'name', obj)}' is not a mesh object")
    layers = obj.data.uv_layers
    if not layers:
        raise ValueError(f"'{obj.name}' has no UV map")
    source_uv = source_uv if source_uv is not None else layers.active.name
    render = render_uv_name(obj.data)
    return [read_material(slot.material, source_uv=source_uv, render_uv=render) for slot in obj.material_slots]


def render_uv_name(mesh):
    """The UV map an Image Texture or Normal Map node with an empty UV map name reads on ``mesh``: the one
    active for rendering, else the first; None if the mesh has none."""
    layers = mesh.uv_layers
    return next((layer.name for layer in layers if layer.active_render), layers[0].name if len(layers) else None)


def base_color_image_node(material):
    """The Image Texture node of ``material``'s base-colour map, or None.

    The first map with role ``base_color`` found by :func:`read_material` (any UV map accepted); for a material
    with none, its first ``emissive`` map (an unlit material's colour, as the glTF importer builds it). An image
    that only drives roughness, metallic, normals or other data is never returned, nor one read through
    generated or computed coordinates.

    Parameters
    ----------
    material : bpy.types.Material or None

    Returns
    -------
    bpy.types.ShaderNodeTexImage or None
    """
    maps = material_maps(material)
    for role in ("base_color", "emissive"):
        found = next((record.node for record in maps if record.role == role), None)
        if found is not None:
            return found
    return None


def loss_image_nodes(materials):
    """Per material, the Image Texture node of the image a run on these materials is framed by, or None.

    That image's texel grid is the frame of the triangle-wise parameters and of the loss's first plane, it sets
    the relative cost's reference size, and the objects a run takes together share it. It is the base colour's
    (:func:`base_color_image_node`) wherever one of ``materials`` has a base-colour map: a slot without one beside
    them is a constant colour (None). Only when none of them has one are they framed by another map, each
    material's map with the most pixels (the first met on a tie), so that a material whose colour is a constant
    and whose detail is in its normal, roughness or other data maps is optimized on those maps. Which image frames
    the run never decides how a map is read: every map keeps its own role (:func:`material_maps`).

    Parameters
    ----------
    materials : sequence of bpy.types.Material or None
        The materials of one run (the objects' slots); None for an empty slot.

    Returns
    -------
    list of bpy.types.ShaderNodeTexImage or None
        In the order of ``materials``.
    """
    materials = list(materials)
    nodes = [base_color_image_node(material) for material in materials]
    if any(node is not None for node in nodes):
        return nodes

    from .image_file import image_size  # from the file's header: a large image is not loaded for this

    def largest(material):
        maps = material_maps(material)
        if not maps:
            return None
        return max(maps, key=lambda record: math.prod(image_size(record.image))).node

    return [largest(material) for material in materials]
