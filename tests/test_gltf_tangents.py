"""core.gltf_tangents: tangents MikkTSpace could not compute made unit, in place, on a hand-built .glb."""
import json
import struct

import numpy as np
import pytest

from perceptual_uv.core.gltf_tangents import repair_tangents

# Per vertex: normal (3 floats) then tangent (4 floats), interleaved in one buffer view (stride 28 bytes).
NORMALS = np.array([[0, 0, 1], [0, 0, 1], [1, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
TANGENTS = np.array([[1, 0, 0, 1],          # already right: its bytes stay
                     [0, 0, 0, 1],          # MikkTSpace's "no tangent" on a zero-area UV triangle
                     [0, 0, 0, -1],         # the same, normal along x, sign kept
                     [0, 2, 0, -1],         # not unit: normalized
                     [0, 0.6, 0.8, 0],      # unit, W not a sign: +1
                     [np.nan, 0, 0, 1]],    # not finite
                    dtype=np.float32)
# By hand: the axis least aligned with the normal (the first on a tie), made orthogonal to it.
EXPECTED = np.array([[1, 0, 0, 1], [1, 0, 0, 1], [0, 1, 0, -1], [0, 1, 0, -1], [0, 0.6, 0.8, 1], [1, 0, 0, 1]],
                    dtype=np.float32)


def write_glb(path, normals, tangents):
    interleaved = np.concatenate([normals, tangents], axis=1).astype(np.float32).tobytes()
    count = len(normals)
    document = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(interleaved)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(interleaved), "byteStride": 28}],
        "accessors": [{"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": count, "type": "VEC3"},
                      {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "count": count, "type": "VEC4"}],
        "meshes": [{"primitives": [{"attributes": {"NORMAL": 0, "TANGENT": 1}},
                                   {"attributes": {"NORMAL": 0, "TANGENT": 1}}]}],  # shared: repaired once
    }
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    binary = interleaved + b"\0" * (-len(interleaved) % 4)
    data = (struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(text) + 8 + len(binary))
            + struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary)
    path.write_bytes(data)
    return 12 + 8 + len(text) + 8  # where the binary chunk's data starts


def read_rows(path, start, count):
    rows = np.frombuffer(path.read_bytes(), dtype=np.float32, count=7 * count, offset=start).reshape(count, 7)
    return rows[:, :3], rows[:, 3:]


def test_tangents_without_a_direction_get_one_orthogonal_to_their_normal(tmp_path):
    path = tmp_path / "mesh.glb"
    start = write_glb(path, NORMALS, TANGENTS)
    before = path.read_bytes()

    assert repair_tangents(path) == 5

    after = path.read_bytes()
    normals, tangents = read_rows(path, start, len(NORMALS))
    np.testing.assert_array_equal(normals, NORMALS)
    np.testing.assert_allclose(tangents, EXPECTED, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(tangents[:, :3], axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.sum(tangents[:, :3] * normals, axis=1), 0.0, atol=1e-7)
    assert after[:start] == before[:start]  # header and JSON untouched
    assert after[start + 12:start + 28] == before[start + 12:start + 28]  # the right tangent's bytes


def test_a_file_with_unit_tangents_is_left_as_it_is(tmp_path):
    path = tmp_path / "mesh.glb"
    write_glb(path, NORMALS[:1], TANGENTS[:1])
    before, mtime = path.read_bytes(), path.stat().st_mtime_ns
    assert repair_tangents(path) == 0
    assert path.read_bytes() == before and path.stat().st_mtime_ns == mtime
    start = write_glb(path, NORMALS, TANGENTS)
    repair_tangents(path)
    repaired = path.read_bytes()
    assert repair_tangents(path) == 0 and path.read_bytes() == repaired
    assert read_rows(path, start, len(NORMALS))[1].shape == (6, 4)


def test_not_a_glb_is_refused(tmp_path):
    path = tmp_path / "mesh.glb"
    path.write_bytes(b'{"asset": {"version": "2.0"}}')
    with pytest.raises(ValueError, match="not a glTF 2.0 binary"):
        repair_tangents(path)
