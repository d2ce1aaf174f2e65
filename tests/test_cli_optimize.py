"""The batch CLI on a real textured patch: .blend and .glb out, the report, bad input, interruption."""
import json
import pathlib
import signal
import subprocess
import sys
import time

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
    assert saved["size"] == [report["resolution"]] * 2 and saved["has_data"]
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

# The triangle-wise stage's first line: the signal lands in that stage (on this small patch the whole stage can take
# less than half a second). The mesh-wise stage's first line and a few hundredths of a second: the signal lands
# while a fit iterates in its thread, which a cancelled run once left running into the interpreter's shutdown
# (exit 120 in most runs).
@pytest.mark.parametrize("marker, delay", [("[triangle]", 0.0), ("Finding the textured triangles", 0.07)],
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
