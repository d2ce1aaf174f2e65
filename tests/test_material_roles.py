# SPDX-License-Identifier: GPL-3.0-or-later
"""Reading a material: every image its output depends on, with its role, channels, colour space and UV map.

Expected roles and uses are derived by hand from the node graphs built here (or, for the shared glTF models,
from the glTF files' material definitions and the glTF 2.0 rule that a metallic-roughness texture keeps
roughness in G and metallic in B, and an occlusion texture occlusion in R).
"""
import pathlib

import pytest

from perceptual_uv.bridge.material_roles import (ROLES, build_map, channels_used, kind_for, role_for,
                                                 socket_drives, sorted_uses)


# ---- the pure rules (no bpy) -----------------------------------------------------------------------------------

@pytest.mark.parametrize("drives, role", [
    ({"base_color"}, "base_color"),
    ({"base_color", "alpha"}, "base_color"),
    ({"base_color", "roughness"}, "base_color"),
    ({"alpha"}, "alpha"),
    ({"emission"}, "emissive"),
    ({"normal_tangent"}, "normal_tangent"),
    ({"normal_object"}, "normal_object"),
    ({"normal_world"}, "normal_world"),
    ({"occlusion", "roughness", "metallic"}, "metallic_roughness"),
    ({"roughness"}, "metallic_roughness"),
    ({"occlusion"}, "occlusion"),
    ({"roughness", "coat_weight"}, "data"),
    ({"bump_height"}, "data"),
    (set(), "data"),
])
def test_role_follows_from_what_the_image_drives(drives, role):
    assert role_for(drives) == role


def test_kinds_split_colour_tangent_normals_and_data():
    assert {role: kind_for(role) for role in ROLES} == {
        "base_color": "color", "alpha": "data", "normal_tangent": "tangent_normal", "normal_object": "data",
        "normal_world": "data", "emissive": "color", "metallic_roughness": "data", "occlusion": "data",
        "data": "data"}
    with pytest.raises(ValueError, match="unknown role"):
        kind_for("albedo")


def test_uses_sort_by_channel_and_channels_merge():
    uses = [("B", "metallic"), ("A", "alpha"), ("R", "occlusion"), ("B", "metallic"), ("RGB", "base_color")]
    assert sorted_uses(uses) == (("R", "occlusion"), ("B", "metallic"), ("RGB", "base_color"), ("A", "alpha"))
    assert channels_used([("G", "roughness"), ("B", "metallic")]) == "GB"
    assert channels_used([("RGB", "base_color"), ("A", "alpha")]) == "RGBA"


def test_socket_names_become_drives_labels():
    assert socket_drives("BSDF_PRINCIPLED", "Base Color") == "base_color"
    assert socket_drives("BSDF_DIFFUSE", "Color") == "base_color"
    assert socket_drives("BSDF_PRINCIPLED", "Emission Color") == "emission"
    assert socket_drives("EMISSION", "Color") == "emission"
    assert socket_drives("BSDF_PRINCIPLED", "Coat Weight") == "coat_weight"
    assert socket_drives("PRINCIPLED_VOLUME", "Density", volume=True) == "volume_density"


def test_notes_flag_a_colour_space_that_does_not_fit_the_role():
    normal_in_srgb = build_map("image", ["node"], [("RGB", "normal_tangent")], colorspace="sRGB", is_data=False,
                               uv_map="UVMap")
    assert normal_in_srgb.notes == ("a normal_tangent map stored as sRGB colour, not Non-Color data",)
    colour_as_data = build_map("image", ["node"], [("RGB", "base_color"), ("G", "roughness")],
                               colorspace="Non-Color", is_data=True, uv_map="UVMap")
    assert colour_as_data.notes == ("taken as base_color; the image also drives roughness",
                                    "a base_color map stored as Non-Color data")
    assert colour_as_data.channels == "RGB" and colour_as_data.drives == ("roughness", "base_color")


# ---- materials built in Blender ---------------------------------------------------------------------------------

bpy_tests = pytest.mark.bpy


@pytest.fixture
def blender(empty_scene):
    import bpy

    return bpy


def new_image(bpy, name, *, data=False):
    image = bpy.data.images.new(name, 4, 4, alpha=True)
    if data:
        image.colorspace_settings.name = "Non-Color"
    return image


def new_material(bpy, name="material"):
    """A material with the default Principled BSDF -> Material Output; returns (material, tree, principled)."""
    material = bpy.data.materials.new(name)
    tree = material.node_tree
    return material, tree, tree.nodes["Principled BSDF"]


def image_node(tree, image):
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    return node


def summary(maps):
    """(image name, role, uses, colour space, UV map) per map, the facts the tests compare."""
    return [(record.image.name, record.role, record.uses, record.colorspace, record.uv_map) for record in maps]


@bpy_tests
def test_base_colour_and_its_alpha_are_one_map(blender):
    from perceptual_uv.bridge.material import base_color_image_node, read_material

    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "colour"))
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])
    tree.links.new(colour.outputs["Alpha"], principled.inputs["Alpha"])

    reading = read_material(material, source_uv="UVMap")

    assert summary(reading.maps) == [("colour", "base_color", (("RGB", "base_color"), ("A", "alpha")), "sRGB",
                                      "UVMap")]
    assert reading.maps[0].channels == "RGBA" and reading.maps[0].kind == "color" and not reading.maps[0].is_data
    assert reading.maps[0].nodes == (colour,) and reading.left_as_is == ()
    assert base_color_image_node(material) == colour


@bpy_tests
def test_alpha_from_its_own_image_is_an_alpha_map(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "colour"))
    mask = image_node(tree, new_image(blender, "mask", data=True))
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])
    tree.links.new(mask.outputs["Color"], principled.inputs["Alpha"])

    assert summary(material_maps(material, source_uv="UVMap")) == [
        ("colour", "base_color", (("RGB", "base_color"),), "sRGB", "UVMap"),
        ("mask", "alpha", (("RGB", "alpha"),), "Non-Color", "UVMap")]


@bpy_tests
def test_packed_image_through_separate_color_uses_two_channels(blender):
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender)
    packed = image_node(tree, new_image(blender, "metal_rough", data=True))
    separate = tree.nodes.new("ShaderNodeSeparateColor")
    tree.links.new(packed.outputs["Color"], separate.inputs["Color"])
    tree.links.new(separate.outputs["Green"], principled.inputs["Roughness"])
    tree.links.new(separate.outputs["Blue"], principled.inputs["Metallic"])

    maps = material_maps(material, source_uv="UVMap")

    assert summary(maps) == [("metal_rough", "metallic_roughness", (("G", "roughness"), ("B", "metallic")),
                              "Non-Color", "UVMap")]
    assert maps[0].channels == "GB" and maps[0].is_data and maps[0].kind == "data"
    # the old walk went from the output into this image and called it the base colour
    assert base_color_image_node(material) is None


def gltf_output_group(bpy, tree):
    """The node group the glTF importer adds for occlusion (not linked to the Material Output)."""
    group = bpy.data.node_groups.new("glTF Material Output", "ShaderNodeTree")
    group.interface.new_socket("Occlusion", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("Thickness", in_out="INPUT", socket_type="NodeSocketFloat")
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    return node


@bpy_tests
def test_occlusion_roughness_metallic_read_by_two_nodes_is_one_map(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    orm = new_image(blender, "orm", data=True)
    metal_rough_node, occlusion_node = image_node(tree, orm), image_node(tree, orm)
    separate, separate_occlusion = tree.nodes.new("ShaderNodeSeparateColor"), tree.nodes.new("ShaderNodeSeparateColor")
    tree.links.new(metal_rough_node.outputs["Color"], separate.inputs["Color"])
    tree.links.new(separate.outputs["Green"], principled.inputs["Roughness"])
    tree.links.new(separate.outputs["Blue"], principled.inputs["Metallic"])
    tree.links.new(occlusion_node.outputs["Color"], separate_occlusion.inputs["Color"])
    tree.links.new(separate_occlusion.outputs["Red"], gltf_output_group(blender, tree).inputs["Occlusion"])

    maps = material_maps(material, source_uv="UVMap")

    assert summary(maps) == [("orm", "metallic_roughness",
                              (("R", "occlusion"), ("G", "roughness"), ("B", "metallic")), "Non-Color", "UVMap")]
    assert maps[0].nodes == (metal_rough_node, occlusion_node) and maps[0].channels == "RGB"


@bpy_tests
def test_occlusion_alone_is_an_occlusion_map(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, _ = new_material(blender)
    occlusion = image_node(tree, new_image(blender, "ao", data=True))
    separate = tree.nodes.new("ShaderNodeSeparateColor")
    tree.links.new(occlusion.outputs["Color"], separate.inputs["Color"])
    tree.links.new(separate.outputs["Red"], gltf_output_group(blender, tree).inputs["Occlusion"])

    assert summary(material_maps(material, source_uv="UVMap")) == [
        ("ao", "occlusion", (("R", "occlusion"),), "Non-Color", "UVMap")]


@bpy_tests
@pytest.mark.parametrize("space, role, kind", [("TANGENT", "normal_tangent", "tangent_normal"),
                                               ("OBJECT", "normal_object", "data"),
                                               ("WORLD", "normal_world", "data")])
def test_normal_map_node_space_gives_the_normal_role(blender, space, role, kind):
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender)
    normal = image_node(tree, new_image(blender, "normal", data=True))
    normal_map = tree.nodes.new("ShaderNodeNormalMap")
    normal_map.space = space
    tree.links.new(normal.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], principled.inputs["Normal"])

    maps = material_maps(material, source_uv="UVMap")

    assert summary(maps) == [("normal", role, (("RGB", role),), "Non-Color", "UVMap")]
    assert maps[0].kind == kind and maps[0].notes == ()
    assert base_color_image_node(material) is None


@bpy_tests
def test_tangent_frame_from_another_uv_map_is_noted(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    normal = image_node(tree, new_image(blender, "normal", data=True))
    normal_map = tree.nodes.new("ShaderNodeNormalMap")
    normal_map.uv_map = "Lightmap"
    tree.links.new(normal.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], principled.inputs["Normal"])

    (record,) = material_maps(material, source_uv="UVMap")

    assert record.role == "normal_tangent"
    assert record.notes == ("its tangent frame comes from UV map 'Lightmap' (Normal Map node 'Normal Map')",)


@bpy_tests
def test_bump_height_is_data_and_a_normal_map_below_the_bump_stays_a_normal_map(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    height = image_node(tree, new_image(blender, "height", data=True))
    normal = image_node(tree, new_image(blender, "normal", data=True))
    bump, normal_map = tree.nodes.new("ShaderNodeBump"), tree.nodes.new("ShaderNodeNormalMap")
    tree.links.new(height.outputs["Color"], bump.inputs["Height"])
    tree.links.new(normal.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], bump.inputs["Normal"])
    tree.links.new(bump.outputs["Normal"], principled.inputs["Normal"])

    assert summary(material_maps(material, source_uv="UVMap")) == [
        ("height", "data", (("RGB", "bump_height"),), "Non-Color", "UVMap"),
        ("normal", "normal_tangent", (("RGB", "normal_tangent"),), "Non-Color", "UVMap")]


@bpy_tests
def test_node_groups_are_followed_in_and_out(blender):
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender)
    # group: Color in -> Invert -> Color out; its own roughness image -> Gamma -> Roughness out
    group = blender.data.node_groups.new("tint", "ShaderNodeTree")
    group.interface.new_socket("Color", in_out="INPUT", socket_type="NodeSocketColor")
    group.interface.new_socket("Color", in_out="OUTPUT", socket_type="NodeSocketColor")
    group.interface.new_socket("Roughness", in_out="OUTPUT", socket_type="NodeSocketFloat")
    group_input, group_output = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    invert, gamma = group.nodes.new("ShaderNodeInvert"), group.nodes.new("ShaderNodeGamma")
    inner = image_node(group, new_image(blender, "inner_rough", data=True))
    group.links.new(group_input.outputs["Color"], invert.inputs["Color"])
    group.links.new(invert.outputs["Color"], group_output.inputs["Color"])
    group.links.new(inner.outputs["Color"], gamma.inputs["Color"])
    group.links.new(gamma.outputs["Color"], group_output.inputs["Roughness"])
    group_node = tree.nodes.new("ShaderNodeGroup")
    group_node.node_tree = group
    outer = image_node(tree, new_image(blender, "outer_colour"))
    tree.links.new(outer.outputs["Color"], group_node.inputs["Color"])
    tree.links.new(group_node.outputs["Color"], principled.inputs["Base Color"])
    tree.links.new(group_node.outputs["Roughness"], principled.inputs["Roughness"])

    maps = material_maps(material, source_uv="UVMap")

    assert summary(maps) == [("outer_colour", "base_color", (("RGB", "base_color"),), "sRGB", "UVMap"),
                             ("inner_rough", "metallic_roughness", (("RGB", "roughness"),), "Non-Color", "UVMap")]
    assert maps[1].node == inner
    assert base_color_image_node(material) == outer


@bpy_tests
def test_an_image_read_through_another_uv_map_is_left_as_is(blender):
    from perceptual_uv.bridge.material import material_maps, read_material

    material, tree, principled = new_material(blender)
    decal = image_node(tree, new_image(blender, "decal"))
    uv_node = tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = "Decals"
    tree.links.new(uv_node.outputs["UV"], decal.inputs["Vector"])
    tree.links.new(decal.outputs["Color"], principled.inputs["Base Color"])

    reading = read_material(material, source_uv="UVMap")

    assert reading.maps == ()
    assert summary(reading.left_as_is) == [("decal", "base_color", (("RGB", "base_color"),), "sRGB", "Decals")]
    assert reading.left_as_is[0].notes == ("left as is: reads UV map 'Decals', not the source UV map 'UVMap'",)
    # optimizing the Decals map itself moves this image
    assert summary(material_maps(material, source_uv="Decals")) == summary(reading.left_as_is)


@bpy_tests
def test_the_render_uv_map_by_default_and_by_name_is_one_map(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    image = new_image(blender, "orm", data=True)
    by_default, by_name = image_node(tree, image), image_node(tree, image)
    uv_node = tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = "UVMap"
    tree.links.new(uv_node.outputs["UV"], by_name.inputs["Vector"])
    separate_default, separate_named = (tree.nodes.new("ShaderNodeSeparateColor") for _ in range(2))
    tree.links.new(by_default.outputs["Color"], separate_default.inputs["Color"])
    tree.links.new(by_name.outputs["Color"], separate_named.inputs["Color"])
    tree.links.new(separate_default.outputs["Green"], principled.inputs["Roughness"])
    tree.links.new(separate_named.outputs["Blue"], principled.inputs["Metallic"])

    (record,) = material_maps(material, source_uv="UVMap", render_uv="UVMap")

    assert record.nodes == (by_name, by_default)  # Metallic comes before Roughness among the BSDF's inputs
    assert record.uses == (("G", "roughness"), ("B", "metallic")) and record.uv_map == "UVMap"


@bpy_tests
@pytest.mark.parametrize("output", ["Generated", "Object", "Window"])
def test_an_image_on_generated_coordinates_is_left_as_is(blender, output):
    from perceptual_uv.bridge.material import base_color_image_node, read_material

    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "colour"))
    coordinates = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coordinates.outputs[output], colour.inputs["Vector"])
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])

    reading = read_material(material, source_uv="UVMap")

    assert reading.maps == ()
    assert [record.notes for record in reading.left_as_is] == [
        (f"left as is: its texture coordinates come from {output} coordinates",)]
    assert reading.left_as_is[0].uv_map is None
    assert base_color_image_node(material) is None


@bpy_tests
def test_a_mapping_node_on_the_uv_map_keeps_the_map_with_a_note(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "colour"))
    coordinates, mapping = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeMapping")
    tree.links.new(coordinates.outputs["UV"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], colour.inputs["Vector"])
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])

    (record,) = material_maps(material, source_uv="UVMap", render_uv="UVMap")

    assert (record.role, record.uv_map) == ("base_color", "UVMap")
    assert record.notes == ("its UV coordinates pass through Mapping node 'Mapping' (a texture transform)",)


@bpy_tests
def test_coordinates_from_another_image_are_left_as_is(blender):
    from perceptual_uv.bridge.material import read_material

    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "colour"))
    flow = image_node(tree, new_image(blender, "flow", data=True))
    tree.links.new(flow.outputs["Color"], colour.inputs["Vector"])
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])

    reading = read_material(material, source_uv="UVMap")

    # the flow image only feeds coordinates, not a socket of the output: it is no map of its own
    assert reading.maps == ()
    assert [(record.image.name, record.notes) for record in reading.left_as_is] == [
        ("colour", ("left as is: its texture coordinates come from image 'flow'",))]


@bpy_tests
def test_no_base_colour_image_but_a_roughness_image_is_still_a_map(blender):
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender)
    rough = image_node(tree, new_image(blender, "rough", data=True))
    tree.links.new(rough.outputs["Color"], principled.inputs["Roughness"])

    assert summary(material_maps(material, source_uv="UVMap")) == [
        ("rough", "metallic_roughness", (("RGB", "roughness"),), "Non-Color", "UVMap")]
    assert base_color_image_node(material) is None


@bpy_tests
def test_old_bug_walk_from_the_output_never_makes_a_data_image_the_base_colour(blender):
    """The old walk fell back from an unlinked Base Color to the output's Surface and returned the first image."""
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender)
    principled.inputs["Base Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    rough = image_node(tree, new_image(blender, "rough"))  # stored as sRGB: the old bake read it as colour
    normal = image_node(tree, new_image(blender, "normal", data=True))
    normal_map = tree.nodes.new("ShaderNodeNormalMap")
    tree.links.new(rough.outputs["Color"], principled.inputs["Roughness"])
    tree.links.new(normal.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], principled.inputs["Normal"])

    maps = material_maps(material, source_uv="UVMap")

    assert base_color_image_node(material) is None
    assert [(record.image.name, record.role) for record in maps] == [("rough", "metallic_roughness"),
                                                                     ("normal", "normal_tangent")]
    assert maps[0].notes == ("a metallic_roughness map stored as sRGB colour, not Non-Color data",)


@bpy_tests
def test_emission_and_unlit_materials(blender):
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender, "lit")
    glow = image_node(tree, new_image(blender, "glow"))
    tree.links.new(glow.outputs["Color"], principled.inputs["Emission Color"])
    assert summary(material_maps(material, source_uv="UVMap")) == [
        ("glow", "emissive", (("RGB", "emission"),), "sRGB", "UVMap")]

    # unlit (an Emission shader in place of the BSDF): the emissive image is the colour old callers bake
    unlit, tree, principled = new_material(blender, "unlit")
    tree.nodes.remove(principled)
    emission = tree.nodes.new("ShaderNodeEmission")
    colour = image_node(tree, new_image(blender, "colour"))
    tree.links.new(colour.outputs["Color"], emission.inputs["Color"])
    tree.links.new(emission.outputs["Emission"], tree.nodes["Material Output"].inputs["Surface"])
    assert [record.role for record in material_maps(unlit, source_uv="UVMap")] == ["emissive"]
    assert base_color_image_node(unlit) == colour


@bpy_tests
def test_channels_follow_separate_and_combine_through_per_channel_nodes(blender):
    """Image G -> Combine R -> Invert -> Separate R -> Roughness reads the image's green channel only."""
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    packed = image_node(tree, new_image(blender, "packed", data=True))
    first, second = tree.nodes.new("ShaderNodeSeparateColor"), tree.nodes.new("ShaderNodeSeparateColor")
    combine, invert = tree.nodes.new("ShaderNodeCombineColor"), tree.nodes.new("ShaderNodeInvert")
    tree.links.new(packed.outputs["Color"], first.inputs["Color"])
    tree.links.new(first.outputs["Green"], combine.inputs["Red"])
    tree.links.new(first.outputs["Blue"], combine.inputs["Green"])  # never separated again: not a use
    tree.links.new(combine.outputs["Color"], invert.inputs["Color"])
    tree.links.new(invert.outputs["Color"], second.inputs["Color"])
    tree.links.new(second.outputs["Red"], principled.inputs["Roughness"])

    (record,) = material_maps(material, source_uv="UVMap")

    assert record.uses == (("G", "roughness"),)


@bpy_tests
def test_mix_shader_factor_displacement_and_coat_are_data(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    output = tree.nodes["Material Output"]
    mask, height, coat = (image_node(tree, new_image(blender, name, data=True)) for name in ("mask", "height", "coat"))
    mix, transparent = tree.nodes.new("ShaderNodeMixShader"), tree.nodes.new("ShaderNodeBsdfTransparent")
    displacement = tree.nodes.new("ShaderNodeDisplacement")
    tree.links.new(mask.outputs["Color"], mix.inputs["Fac"])
    tree.links.new(principled.outputs["BSDF"], mix.inputs[1])
    tree.links.new(transparent.outputs["BSDF"], mix.inputs[2])
    tree.links.new(mix.outputs["Shader"], output.inputs["Surface"])
    tree.links.new(coat.outputs["Alpha"], principled.inputs["Coat Weight"])
    tree.links.new(height.outputs["Color"], displacement.inputs["Height"])
    tree.links.new(displacement.outputs["Displacement"], output.inputs["Displacement"])

    assert summary(material_maps(material, source_uv="UVMap")) == [
        ("mask", "data", (("RGB", "shader_mix_factor"),), "Non-Color", "UVMap"),
        ("coat", "data", (("A", "coat_weight"),), "Non-Color", "UVMap"),
        ("height", "data", (("RGB", "displacement_height"),), "Non-Color", "UVMap")]


@bpy_tests
def test_muted_links_and_unlinked_nodes_are_not_followed(blender):
    from perceptual_uv.bridge.material import material_maps

    material, tree, principled = new_material(blender)
    muted = image_node(tree, new_image(blender, "muted"))
    image_node(tree, new_image(blender, "loose"))
    tree.links.new(muted.outputs["Color"], principled.inputs["Base Color"]).is_muted = True
    # a muted Invert passes its Color input through to the output
    passed = image_node(tree, new_image(blender, "passed", data=True))
    invert = tree.nodes.new("ShaderNodeInvert")
    invert.mute = True
    tree.links.new(passed.outputs["Color"], invert.inputs["Color"])
    tree.links.new(invert.outputs["Color"], principled.inputs["Roughness"])

    assert [record.image.name for record in material_maps(material, source_uv="UVMap")] == ["passed"]


@bpy_tests
def test_a_tiled_image_stays_a_map_with_a_note(blender):
    """Whether UDIM tiles can move is the caller's decision (the pipeline refuses them with its own message)."""
    from perceptual_uv.bridge.material import base_color_image_node, material_maps

    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "tiles"))
    colour.image.source = "TILED"
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])

    (record,) = material_maps(material, source_uv="UVMap")

    assert record.role == "base_color" and record.notes == ("a tiled (UDIM) image: one image per UV tile",)
    assert base_color_image_node(material) == colour


@bpy_tests
def test_object_reading_fills_in_the_render_uv_map(blender):
    from perceptual_uv.bridge.material import read_object_materials

    mesh = blender.data.meshes.new("quad")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    mesh.uv_layers.new(name="UVMap")
    mesh.uv_layers.new(name="Lightmap")
    mesh.uv_layers.active = mesh.uv_layers["Lightmap"]  # the render UV map stays UVMap
    material, tree, principled = new_material(blender)
    colour = image_node(tree, new_image(blender, "colour"))
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])
    mesh.materials.append(material)
    mesh.materials.append(None)
    obj = blender.data.objects.new("quad", mesh)

    default_source, uvmap_source = read_object_materials(obj), read_object_materials(obj, source_uv="UVMap")

    assert [reading.material for reading in default_source] == [material, None]
    assert default_source[0].maps == () and default_source[0].left_as_is[0].uv_map == "UVMap"
    assert summary(uvmap_source[0].maps) == [("colour", "base_color", (("RGB", "base_color"),), "sRGB", "UVMap")]
    assert uvmap_source[1].maps == uvmap_source[1].left_as_is == ()
    with pytest.raises(ValueError, match="not a mesh"):
        read_object_materials(None)



@bpy_tests
def test_render_uv_name_is_the_render_uv_map_else_the_first(blender):
    from perceptual_uv.bridge.material import render_uv_name

    mesh = blender.data.meshes.new("quad")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0)], [], [(0, 1, 2)])
    assert render_uv_name(mesh) is None
    mesh.uv_layers.new(name="UVMap")
    mesh.uv_layers.new(name="Lightmap")
    assert render_uv_name(mesh) == "UVMap"  # the first map made is the render one
    mesh.uv_layers["Lightmap"].active_render = True
    mesh.uv_layers.active = mesh.uv_layers["UVMap"]  # the active (edited) map does not change it
    assert render_uv_name(mesh) == "Lightmap"

# ---- the shared glTF models ---------------------------------------------------------------------------------

_NORMAL = ("normal_tangent", (("RGB", "normal_tangent"),))
_BASE = ("base_color", (("RGB", "base_color"),))
_METAL_ROUGH = ("metallic_roughness", (("G", "roughness"), ("B", "metallic")))
GLTF_MATERIALS = {
    "WaterBottle/WaterBottle.gltf": {"BottleMat": {
        "WaterBottle_baseColor.png": _BASE,
        "WaterBottle_occlusionRoughnessMetallic.png": (
            "metallic_roughness", (("R", "occlusion"), ("G", "roughness"), ("B", "metallic"))),
        "WaterBottle_normal.png": _NORMAL,
        "WaterBottle_emissive.png": ("emissive", (("RGB", "emission"),))}},
    "BoomBox/BoomBox.gltf": {"BoomBox_Mat": {
        "BoomBox_baseColor.png": _BASE, "BoomBox_normal.png": _NORMAL,
        "BoomBox_emissive.png": ("emissive", (("RGB", "emission"),))}},
    "Avocado/Avocado.gltf": {"2256_Avocado_d": {
        "Avocado_baseColor.png": _BASE, "Avocado_roughnessMetallic.png": _METAL_ROUGH,
        "Avocado_normal.png": _NORMAL}},
    "sofa_03/sofa_03_1k.gltf": {
        "sofa_03": {"sofa_03_diff_1k.jpg": _BASE, "sofa_03_rough_1k.jpg": _METAL_ROUGH,
                    "sofa_03_nor_gl_1k.jpg": _NORMAL},
        "sofa_03_fringe": {"sofa_03_diff_1k.jpg": ("base_color", (("RGB", "base_color"), ("A", "alpha"))),
                           "sofa_03_rough_1k.jpg": _METAL_ROUGH, "sofa_03_nor_gl_1k.jpg": _NORMAL}},
    "tea_set_01/tea_set_01_1k.gltf": {"tea_set_01": {
        "tea_set_01_diff_1k.jpg": _BASE, "tea_set_01_arm_1k.jpg": _METAL_ROUGH, "tea_set_01_nor_gl_1k.jpg": _NORMAL}},
    "wooden_bookshelf_worn/wooden_bookshelf_worn_1k.gltf": {"wooden_bookshelf_worn": {
        "wooden_bookshelf_worn_diff_1k.jpg": _BASE, "wooden_bookshelf_worn_arm_1k.jpg": _METAL_ROUGH,
        "wooden_bookshelf_worn_nor_gl_1k.jpg": _NORMAL}},
}
_COLOUR_SPACES = {"base_color": "sRGB", "emissive": "sRGB", "metallic_roughness": "Non-Color",
                  "normal_tangent": "Non-Color"}


@bpy_tests
@pytest.mark.parametrize("model", sorted(GLTF_MATERIALS))
def test_shared_gltf_models_have_the_roles_their_files_declare(shared_models_dir, model):
    pytest.importorskip("bpy")
    from perceptual_uv.bridge.material import base_color_image_node, read_object_materials
    from perceptual_uv.bridge.mesh_io import import_model

    path = shared_models_dir / model
    if not path.is_file():
        pytest.skip(f"{path} not available")
    objects = import_model(path)

    found = {}
    for obj in (obj for obj in objects if obj.type == "MESH"):
        for reading in read_object_materials(obj):
            assert reading.left_as_is == ()
            found[reading.material.name] = {pathlib.Path(record.image.filepath).name: (record.role, record.uses)
                                            for record in reading.maps}
            for record in reading.maps:
                assert record.uv_map == "UVMap" and record.notes == ()
                assert record.colorspace == _COLOUR_SPACES[record.role]
            base = [record for record in reading.maps if record.role == "base_color"]
            assert base_color_image_node(reading.material) == base[0].node
    assert found == GLTF_MATERIALS[model]
