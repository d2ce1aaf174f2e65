"""The batch CLI on a real textured patch: .blend and .glb out, the report, bad input, interruption."""
import json
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from test_optimize_end_to_end import FAST, spot_patch  # noqa: E402  (tests/ is on sys.path under pytest)

pytestmark = pytest.mark.bpy
FAST_ARGS = ["--iterations", str(FAST["iterations"]), "--screen-pixels", str(FAST["screen_pixels"]),
             "--max-screen-pixels", str(FAST["max_screen_pixels"]), "--workers", "1"]


@pytest.fixture(scope="module")
def patch_blend(spot_obj, tmp_path_factory):
    spot_patch(spot_obj, above=1.0)
    path = tmp_path_factory.mktemp("in") / "patch.blend"
    bpy.data.images["spot_texture.png"].pack()
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def run_cli(*args, **kwargs):
    return subprocess.run([sys.executable, "-m", "perceptual_uv", *args], capture_output=True, text=True,
                          timeout=600, **kwargs)


def inspect_blend(path):
    code = f"""
import bpy, json
bpy.ops.wm.open_mainfile(filepath={str(path)!r})
obj = bpy.data.objects["spot_triangulated"]
image = bpy.data.images["spot_texture_perceptual"]
print("JSON" + json.dumps({{"uv_layers": [l.name for l in obj.data.uv_layers], "size": list(image.size),
    "has_data": image.has_data, "original_image": "spot_texture.png" in bpy.data.images,
    "slot": obj.material_slots[0].material.name}}))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    line = next(line for line in out.stdout.splitlines() if line.startswith("JSON"))
    return json.loads(line[4:])


def test_optimize_blend_out(patch_blend, tmp_path):
    out, report_path = tmp_path / "out.blend", tmp_path / "report.json"
    result = run_cli("optimize", str(patch_blend), "--out", str(out), "--report", str(report_path), *FAST_ARGS,
                     "--cost-measure", "texels")
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"result: {out}" in result.stdout
    report = json.loads(report_path.read_text())
    assert report["uv_map"] == "PerceptualUV" and report["flipped_triangles"] == 0
    assert abs(report["relative_cost"] - 0.3) <= 0.015
    saved = inspect_blend(out)
    assert saved["uv_layers"] == ["UVMap", "PerceptualUV"]
    assert saved["size"] == report["resolution"] and saved["has_data"]
    assert saved["original_image"] and saved["slot"] == "spot_perceptual"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.blend", "report.json", "spot_texture_perceptual.png"]


def test_optimize_glb_out_carries_one_uv_set_and_the_new_image(patch_blend, tmp_path):
    out = tmp_path / "out.glb"
    result = run_cli("optimize", str(patch_blend), "--out", str(out), "--resolution", "64", *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    data = out.read_bytes()
    length = int.from_bytes(data[12:16], "little")
    gltf = json.loads(data[20:20 + length])
    attributes = gltf["meshes"][0]["primitives"][0]["attributes"]
    assert "TEXCOORD_0" in attributes and "TEXCOORD_1" not in attributes
    assert len(gltf["images"]) == 1 and gltf["images"][0]["mimeType"] == "image/png"
    # The embedded image is the new 64 x 64 one: PNG width and height sit at bytes 16-24 of the file.
    view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    start = 20 + length + 8 + view.get("byteOffset", 0)
    png = data[start:start + view["byteLength"]]
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert (int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")) == (64, 64)


def test_file_without_texture_is_refused_in_one_line(tmp_path):
    plain = tmp_path / "plain.obj"
    plain.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    result = run_cli("optimize", str(plain), "--out", str(tmp_path / "o.blend"))
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("perceptual_uv: error: ") and "image texture" in last
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.obj"]



def test_a_gltf_its_importer_fails_on_is_refused_in_one_line(tmp_path):
    """An index past the last vertex: Blender's glTF importer raises IndexError and logs its traceback to both
    streams; the CLI prints one line naming the exception and keeps the importer's messages in a file."""
    import base64
    import struct

    buffer = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<3H", 0, 1, 255) + b"\0\0"
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
            "buffers": [{"byteLength": len(buffer),
                         "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer).decode()}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                            {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 0]},
                          {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}]}
    model = tmp_path / "bad.gltf"
    model.write_text(json.dumps(gltf))

    result = run_cli("optimize", str(model), "--out", str(tmp_path / "o.glb"))

    assert result.returncode == 2
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"perceptual_uv: error: could not load {model}: the glTF importer failed on it (IndexError")
    kept = pathlib.Path(line.rsplit(" ", 1)[1])
    try:
        assert "Traceback (most recent call last)" in kept.read_text() and "IndexError" in kept.read_text()
    finally:
        kept.unlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.gltf"]

@pytest.mark.parametrize("extension, advice", [
    ("EXT_meshopt_compression", "write the file without the compression first, e.g. `npx @gltf-transform/cli copy"),
    ("ACME_gizmo", "requires the glTF extension ACME_gizmo, which Blender's glTF importer does not read"),
])
def test_a_gltf_requiring_an_extension_blender_cannot_read_is_refused_with_what_to_do(tmp_path, extension, advice):
    # glTF-Transform's test files BoxMeshopt.glb and ACMEBox.gltf failed so; a file that only declares the
    # extension required is refused by the importer before it reads a buffer
    gltf = {"asset": {"version": "2.0"}, "extensionsUsed": [extension], "extensionsRequired": [extension],
            "scene": 0, "scenes": [{"nodes": []}]}
    model = tmp_path / "required.gltf"
    model.write_text(json.dumps(gltf))

    result = run_cli("optimize", str(model), "--out", str(tmp_path / "o.glb"))

    assert result.returncode == 2 and "Traceback" not in result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"perceptual_uv: error: could not load {model}: ") and advice in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["required.gltf"]


# The triangle-wise stage's first line: the signal lands in that stage (on this small patch the whole stage can take
# less than half a second). The mesh-wise fit's first line and a few hundredths of a second: the signal lands
# while a fit iterates in its thread, which a cancelled run once left running into the interpreter's shutdown
# (exit 120 in most runs).
@pytest.mark.parametrize("marker, delay", [("[triangle]", 0.0), ("Mesh-wise fit, with and without", 0.07)],
                         ids=["triangle-wise", "mesh-wise"])
def test_sigterm_leaves_no_partial_files(patch_blend, tmp_path, marker, delay):
    out = tmp_path / "out" / "o.blend"
    process = subprocess.Popen([sys.executable, "-m", "perceptual_uv", "optimize", str(patch_blend), "--out",
                                str(out), "--report", str(tmp_path / "out" / "r.json"), *FAST_ARGS],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in process.stderr:
        if marker in line:
            break
    time.sleep(delay)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err[-2000:]
    assert "cancelled" in err
    assert not out.parent.exists() or list(out.parent.iterdir()) == []


# ---- a file whose meshes show several textures -----------------------------------------------------------------

@pytest.fixture(scope="module")
def two_textures_blend(spot_obj, tmp_path_factory):
    """The spot patch and a copy of it beside it whose material reads another image (the texture mirrored left
    to right, so that the copy shows other detail)."""
    import numpy as np

    first = spot_patch(spot_obj, above=0.9)
    second = first.copy()
    second.data = first.data.copy()
    second.name = second.data.name = "spot_mirrored"
    second.location.x += 3.0
    bpy.context.scene.collection.objects.link(second)
    image = bpy.data.images["spot_texture.png"]
    mirrored = image.copy()
    mirrored.name = "spot_mirrored.png"
    width, height = image.size
    pixels = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(pixels)
    mirrored.pixels.foreach_set(pixels.reshape(height, width, 4)[:, ::-1].ravel())
    material = first.material_slots[0].material.copy()
    material.name = "spot_mirrored"
    next(node for node in material.node_tree.nodes if node.type == "TEX_IMAGE").image = mirrored
    second.data.materials[0] = material
    image.pack()
    mirrored.pack()
    path = tmp_path_factory.mktemp("in") / "two_textures.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def test_one_run_per_texture_into_one_glb(two_textures_blend, tmp_path):
    import gltf_validate
    from test_gltf_export import buffer_view_bytes, image_size, read_glb

    out, report_path = tmp_path / "out.glb", tmp_path / "report.json"
    result = run_cli("optimize", str(two_textures_blend), "--out", str(out), "--report", str(report_path),
                     *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Texture 1 of 2 ('spot_mirrored.png' on spot_mirrored): " in result.stderr
    assert "Texture 2 of 2 ('spot_texture.png' on spot_triangulated): " in result.stderr
    report = json.loads(report_path.read_text())
    first, second = report["textures"]
    assert [first["maps"][0]["image"], second["maps"][0]["image"]] == ["spot_mirrored.png", "spot_texture.png"]
    assert report["objects"] == ["spot_mirrored", "spot_triangulated"]
    assert report["faces"] == first["faces"] + second["faces"] == 2 * first["faces"]
    assert report["image_memory"]["before"] == 2 * first["maps"][0]["raw_bytes_before"]
    gltf, binary = read_glb(out)
    by_mesh = {mesh["name"]: mesh["primitives"][0] for mesh in gltf["meshes"]}
    for texture in (first, second):
        (name,) = texture["objects"]
        primitive = by_mesh[name]
        assert "TEXCOORD_0" in primitive["attributes"] and "TEXCOORD_1" not in primitive["attributes"]
        material = gltf["materials"][primitive["material"]]
        assert [material["name"]] == texture["materials"]
        image = gltf["images"][gltf["textures"][material["pbrMetallicRoughness"]["baseColorTexture"]["index"]]
                               ["source"]]
        data, _ = buffer_view_bytes(gltf, binary, image["bufferView"])
        assert image["name"] == texture["image"] and image_size(data) == tuple(texture["resolution"])
    if gltf_validate.unavailable() is None:
        assert gltf_validate.validate(out)["errors"] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["out.glb", "report.json", "spot_mirrored_perceptual.png", "spot_texture_perceptual.png"])


def test_a_texture_that_would_be_refused_stops_the_file_before_any_run(two_textures_blend, tmp_path):
    """The second texture's object also reads the first texture on a second slot: refused before the first run,
    which would otherwise have run for nothing."""
    code = f"""
import bpy
bpy.ops.wm.open_mainfile(filepath={str(two_textures_blend)!r})
obj = bpy.data.objects["spot_triangulated"]
obj.data.materials.append(bpy.data.materials["spot_mirrored"])
bpy.ops.wm.save_as_mainfile(filepath={str(tmp_path / 'mixed.blend')!r})
"""
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)
    out = tmp_path / "out"
    out.mkdir()
    result = run_cli("optimize", str(tmp_path / "mixed.blend"), "--out", str(out / "o.glb"), *FAST_ARGS)
    assert result.returncode == 2
    assert "[triangle]" not in result.stderr and "Texture 1 of" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("perceptual_uv: error: object 'spot_triangulated' uses 2 different images")
    assert list(out.iterdir()) == []


def test_combined_report_sums_counts_and_weighs_the_bound_by_triangles():
    from perceptual_uv.bridge.texture_sets import combined_report

    def report(image, faces, within, before, after, files, uv_map, notes):
        return {"objects": [image], "faces": faces, "vertices": faces // 2, "optimized_triangles": faces,
                "skipped_triangles": 1, "unevaluated_triangles": 0, "flipped_triangles": 2, "restored_charts": 0,
                "stacked_charts": 1, "epsilon": 0.01, "target_cost": 0.3, "cost_measure": "memory", "seed": 0,
                "evaluations_per_triangle": 100, "times_s": {"triangle": 1.5, "total": 2.0},
                "overlapping_pairs": {"total": 3, "within_charts": 1, "between_charts": 2},
                "triangles_within_bound": within, "uv_map": uv_map, "image": f"{image}_perceptual",
                "image_file": f"/out/{image}_perceptual.png", "notes": notes, "warnings": [],
                "maps": [{"image": image, "raw_bytes_before": before, "raw_bytes_after": after,
                          "file_bytes_before": files[0], "file_bytes_after": files[1]}]}

    a = report("a.png", 100, 0.9, 1000, 250, (400, 100), "PerceptualUV", ["first note"])
    b = report("b.png", 300, 0.5, 3000, 600, (600, None), "PerceptualUV.001", [])

    combined = combined_report([a, b])

    assert combined["faces"] == 400 and combined["vertices"] == 200 and combined["skipped_triangles"] == 2
    assert combined["flipped_triangles"] == 4 and combined["stacked_charts"] == 2
    assert combined["triangles_within_bound"] == pytest.approx((0.9 * 100 + 0.5 * 300) / 400)  # 0.6
    assert combined["image_memory"] == {"before": 4000, "after": 850}
    assert combined["memory_ratio"] == pytest.approx(850 / 4000)
    assert combined["file_ratio"] is None  # one map's file size is unknown
    assert combined["times_s"] == {"triangle": 3.0, "total": 4.0}
    assert combined["overlapping_pairs"] == {"total": 6, "within_charts": 2, "between_charts": 4}
    assert combined["uv_map"] is None  # the runs' UV maps differ in name: each texture's report says which
    assert combined["images"] == ["a.png_perceptual", "b.png_perceptual"]
    assert combined["notes"] == ["texture 'a.png': first note"]
    assert combined["objects"] == ["a.png", "b.png"] and combined["textures"] == [a, b]
    assert combined_report([a, dict(b, uv_map="PerceptualUV")])["uv_map"] == "PerceptualUV"


def test_evaluate_measures_one_texture_of_several_at_a_time(two_textures_blend, tmp_path):
    out = tmp_path / "out.blend"
    assert run_cli("optimize", str(two_textures_blend), "--out", str(out), *FAST_ARGS).returncode == 0

    unnamed = run_cli("evaluate", str(out), "--uv", "PerceptualUV", "--costs", "0.5", "--screen", "64")
    assert unnamed.returncode == 2
    assert unnamed.stderr.strip().splitlines()[-1].endswith("evaluate one at a time with --texture IMAGE")
    unknown = run_cli("evaluate", str(out), "--uv", "PerceptualUV", "--texture", "nope.png")
    assert unknown.returncode == 2 and "no mesh shows an image 'nope.png'" in unknown.stderr

    q = q_of_each_texture(out, tmp_path)

    assert all(0 < value < 0.1 for value in q) and q[0] != q[1]  # each measured its own texture and layout


def q_of_each_texture(out, folder):
    """``evaluate --texture`` of each of the two textures at c_r 0.5 on 64 px views: q per texture."""
    q = []
    for image in ("spot_texture.png", "spot_mirrored.png"):
        run = run_cli("evaluate", str(out), "--uv", "PerceptualUV", "--texture", image, "--costs", "0.5",
                      "--screen", "64", "--json", str(folder / f"{image}.json"))
        assert run.returncode == 0, run.stderr[-2000:]
        q.append(json.loads((folder / f"{image}.json").read_text())["points"][0]["q"])
    return q


def test_a_mesh_shared_by_objects_of_two_textures_is_refused_before_any_run(two_textures_blend, tmp_path):
    code = f"""
import bpy
bpy.ops.wm.open_mainfile(filepath={str(two_textures_blend)!r})
mirrored = bpy.data.objects["spot_mirrored"]
mirrored.data = bpy.data.objects["spot_triangulated"].data
mirrored.material_slots[0].link = "OBJECT"
mirrored.material_slots[0].material = bpy.data.materials["spot_mirrored"]
bpy.ops.wm.save_as_mainfile(filepath={str(tmp_path / 'linked.blend')!r})
"""
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)
    out = tmp_path / "out"
    out.mkdir()
    result = run_cli("optimize", str(tmp_path / "linked.blend"), "--out", str(out / "o.glb"), *FAST_ARGS)
    assert result.returncode == 2 and "[triangle]" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert "mesh 'spot_triangulated' is shared by objects that show different textures" in last
    assert "'spot_mirrored' shows 'spot_mirrored.png'" in last
    assert "'spot_triangulated' shows 'spot_texture.png'" in last
    assert list(out.iterdir()) == []


@pytest.fixture(scope="module")
def two_slot_blend(two_textures_blend, tmp_path_factory):
    """The spot patch alone with its faces right of x = 0 on a second slot that shows the mirrored texture."""
    path = tmp_path_factory.mktemp("in") / "two_slots.blend"
    code = f"""
import bpy, numpy as np
bpy.ops.wm.open_mainfile(filepath={str(two_textures_blend)!r})
bpy.data.objects.remove(bpy.data.objects["spot_mirrored"])
obj = bpy.data.objects["spot_triangulated"]
obj.data.materials.append(bpy.data.materials["spot_mirrored"])
centres = np.empty(3 * len(obj.data.polygons), np.float32)
obj.data.polygons.foreach_get("center", centres)
obj.data.polygons.foreach_set("material_index", (centres.reshape(-1, 3)[:, 0] > 0).astype(np.int32))
bpy.ops.wm.save_as_mainfile(filepath={str(path)!r})
"""
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)
    return path


def test_an_object_whose_slots_show_two_textures_gets_one_uv_map_laid_out_per_texture(two_slot_blend, tmp_path):
    import gltf_validate
    from test_gltf_export import accessor, buffer_view_bytes, image_size, read_glb

    out, report_path = tmp_path / "out.glb", tmp_path / "report.json"
    result = run_cli("optimize", str(two_slot_blend), "--out", str(out), "--report", str(report_path), *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Texture 1 of 2 ('spot_mirrored.png' on spot_triangulated (slot 2)): " in result.stderr
    report = json.loads(report_path.read_text())
    assert report["objects"] == ["spot_triangulated"]
    first, second = report["textures"]
    gltf, binary = read_glb(out)
    (mesh,) = gltf["meshes"]
    assert len(mesh["primitives"]) == 2
    for primitive in mesh["primitives"]:
        assert "TEXCOORD_0" in primitive["attributes"] and "TEXCOORD_1" not in primitive["attributes"]
        material = gltf["materials"][primitive["material"]]
        texture = first if material["name"] == first["materials"][0] else second
        assert material["name"] == texture["materials"][0]
        image = gltf["images"][gltf["textures"][material["pbrMetallicRoughness"]["baseColorTexture"]["index"]]
                               ["source"]]
        data, _ = buffer_view_bytes(gltf, binary, image["bufferView"])
        assert image["name"] == texture["image"] and image_size(data) == tuple(texture["resolution"])
        uv = accessor(gltf, binary, primitive["attributes"]["TEXCOORD_0"])
        assert uv.min() >= 0 and uv.max() <= 1 and uv.max() - uv.min() > 0.5  # each layout fills its own image
    assert first["faces"] + second["faces"] == report["faces"]
    if gltf_validate.unavailable() is None:
        assert gltf_validate.validate(out)["errors"] == 0


def test_the_mesh_of_a_two_texture_object_keeps_its_data_in_a_blend(two_slot_blend, tmp_path):
    out = tmp_path / "out.blend"
    assert run_cli("optimize", str(two_slot_blend), "--out", str(out), *FAST_ARGS).returncode == 0
    code = f"""
import bpy, json, numpy as np
def state(path):
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects["spot_triangulated"]
    mesh = obj.data
    uv = np.empty(2 * len(mesh.loops), np.float32)
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv)
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    return {{"counts": [len(mesh.vertices), len(mesh.polygons), len(mesh.loops)], "uv": uv.tolist(),
             "co": co.tolist(), "layers": [layer.name for layer in mesh.uv_layers],
             "mesh_materials": [m.name for m in mesh.materials],
             "slots": [(slot.link, slot.material.name) for slot in obj.material_slots],
             "objects": sorted(o.name for o in bpy.data.objects)}}
print("JSON" + json.dumps([state({str(two_slot_blend)!r}), state({str(out)!r})]))
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    before, after = json.loads(next(line for line in run.stdout.splitlines() if line.startswith("JSON"))[4:])
    for key in ("counts", "uv", "co", "mesh_materials", "objects"):
        assert after[key] == before[key], key
    assert after["layers"] == ["UVMap", "PerceptualUV"]
    assert after["slots"] == [["OBJECT", "spot_perceptual"], ["OBJECT", "spot_mirrored_perceptual"]]


def test_evaluate_measures_each_texture_of_an_object_on_its_own_faces(two_slot_blend, tmp_path):
    out = tmp_path / "out.blend"
    assert run_cli("optimize", str(two_slot_blend), "--out", str(out), *FAST_ARGS).returncode == 0

    unnamed = run_cli("evaluate", str(out), "--uv", "PerceptualUV", "--costs", "0.5", "--screen", "64")
    assert unnamed.returncode == 2
    assert "spot_texture.png: spot_triangulated (slot 1)" in unnamed.stderr
    q = q_of_each_texture(out, tmp_path)

    assert all(0 < value < 0.1 for value in q) and q[0] != q[1]


@pytest.fixture(scope="module")
def patch_fbx(spot_obj, tmp_path_factory):
    """The patch as an FBX file with a light (as exports from other programs have), its texture in a subfolder
    that the file names by its absolute path and by a relative one."""
    import shutil

    obj = spot_patch(spot_obj, above=1.0)
    folder = tmp_path_factory.mktemp("fbx")
    (folder / "maps").mkdir()
    shutil.copy(spot_obj.parent / "spot_texture.png", folder / "maps" / "spot_texture.png")
    bpy.data.images["spot_texture.png"].filepath = str(folder / "maps" / "spot_texture.png")
    light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    bpy.context.scene.collection.objects.link(light)
    obj.select_set(True)
    path = folder / "patch.fbx"
    bpy.ops.export_scene.fbx(filepath=str(path), path_mode="RELATIVE")
    return path


def test_an_fbx_file_with_a_light_is_optimized(patch_fbx, tmp_path):
    """Blender 5.0's FBX importer failed on any light (it sets a Cycles setting 5.0 no longer has)."""
    from perceptual_uv.bridge.mesh_io import import_model
    from perceptual_uv.library_batch.inputs import external_files

    assert external_files(patch_fbx) == [patch_fbx.parent / "maps" / "spot_texture.png"]
    objects = import_model(patch_fbx)
    assert sorted(obj.type for obj in objects) == ["LIGHT", "MESH"]
    light_settings = type(bpy.data.lights["Lamp"].cycles)
    assert "cast_shadow" not in light_settings.bl_rna.properties  # the importer's setting is gone again

    out, report_path = tmp_path / "out.glb", tmp_path / "report.json"
    result = run_cli("optimize", str(patch_fbx), "--out", str(out), "--report", str(report_path), *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(report_path.read_text())
    assert report["uv_map"] == "PerceptualUV" and report["maps"][0]["image"] == "spot_texture.png"
    import gltf_validate

    reason = gltf_validate.unavailable()
    if reason:
        pytest.skip(reason)
    assert gltf_validate.validate(out)["errors"] == 0


@pytest.fixture(scope="module")
def patch_usd(spot_obj, tmp_path_factory):
    """The patch as a binary USD layer with its texture in textures/ beside it, and a text layer that references
    the binary one."""
    spot_patch(spot_obj, above=1.0)
    folder = tmp_path_factory.mktemp("usd")
    bpy.ops.wm.usd_export(filepath=str(folder / "patch.usdc"), export_textures_mode="NEW")
    (folder / "scene.usda").write_text('#usda 1.0\n\ndef "Patch" (\n    references = @./patch.usdc@\n)\n{\n}\n')
    return folder


def test_a_usd_layer_is_optimized_and_its_files_are_the_layers_and_images_it_names(patch_usd, tmp_path):
    from perceptual_uv.library_batch.inputs import external_files

    texture = patch_usd / "textures" / "spot_texture.png"
    assert external_files(patch_usd / "patch.usdc") == [texture]  # an asset path in the crate's LZ4 tokens
    assert external_files(patch_usd / "scene.usda") == [patch_usd / "patch.usdc", texture]
    out, report_path = tmp_path / "out.glb", tmp_path / "report.json"
    result = run_cli("optimize", str(patch_usd / "patch.usdc"), "--out", str(out), "--report", str(report_path),
                     *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(report_path.read_text())
    assert report["source_uv_map"] == "st" and report["maps"][0]["image"] == "spot_texture.png"


def test_an_ascii_fbx_is_refused_in_one_line_that_says_what_to_do(tmp_path):
    path = tmp_path / "box.fbx"
    path.write_text('; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n\tFBXHeaderVersion: 1003\n}\n')
    result = run_cli("optimize", str(path), "--out", str(tmp_path / "out.glb"))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "ASCII FBX files are not supported" in lines[0]
    assert "save the file as binary FBX" in lines[0]


def test_an_fbx_output_holds_the_new_uv_map_alone_the_copies_and_the_new_image(patch_fbx, tmp_path):
    from perceptual_uv.bridge.mesh_io import import_model

    out, report_path = tmp_path / "out.fbx", tmp_path / "report.json"
    result = run_cli("optimize", str(patch_fbx), "--out", str(out), "--report", str(report_path), *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(report_path.read_text())

    objects = import_model(out)
    assert sorted(obj.type for obj in objects) == ["LIGHT", "MESH"]  # the scene as it was
    (obj,) = [obj for obj in objects if obj.type == "MESH"]
    mesh = obj.data
    assert [layer.name for layer in mesh.uv_layers] == ["PerceptualUV"] and not mesh.color_attributes
    images = [node.image for node in obj.material_slots[0].material.node_tree.nodes if node.type == "TEX_IMAGE"]
    assert [(image.name, tuple(image.size), image.packed_file is not None) for image in images] == [
        ("spot_texture_perceptual", tuple(report["resolution"]), True)]  # embedded
    # The UV set is the packed new UV map: its triangles cover what the report measured on it.
    uv = np.empty(2 * len(mesh.loops), dtype=np.float64)
    mesh.uv_layers[0].uv.foreach_get("vector", uv)
    mesh.calc_loop_triangles()
    corners = np.empty(3 * len(mesh.loop_triangles), dtype=np.int64)
    mesh.loop_triangles.foreach_get("loops", corners)
    triangles = uv.reshape(-1, 2)[corners.reshape(-1, 3)]
    edges = triangles[:, 1:] - triangles[:, :1]
    area = 0.5 * np.abs(edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]).sum()
    assert area == pytest.approx(report["image_coverage"], rel=1e-3)


def test_an_fbx_output_leaves_out_the_bone_shapes_the_gltf_importer_made(empty_scene, tmp_path):
    from perceptual_uv.bridge.fbx_export import GLTF_NOT_EXPORTED, export_fbx
    from perceptual_uv.bridge.mesh_io import import_model

    for name in ("Body", "Icosphere"):
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
        bpy.data.objects.new(name, mesh)
    empty_scene.collection.objects.link(bpy.data.objects["Body"])
    shapes = bpy.data.collections.new(GLTF_NOT_EXPORTED)  # as the glTF importer keeps a bone's shape
    empty_scene.collection.children.link(shapes)
    shapes.objects.link(bpy.data.objects["Icosphere"])

    export_fbx([], tmp_path / "out.fbx")

    assert [child.name for child in empty_scene.collection.children] == [GLTF_NOT_EXPORTED]  # linked back
    assert [obj.name for obj in import_model(tmp_path / "out.fbx")] == ["Body"]
