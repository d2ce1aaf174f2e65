"""What a .glb written by ``optimize --out X.glb`` keeps (issue 23, "Must show" item 4).

The whole input scene (nodes, empties, lights, cameras, other meshes, skins with their joints and weights,
animations), the new UV map as the optimized meshes' only texture coordinates, the new baked image in their
material, no loss-overlay colours, and 0 errors from the Khronos glTF validator.
"""
import json
import math
import pathlib
import struct
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
bmesh = pytest.importorskip("bmesh")

import gltf_validate  # noqa: E402  (tests/ is on sys.path under pytest)
from conftest import reset_blender_scene  # noqa: E402

pytestmark = pytest.mark.bpy
FAST_ARGS = ["--iterations", "10", "--screen-pixels", "32", "--max-screen-pixels", "32", "--workers", "1"]
COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}


# --- reading a .glb / .gltf with the standard library and numpy -------------------------------------------

def read_glb(path):
    """The JSON chunk (dict) and the BIN chunk (bytes) of a .glb."""
    data = pathlib.Path(path).read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    json_length, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON"
    gltf = json.loads(data[20:20 + json_length])
    binary = b""
    offset = 20 + json_length
    if offset < len(data):
        bin_length, bin_type = struct.unpack_from("<I4s", data, offset)
        assert bin_type == b"BIN\x00"
        binary = data[offset + 8:offset + 8 + bin_length]
    return gltf, binary


def read_input_json(path):
    path = pathlib.Path(path)
    return read_glb(path)[0] if path.suffix.lower() == ".glb" else json.loads(path.read_text())


def buffer_view_bytes(gltf, binary, index):
    view = gltf["bufferViews"][index]
    start = view.get("byteOffset", 0)
    return binary[start:start + view["byteLength"]], view.get("byteStride")


def accessor(gltf, binary, index):
    """An accessor's elements as an (count, components) array (not sparse, not normalized)."""
    acc = gltf["accessors"][index]
    dtype = np.dtype(DTYPES[acc["componentType"]])
    width = COMPONENTS[acc["type"]]
    data, stride = buffer_view_bytes(gltf, binary, acc["bufferView"])
    start, count = acc.get("byteOffset", 0), acc["count"]
    stride = stride or dtype.itemsize * width
    rows = np.lib.stride_tricks.as_strided(np.frombuffer(data, dtype=np.uint8, offset=start,
                                                         count=(count - 1) * stride + dtype.itemsize * width),
                                           shape=(count, dtype.itemsize * width), strides=(stride, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(count, width)


def image_size(data):
    """(width, height) of PNG or JPEG bytes."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return struct.unpack(">II", data[16:24])
    assert data[:2] == b"\xff\xd8", "neither PNG nor JPEG"
    offset = 2
    while offset < len(data):
        marker, length = data[offset + 1], struct.unpack(">H", data[offset + 2:offset + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2):
            height, width = struct.unpack(">HH", data[offset + 5:offset + 9])
            return width, height
        offset += 2 + length
    raise AssertionError("no JPEG frame header")


def counts(gltf):
    """What the whole-scene checks compare between the input and the output."""
    lights = gltf.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    return {"nodes": len(gltf.get("nodes", [])), "skins": len(gltf.get("skins", [])),
            "joints": sorted(len(skin["joints"]) for skin in gltf.get("skins", [])),
            "animations": len(gltf.get("animations", [])), "cameras": len(gltf.get("cameras", [])),
            "lights": len(lights), "meshes": len(gltf.get("meshes", [])),
            "skinned_nodes": sum("skin" in node for node in gltf.get("nodes", []))}


def colour_attributes(gltf):
    return {name for mesh in gltf.get("meshes", []) for primitive in mesh["primitives"]
            for name in primitive["attributes"] if name.startswith("COLOR_")}


# --- the checks --------------------------------------------------------------------------------------------

def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "perceptual_uv", *args], capture_output=True, text=True,
                          timeout=900)


def optimize_to_glb(model, folder, *extra):
    out, report_path = folder / "out.glb", folder / "report.json"
    result = run_cli("optimize", str(model), "--out", str(out), "--report", str(report_path), *FAST_ARGS, *extra)
    assert result.returncode == 0, result.stderr[-3000:]
    return out, json.loads(report_path.read_text())


def check_export(input_path, out, report):
    """The structure the brief asks for, on one optimized .glb (its input at ``input_path``)."""
    source = read_input_json(input_path)
    gltf, binary = read_glb(out)
    assert counts(gltf) == counts(source)
    assert colour_attributes(gltf) <= colour_attributes(source)  # no COLOR_n the input did not have

    names = set(report["objects"])
    optimized = [node for node in gltf["nodes"] if node.get("name") in names and "mesh" in node]
    assert len(optimized) == len(names)
    for node in optimized:
        skinned = "skin" in node
        area = 0.0
        for primitive in gltf["meshes"][node["mesh"]]["primitives"]:
            attributes = primitive["attributes"]
            assert "TEXCOORD_0" in attributes and not any(
                name.startswith("TEXCOORD_") and name != "TEXCOORD_0" for name in attributes), attributes
            # tangents where a normal map needs them (baked in the new UV map's frame), none otherwise
            assert ("TANGENT" in attributes) == any("normalTexture" in m for m in gltf.get("materials", []))
            if skinned:
                assert "JOINTS_0" in attributes and "WEIGHTS_0" in attributes
            material = gltf["materials"][primitive["material"]]
            base = material["pbrMetallicRoughness"]["baseColorTexture"]
            assert base.get("texCoord", 0) == 0
            image = gltf["images"][gltf["textures"][base["index"]]["source"]]
            assert image["name"] == pathlib.Path(report["image"]).stem
            data, _ = buffer_view_bytes(gltf, binary, image["bufferView"])
            assert image_size(data) == tuple(report["resolution"])
            # TEXCOORD_0 is the packed new UV map: its triangles cover what the report measured on it.
            uv = accessor(gltf, binary, attributes["TEXCOORD_0"]).astype(np.float64)
            triangles = uv[accessor(gltf, binary, primitive["indices"]).reshape(-1, 3)]
            edges = triangles[:, 1:] - triangles[:, :1]
            area += 0.5 * np.abs(edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]).sum()
        if len(optimized) == 1:
            assert area == pytest.approx(report["image_coverage"], rel=1e-3)
    return gltf


def check_validator(input_path, out):
    """0 errors from the Khronos validator, and no kind of warning that the input did not have already."""
    reason = gltf_validate.unavailable()
    if reason:
        pytest.skip(reason)
    validated = gltf_validate.validate(out)
    errors = [m for m in validated["messages"] if m["severity"] == 0]
    assert validated["errors"] == 0, errors[:5]
    source_warnings = {m["code"] for m in gltf_validate.validate(input_path)["messages"] if m["severity"] == 1}
    assert {m["code"] for m in validated["messages"] if m["severity"] == 1} <= source_warnings
    return validated


# --- inputs ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def spot_scene(spot_obj, tmp_path_factory):
    """A .glb scene around a patch of the bundled spot: an animated parent empty, an animated armature that skins
    the patch, an untextured mesh, a light and a camera, none of which the run optimizes."""
    reset_blender_scene()
    bpy.ops.wm.obj_import(filepath=str(spot_obj))
    spot = bpy.data.objects["spot_triangulated"]
    bm = bmesh.new()
    bm.from_mesh(spot.data)
    bmesh.ops.delete(bm, geom=[f for f in bm.faces if f.calc_center_median().z < 1.0], context="FACES")
    bm.to_mesh(spot.data)
    bm.free()
    # Smooth shading lets the exporter share vertices between triangles; flat-shaded, every triangle is written
    # apart and comes back as its own UV island (slow to pack, and not what a real asset looks like).
    spot.data.shade_smooth()
    scene = bpy.context.scene
    root = bpy.data.objects.new("Root", None)
    scene.collection.objects.link(root)
    spot.parent = root
    root.location = (0.0, 0.0, 0.0)
    root.keyframe_insert("location", frame=1)
    root.location = (0.0, 0.5, 0.0)
    root.keyframe_insert("location", frame=10)
    # A two-bone rig under the root, skinning the patch (lower half to one bone, upper half to the other), with
    # a bone animation of its own.
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    scene.collection.objects.link(rig)
    rig.parent = root
    bpy.context.view_layer.objects.active = rig
    with bpy.context.temp_override(active_object=rig, object=rig, selected_objects=[rig]):
        bpy.ops.object.mode_set(mode="EDIT")
        lower = rig.data.edit_bones.new("Lower")
        lower.head, lower.tail = (0.0, 0.0, 0.8), (0.0, 0.0, 1.1)
        upper = rig.data.edit_bones.new("Upper")
        upper.head, upper.tail, upper.parent = (0.0, 0.0, 1.1), (0.0, 0.0, 1.4), lower
        bpy.ops.object.mode_set(mode="OBJECT")
    spot.parent = rig
    heights = [vertex.co.z for vertex in spot.data.vertices]
    middle = sorted(heights)[len(heights) // 2]
    for bone, chosen in (("Lower", [i for i, z in enumerate(heights) if z < middle]),
                         ("Upper", [i for i, z in enumerate(heights) if z >= middle])):
        spot.vertex_groups.new(name=bone).add(chosen, 1.0, "REPLACE")
    spot.modifiers.new("Armature", "ARMATURE").object = rig
    pose_bone = rig.pose.bones["Upper"]
    pose_bone.rotation_mode = "XYZ"
    pose_bone.rotation_euler = (0.0, 0.0, 0.0)
    pose_bone.keyframe_insert("rotation_euler", frame=1)
    pose_bone.rotation_euler = (0.3, 0.0, 0.0)
    pose_bone.keyframe_insert("rotation_euler", frame=10)
    crate = bpy.data.objects.new("Crate", bpy.data.meshes.new("Crate"))
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=0.3)
    bm.to_mesh(crate.data)
    bm.free()
    crate.data.materials.append(bpy.data.materials.new("Plain"))
    crate.location = (1.0, 0.0, 0.0)
    scene.collection.objects.link(crate)
    for name, data in (("Lamp", bpy.data.lights.new("Lamp", "POINT")), ("Eye", bpy.data.cameras.new("Eye"))):
        obj = bpy.data.objects.new(name, data)
        obj.location = (0.0, -3.0, 1.0)
        scene.collection.objects.link(obj)
    path = tmp_path_factory.mktemp("scene") / "spot_scene.glb"
    bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", export_lights=True, export_cameras=True)
    reset_blender_scene()
    source = counts(read_glb(path)[0])
    assert source["skins"] == 1 and source["joints"] == [2] and source["animations"] >= 1, source
    assert source["lights"] == 1 and source["cameras"] == 1, source
    return path


@pytest.fixture(scope="module")
def cesium_man(shared_models_dir):
    path = shared_models_dir / "CesiumMan" / "CesiumMan.gltf"
    if not path.is_file():
        pytest.skip(f"{path} is not available")
    return path


@pytest.fixture(scope="module")
def spot_run(spot_scene, tmp_path_factory):
    return optimize_to_glb(spot_scene, tmp_path_factory.mktemp("spot_run"))


@pytest.fixture(scope="module")
def cesium_run(cesium_man, tmp_path_factory):
    # An explicit resolution packs once (the run's slowest part after the triangle-wise stage).
    return optimize_to_glb(cesium_man, tmp_path_factory.mktemp("cesium_run"), "--resolution", "256")


# --- tests -------------------------------------------------------------------------------------------------

def test_validator_helper_reports_errors_of_a_broken_file(tmp_path):
    reason = gltf_validate.unavailable()
    if reason:
        pytest.skip(reason)
    broken = tmp_path / "broken.gltf"
    broken.write_text(json.dumps({"asset": {"version": "2.0"}, "nodes": [{"mesh": 3}]}))
    result = gltf_validate.validate(broken)
    assert result["errors"] >= 1 and any(m["severity"] == 0 for m in result["messages"])


def test_spot_scene_keeps_every_object(spot_scene, spot_run):
    out, report = spot_run
    assert report["objects"] == ["spot_triangulated"]
    gltf = check_export(spot_scene, out, report)
    names = {node.get("name") for node in gltf["nodes"]}
    assert {"Root", "Rig", "Lower", "Upper", "Crate", "Lamp", "Eye", "spot_triangulated"} <= names
    # The untextured mesh is exported as it was: its own material, no baked image.
    crate = next(node for node in gltf["nodes"] if node.get("name") == "Crate")
    assert gltf["materials"][gltf["meshes"][crate["mesh"]]["primitives"][0]["material"]]["name"] == "Plain"
    assert len(gltf["images"]) == 1


def test_spot_scene_glb_passes_the_validator(spot_scene, spot_run):
    check_validator(spot_scene, spot_run[0])


@pytest.mark.slow  # ~45-60 s on 2 shared cores: the whole 4672-triangle run
def test_cesium_man_keeps_skin_joints_weights_and_animation(cesium_man, cesium_run):
    out, report = cesium_run
    gltf = check_export(cesium_man, out, report)
    assert counts(gltf)["nodes"] == 22 and counts(gltf)["joints"] == [19] and counts(gltf)["animations"] == 1


@pytest.mark.slow  # ~45-60 s on 2 shared cores: the whole 4672-triangle run
def test_cesium_man_glb_passes_the_validator(cesium_man, cesium_run):
    # The input itself has 210 errors (joint weights that do not sum to 1); Blender's exporter normalizes them.
    check_validator(cesium_man, cesium_run[0])


def test_export_glb_uses_copies_and_leaves_the_scene_as_it_was(empty_scene, tmp_path):
    """Without a run: two objects sharing a mesh (only the first has the material copy, as the pipeline leaves
    them), the overlay attributes, a second UV map and an animated shape key. The .glb gets one mesh on the new
    UV map with the copy; afterwards the file's data are exactly as before."""
    from types import SimpleNamespace

    from perceptual_uv.bridge.gltf_export import export_glb
    from perceptual_uv.bridge.loss_overlay import LOSS_ATTRIBUTE, LOSS_COLOR_ATTRIBUTE

    mesh = bpy.data.meshes.new("Box")
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")
    bmesh.ops.create_cube(bm, size=1.0, calc_uvs=True)
    bm.to_mesh(mesh)
    bm.free()
    mesh.uv_layers.new(name="PerceptualUV")
    mesh.attributes.new(LOSS_ATTRIBUTE, "FLOAT", "FACE")
    mesh.attributes.new(LOSS_COLOR_ATTRIBUTE, "BYTE_COLOR", "CORNER")
    images, materials = {}, {}
    for name, size in (("old", 32), ("new", 16)):
        images[name] = bpy.data.images.new(f"{name}_image", size, size)
        images[name].pack()  # the exporter embeds pixels from packed or saved images
        material = bpy.data.materials.new("Box" if name == "old" else "Box_perceptual")
        tree = material.node_tree
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image = images[name]
        tree.links.new(texture.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
        if name == "new":
            uv_node = tree.nodes.new("ShaderNodeUVMap")
            uv_node.uv_map = "PerceptualUV"
            tree.links.new(uv_node.outputs["UV"], texture.inputs["Vector"])
        materials[name] = material
    mesh.materials.append(materials["old"])
    first, second = (bpy.data.objects.new(name, mesh) for name in ("First", "Second"))
    for obj in (first, second):
        empty_scene.collection.objects.link(obj)
    first.material_slots[0].link = "OBJECT"
    first.material_slots[0].material = materials["new"]
    first.shape_key_add(name="Basis")
    key = first.shape_key_add(name="Bulge")
    key.value = 0.0
    key.keyframe_insert("value", frame=1)
    key.value = 1.0
    key.keyframe_insert("value", frame=10)
    before = {"meshes": sorted(m.name for m in bpy.data.meshes), "keys": len(bpy.data.shape_keys),
              "actions": len(bpy.data.actions), "uv": [layer.name for layer in mesh.uv_layers],
              "attributes": sorted(a.name for a in mesh.attributes), "data": [first.data, second.data],
              "slots": [(s.link, s.material.name) for o in (first, second) for s in o.material_slots]}

    out = tmp_path / "box.glb"
    export_glb([([first, second], SimpleNamespace(uv_map="PerceptualUV", materials=[materials["new"]]))], out)

    after = {"meshes": sorted(m.name for m in bpy.data.meshes), "keys": len(bpy.data.shape_keys),
             "actions": len(bpy.data.actions), "uv": [layer.name for layer in mesh.uv_layers],
             "attributes": sorted(a.name for a in mesh.attributes), "data": [first.data, second.data],
             "slots": [(s.link, s.material.name) for o in (first, second) for s in o.material_slots]}
    assert after == before
    gltf, binary = read_glb(out)
    nodes = {node["name"]: node for node in gltf["nodes"]}
    assert nodes["First"]["mesh"] == nodes["Second"]["mesh"]
    (mesh_json,) = gltf["meshes"]
    assert mesh_json["name"] == "Box" and len(mesh_json["weights"]) == 1
    for primitive in mesh_json["primitives"]:
        assert {name for name in primitive["attributes"] if name.startswith(("TEXCOORD_", "COLOR_"))} == {
            "TEXCOORD_0"}
        assert "TANGENT" not in primitive["attributes"] and len(primitive["targets"]) == 1  # no normal map
        assert gltf["materials"][primitive["material"]]["name"] == "Box_perceptual"
    assert [image["name"] for image in gltf["images"]] == ["new_image"]
    assert len(gltf.get("animations", [])) == 1
    reason = gltf_validate.unavailable()
    if reason is None:
        assert gltf_validate.validate(out)["errors"] == 0



# A triangle of DamagedHelmet (glTF-Sample-Assets) after a run, glTF's y-up coordinates: its UV area is 1.2e-8, and
# MikkTSpace leaves its third corner without a tangent, (0, 0, 0, 1), which the validator reports as an error.
HELMET_CORNERS = np.array([[-0.9138807058334351, -0.6013648509979248, 0.1041320413351059],
                           [-0.9130095839500427, -0.601050853729248, 0.10783304274082184],
                           [-0.944661557674408, -0.6124428510665894, -0.02745436131954193]], dtype=np.float32)
HELMET_UVS = np.array([[0.9884565472602844, 0.9734083414077759], [0.9889580011367798, 0.9728500843048096],
                       [0.970609724521637, 0.9932299852371216]], dtype=np.float32)


def test_a_corner_without_a_tangent_gets_a_unit_one_in_the_glb(empty_scene, tmp_path):
    from types import SimpleNamespace

    from perceptual_uv.bridge.gltf_export import export_glb

    corners = HELMET_CORNERS[:, [0, 2, 1]] * np.array([1, -1, 1], dtype=np.float32)  # y-up to Blender's z-up
    mesh = bpy.data.meshes.new("Sliver")
    mesh.from_pydata(corners.tolist(), [], [(0, 1, 2)])
    layer = mesh.uv_layers.new(name="PerceptualUV")
    layer.uv.foreach_set("vector", np.stack([HELMET_UVS[:, 0], 1 - HELMET_UVS[:, 1]], axis=1).ravel())
    material = bpy.data.materials.new("Bumps")  # a normal map: the file needs tangents
    normal_image = bpy.data.images.new("bumps", 4, 4)
    normal_image.pack()
    texture = material.node_tree.nodes.new("ShaderNodeTexImage")
    texture.image = normal_image
    normal_map = material.node_tree.nodes.new("ShaderNodeNormalMap")
    material.node_tree.links.new(texture.outputs["Color"], normal_map.inputs["Color"])
    principled = material.node_tree.nodes["Principled BSDF"]
    material.node_tree.links.new(normal_map.outputs["Normal"], principled.inputs["Normal"])
    mesh.materials.append(material)
    obj = bpy.data.objects.new("Sliver", mesh)
    empty_scene.collection.objects.link(obj)
    out = tmp_path / "sliver.glb"

    export_glb([([obj], SimpleNamespace(uv_map="PerceptualUV", materials=[]))], out)

    gltf, binary = read_glb(out)
    (primitive,) = gltf["meshes"][0]["primitives"]
    normals = accessor(gltf, binary, primitive["attributes"]["NORMAL"])
    tangents = accessor(gltf, binary, primitive["attributes"]["TANGENT"])
    np.testing.assert_allclose(np.linalg.norm(tangents[:, :3], axis=1), 1.0, atol=1e-4)  # Blender rounds
    np.testing.assert_allclose(np.abs(tangents[:, 3]), 1.0)
    np.testing.assert_allclose(np.sum(tangents[:, :3] * normals, axis=1), 0.0, atol=1e-3)
    # The corners MikkTSpace did give a tangent keep it: dP/du by hand, made orthogonal to the face normal.
    p, uv = HELMET_CORNERS.astype(float), HELMET_UVS.astype(float) * [1, -1]  # glTF's v runs down
    (du1, dv1), (du2, dv2) = uv[1] - uv[0], uv[2] - uv[0]
    along_u = ((p[1] - p[0]) * dv2 - (p[2] - p[0]) * dv1) / (du1 * dv2 - du2 * dv1)
    normal = np.cross(p[1] - p[0], p[2] - p[0])
    normal /= np.linalg.norm(normal)
    along_u -= along_u.dot(normal) * normal
    np.testing.assert_allclose(tangents[:2, :3], np.tile(along_u / np.linalg.norm(along_u), (2, 1)), atol=1e-2)
    reason = gltf_validate.unavailable()
    if reason is None:
        assert gltf_validate.validate(out)["errors"] == 0


def test_a_map_left_on_another_uv_map_keeps_its_coordinates_after_the_new_ones(empty_scene, tmp_path):
    """An occlusion image read through a second UV map ("AO") is left as it is by a run; the .glb must still read
    it through that UV map: TEXCOORD_0 the new UV map, TEXCOORD_1 "AO" (each corner's pair of coordinates as in
    Blender), the occlusion texture on texCoord 1, the replaced UV map gone, the validator clean."""
    from types import SimpleNamespace

    from perceptual_uv.bridge.gltf_export import export_glb

    mesh = bpy.data.meshes.new("Panel")
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=3, y_segments=2, size=1.0)
    bm.to_mesh(mesh)
    bm.free()
    rng = np.random.default_rng(2)
    for name in ("UVMap", "AO", "PerceptualUV"):
        mesh.uv_layers.new(name=name).uv.foreach_set("vector", rng.random(2 * len(mesh.loops)).astype(np.float32))
    material = bpy.data.materials.new("Panel_perceptual")
    tree = material.node_tree
    images = {}
    for name, uv_name in (("colour", "PerceptualUV"), ("occlusion", "AO")):
        images[name] = bpy.data.images.new(name, 4, 4)
        images[name].pack()
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image = images[name]
        coordinates = tree.nodes.new("ShaderNodeUVMap")
        coordinates.uv_map = uv_name
        tree.links.new(coordinates.outputs["UV"], texture.inputs["Vector"])
        if name == "colour":
            tree.links.new(texture.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
        else:
            images[name].colorspace_settings.name = "Non-Color"
            separate = tree.nodes.new("ShaderNodeSeparateColor")
            tree.links.new(texture.outputs["Color"], separate.inputs["Color"])
            group = bpy.data.node_groups.new("glTF Material Output", "ShaderNodeTree")
            group.interface.new_socket("Occlusion", in_out="INPUT", socket_type="NodeSocketFloat")
            output = tree.nodes.new("ShaderNodeGroup")
            output.node_tree = group
            tree.links.new(separate.outputs["Red"], output.inputs["Occlusion"])
    mesh.materials.append(material)
    obj = bpy.data.objects.new("Panel", mesh)
    empty_scene.collection.objects.link(obj)
    out = tmp_path / "panel.glb"

    export_glb([([obj], SimpleNamespace(uv_map="PerceptualUV", materials=[material]))], out)

    gltf, binary = read_glb(out)
    (primitive,) = gltf["meshes"][0]["primitives"]
    assert {name for name in primitive["attributes"] if name.startswith("TEXCOORD_")} == {"TEXCOORD_0", "TEXCOORD_1"}
    assert gltf["materials"][0]["occlusionTexture"].get("texCoord", 0) == 1
    assert gltf["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"].get("texCoord", 0) == 0
    pairs = np.hstack([accessor(gltf, binary, primitive["attributes"][name]) for name in ("TEXCOORD_0", "TEXCOORD_1")])
    pairs[:, [1, 3]] = 1 - pairs[:, [1, 3]]  # glTF's v runs down
    corners = np.hstack([np.array([tuple(loop.uv) for loop in mesh.uv_layers[name].data]) for name in
                         ("PerceptualUV", "AO")])
    # every exported vertex is some corner's pair, and every corner's pair is exported (up to float32 rounding)
    distance = np.abs(pairs[:, None, :] - corners[None, :, :]).max(axis=2)
    assert distance.min(axis=1).max() < 1e-6 and distance.min(axis=0).max() < 1e-6
    assert [layer.name for layer in mesh.uv_layers] == ["UVMap", "AO", "PerceptualUV"]  # the user's mesh as it was
    reason = gltf_validate.unavailable()
    if reason is None:
        assert gltf_validate.validate(out)["errors"] == 0


def test_a_light_whose_power_is_not_normalized_exports_the_power_it_gives(empty_scene, tmp_path):
    """USD's lights come in with ``normalize`` off (power = energy x area); Blender 5.0's exporter failed on them.
    A point light of radius 0.5 m (a sphere of area 4 pi 0.5^2 = pi m^2) and 100 W not normalized gives what a
    normalized one of 100 pi W gives."""
    from perceptual_uv.bridge.gltf_export import export_glb

    def scene_with(energy, normalize, out):
        reset_blender_scene()
        light = bpy.data.lights.new("Bulb", "POINT")
        light.shadow_soft_size, light.energy, light.normalize = 0.5, energy, normalize
        bpy.context.scene.collection.objects.link(bpy.data.objects.new("Bulb", light))
        export_glb([], out)
        return light

    light = scene_with(100.0, False, tmp_path / "raw.glb")
    assert (light.energy, light.normalize) == (100.0, False)  # the user's light is left as it was
    scene_with(100.0 * math.pi, True, tmp_path / "normalized.glb")
    (raw,), (normalized,) = (read_glb(tmp_path / name)[0]["extensions"]["KHR_lights_punctual"]["lights"]
                             for name in ("raw.glb", "normalized.glb"))
    assert raw["intensity"] == pytest.approx(normalized["intensity"], rel=1e-6) and normalized["intensity"] > 0
