# SPDX-License-Identifier: GPL-3.0-or-later
"""What an image does in a material: the role vocabulary and the records of a material reading (no bpy).

:mod:`.material` walks a material's node tree and collects, for every image it reaches, *uses*: pairs
``(channel, drives)`` such as ``("G", "roughness")``. This module turns those uses into a :class:`MaterialMap`
with one role. Nothing here imports bpy, so the rules can be read and tested on their own.

Channels: ``"R"``, ``"G"``, ``"B"`` (one channel picked by a Separate Color / Separate XYZ node), ``"RGB"`` (the
colour output used whole, or converted to a scalar, which reads all three channels) and ``"A"`` (the Alpha output).

Drives: the socket a use ends at, in snake case (``"base_color"``, ``"roughness"``, ``"coat_weight"``, ...), or
what an interpreting node makes of it: ``"normal_tangent"``, ``"normal_object"``, ``"normal_world"`` (the Color
input of a Normal Map node in that space), ``"bump_height"``, ``"displacement_height"``, ``"occlusion"`` (the glTF
importer's material output group), ``"emission"`` (Emission Color, an Emission shader's Color, or a colour wired
straight into a shader socket, which Blender renders as emission).
"""
import dataclasses
import re

__all__ = ["ROLES", "MaterialMap", "MaterialReading", "build_map", "role_for", "kind_for", "sorted_uses",
           "channels_used", "socket_drives"]

ROLES = ("base_color", "alpha", "normal_tangent", "normal_object", "normal_world", "emissive",
         "metallic_roughness", "occlusion", "data")
"""Every role a map can have, in the order a map driving several kinds of socket is given one."""

NORMAL_ROLES = ("normal_tangent", "normal_object", "normal_world")
PBR_DATA_DRIVES = frozenset({"roughness", "metallic", "occlusion"})
_CHANNEL_ORDER = {"R": 0, "G": 1, "B": 2, "RGB": 3, "A": 4}

# Input sockets of shader nodes whose name alone does not say what they drive.
_RENAMED_SHADER_SOCKETS = {
    ("BSDF_PRINCIPLED", "Emission Color"): "emission",
    ("EMISSION", "Color"): "emission",
    ("EMISSION", "Strength"): "emission_strength",
    ("MIX_SHADER", "Factor"): "shader_mix_factor",
}


def _snake(name):
    return re.sub(r"[^0-9a-z]+", "_", name.lower()).strip("_") or "unnamed"


def socket_drives(node_type, socket_name, *, volume=False):
    """The ``drives`` label of an input socket of a shader node (a node with a shader output).

    Parameters
    ----------
    node_type : str
        ``bpy.types.Node.type`` of the shader node, e.g. ``"BSDF_PRINCIPLED"``, ``"EMISSION"``.
    socket_name : str
        The input's name, e.g. ``"Base Color"``.
    volume : bool, optional
        True when the node feeds the material output's Volume: the label is prefixed ``volume_``.

    Returns
    -------
    str
        ``"base_color"`` for any shader's Color or Base Color, ``"emission"`` for emission colours, otherwise
        the socket's name in snake case (``"Coat Weight"`` -> ``"coat_weight"``).
    """
    drives = _RENAMED_SHADER_SOCKETS.get((node_type, socket_name))
    if drives is None:
        drives = "base_color" if socket_name in ("Color", "Base Color") else _snake(socket_name)
    return f"volume_{drives}" if volume else drives


def role_for(drives):
    """The one role of an image from everything it drives.

    Parameters
    ----------
    drives : iterable of str
        The ``drives`` labels of the image's uses.

    Returns
    -------
    str
        One of :data:`ROLES`. Colour wins over everything (an image that is base colour and also alpha, or
        also roughness, is base colour), then emissive, then normal maps; roughness/metallic/occlusion only
        is ``metallic_roughness`` (glTF's packed image, occlusion-roughness-metallic included), occlusion only
        is ``occlusion``, alpha only is ``alpha``; anything else (bump height, coat, sheen, displacement, ...)
        is ``data``.
    """
    drives = set(drives)
    if "base_color" in drives:
        return "base_color"
    if "emission" in drives:
        return "emissive"
    for role in NORMAL_ROLES:
        if role in drives:
            return role
    if drives == {"occlusion"}:
        return "occlusion"
    if drives and drives <= PBR_DATA_DRIVES:
        return "metallic_roughness"
    if drives == {"alpha"}:
        return "alpha"
    return "data"


def kind_for(role):
    """How a role's map is compared and re-baked: ``"color"``, ``"tangent_normal"`` or ``"data"``.

    Base colour and emissive maps are colour (seen through luma). A tangent-space normal map is expressed in
    its UV map's tangent frame, so it must be re-baked as a normal map in the new frame. Everything else is data
    copied value for value through the original UV map, object- and world-space normal maps included (their
    values do not depend on the UV layout).
    """
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}; expected one of {', '.join(ROLES)}")
    if role in ("base_color", "emissive"):
        return "color"
    return "tangent_normal" if role == "normal_tangent" else "data"


def sorted_uses(uses):
    """``(channel, drives)`` pairs without repeats, in channel order R, G, B, RGB, A, then by ``drives``."""
    return tuple(sorted(set(uses), key=lambda use: (_CHANNEL_ORDER.get(use[0], 9), use[0], use[1])))


def channels_used(uses):
    """The image channels some use reads, as a string in ``"RGBA"`` order, e.g. ``"GB"`` or ``"RGBA"``."""
    read = set()
    for channel, _ in uses:
        read.update("RGB" if channel == "RGB" else channel)
    return "".join(letter for letter in "RGBA" if letter in read)


@dataclasses.dataclass(frozen=True)
class MaterialMap:
    """One image a material's output depends on, read through one UV map, with what it does.

    Attributes
    ----------
    image : bpy.types.Image
    nodes : tuple of bpy.types.ShaderNodeTexImage
        Every Image Texture node (top level or inside node groups) that reads ``image`` through ``uv_map``, in
        the order the walk from the output met them. The glTF importer reads a packed occlusion-roughness-
        metallic image with two nodes; it is still one map.
    role : str
        One of :data:`ROLES` (see :func:`role_for`).
    uses : tuple of (str, str)
        ``(channel, drives)`` pairs, e.g. ``(("R", "occlusion"), ("G", "roughness"), ("B", "metallic"))``.
    colorspace : str
        The image's colour space name as Blender holds it (``"sRGB"``, ``"Non-Color"``, ...).
    is_data : bool
        True when that colour space is a data space (Non-Color): values are read without conversion.
    uv_map : str or None
        The UV map the nodes read; None when they read the mesh's default (active render) UV map and its name
        was not given.
    notes : tuple of str
        Anything a user should know: why the map is left as it is, a colour space that does not fit the role,
        a Mapping node on the coordinates, uses beyond the role.
    """

    image: object
    nodes: tuple
    role: str
    uses: tuple
    colorspace: str
    is_data: bool
    uv_map: object
    notes: tuple = ()

    @property
    def node(self):
        """The first Image Texture node reading the map (the one nearest the output)."""
        return self.nodes[0]

    @property
    def kind(self):
        """``"color"``, ``"tangent_normal"`` or ``"data"`` (see :func:`kind_for`)."""
        return kind_for(self.role)

    @property
    def channels(self):
        """The channels some use reads, in ``"RGBA"`` order (``"RGB"`` for a base colour, ``"RGB"`` for ORM)."""
        return channels_used(self.uses)

    @property
    def drives(self):
        """What each use drives, without repeats, in the order of :attr:`uses`."""
        return tuple(dict.fromkeys(drives for _, drives in self.uses))


@dataclasses.dataclass(frozen=True)
class MaterialReading:
    """Everything a material's output reads from images.

    Attributes
    ----------
    material : bpy.types.Material or None
    maps : tuple of MaterialMap
        Maps read through the source UV map: these move to a new UV map.
    left_as_is : tuple of MaterialMap
        Images read some other way (another UV map, generated/object/window coordinates, coordinates computed
        from other textures, tiled or movie images); each has a note saying why. They stay as they are.
    """

    material: object
    maps: tuple = ()
    left_as_is: tuple = ()


def build_map(image, nodes, uses, *, colorspace, is_data, uv_map, notes=()):
    """A :class:`MaterialMap` whose role follows from ``uses``, with notes on anything that does not fit it.

    Parameters
    ----------
    image : bpy.types.Image
    nodes : sequence of bpy.types.ShaderNodeTexImage
    uses : iterable of (str, str)
        ``(channel, drives)`` pairs.
    colorspace : str
    is_data : bool
    uv_map : str or None
    notes : iterable of str, optional
        Notes found while walking (kept first, in order, without repeats).

    Returns
    -------
    MaterialMap
    """
    uses = sorted_uses(uses)
    role = role_for(drives for _, drives in uses)
    notes = list(dict.fromkeys(notes))
    ignored_by_role = {"base_color": {"base_color", "alpha"}, "emissive": {"emission"}}.get(role, {role})
    others = [drives for _, drives in uses if drives not in ignored_by_role]
    if role in ("base_color", "emissive") + NORMAL_ROLES and others:
        notes.append(f"taken as {role}; the image also drives {', '.join(dict.fromkeys(others))}")
    if kind_for(role) == "color" and is_data:
        notes.append(f"a {role} map stored as {colorspace} data")
    elif role in NORMAL_ROLES + ("metallic_roughness", "occlusion") and not is_data:
        notes.append(f"a {role} map stored as {colorspace} colour, not Non-Color data")
    return MaterialMap(image=image, nodes=tuple(dict.fromkeys(nodes)), role=role, uses=uses, colorspace=colorspace,
                       is_data=bool(is_data), uv_map=uv_map, notes=tuple(notes))
