# SPDX-License-Identifier: GPL-3.0-or-later
"""Unit tangents in a .glb: the vertices where MikkTSpace finds no tangent get one orthogonal to their normal.

glTF requires every TANGENT to be a unit XYZ vector with W = +1 or -1 (the bitangent's sign). Blender's exporter
writes what MikkTSpace computes in the UV map, and MikkTSpace has no direction to give a vertex whose triangles
all have zero area in that UV map: it writes (0, 0, 0, 1), which the Khronos validator reports as an error
(``ACCESSOR_VECTOR3_NON_UNIT``). Such a vertex samples one point of the texture, so no tangent frame is more
right than another there; any unit vector orthogonal to the normal keeps the file valid and the shading of every
other vertex unchanged. Only those vertices are rewritten, in place in the binary chunk: the JSON and every
other byte stay as they were.

Pure format code: no bpy (``bridge.gltf_export`` calls it on the file Blender wrote).

References
----------
glTF 2.0 specification, 3.7.2.1 (TANGENT: "XYZW vertex tangents where the XYZ portion is normalized, and the
W component is a sign value (-1 or +1)").
"""
import json
import pathlib
import struct

import numpy as np

from .atomic import atomic_path

__all__ = ["repair_tangents"]

_GLB_MAGIC = 0x46546C67  # "glTF"
_JSON_CHUNK = 0x4E4F534A
_BIN_CHUNK = 0x004E4942
_FLOAT = 5126
# What counts as a unit vector: well inside the validator's tolerance, well outside float32 rounding.
_UNIT_TOLERANCE = 1e-4


def _chunks(data):
    """``(json_dict, bin_offset, bin_length)`` of a .glb's bytes; bin_offset None without a binary chunk."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC or version != 2 or length != len(data):
        raise ValueError("not a glTF 2.0 binary file (.glb)")
    offset, document, binary = 12, None, (None, 0)
    while offset + 8 <= length:
        chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
        if chunk_type == _JSON_CHUNK and document is None:
            document = json.loads(bytes(data[offset + 8:offset + 8 + chunk_length]))
        elif chunk_type == _BIN_CHUNK and binary[0] is None:
            binary = (offset + 8, chunk_length)
        offset += 8 + chunk_length
    if document is None:
        raise ValueError("the .glb has no JSON chunk")
    return document, *binary


def _float_rows(data, document, bin_offset, accessor_index, width):
    """A writable (count, width) float32 view of an accessor stored in the binary chunk, or None if it is not
    such an accessor (sparse, another component type or width, or in an external buffer)."""
    accessor = document["accessors"][accessor_index]
    if (accessor.get("componentType") != _FLOAT or accessor.get("type") != f"VEC{width}"
            or "sparse" in accessor or "bufferView" not in accessor):
        return None
    view = document["bufferViews"][accessor["bufferView"]]
    if view.get("buffer", 0) != 0 or "uri" in document["buffers"][0] or bin_offset is None:
        return None
    stride = view.get("byteStride", 4 * width)
    start = bin_offset + view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    count = int(accessor["count"])
    if count == 0:
        return None
    if stride % 4:
        return None
    # glTF aligns float accessors to 4 bytes; numpy needs only the view to be whole floats.
    base = np.frombuffer(data, dtype=np.uint8, count=(count - 1) * stride + 4 * width, offset=start)
    return np.lib.stride_tricks.as_strided(base.view(np.float32), shape=(count, width), strides=(stride, 4),
                                           writeable=True)


def _orthogonal_unit(normals):
    """(k, 3) unit vectors orthogonal to each of ``normals`` (any unit vector where a normal is zero)."""
    normals = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    n = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    # The coordinate axis least aligned with the normal, made orthogonal to it (Gram-Schmidt).
    axis = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    t = axis - np.sum(axis * n, axis=1, keepdims=True) * n
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def repair_tangents(path):
    """Give every TANGENT of the .glb at ``path`` a unit XYZ and a W of +1 or -1, in place.

    Vertices whose tangent is already unit with W = +-1 keep their bytes. A zero or non-finite XYZ becomes a unit
    vector orthogonal to the vertex's NORMAL; any other non-unit XYZ is normalized; a W that is not +-1 takes
    its sign (+1 for 0). The file is rewritten (whole or not at all) only when something changed.

    Parameters
    ----------
    path : str or os.PathLike
        A .glb file whose buffer 0 is its binary chunk (as Blender's exporter writes it).

    Returns
    -------
    int
        How many tangents were rewritten.

    Raises
    ------
    ValueError
        The file is not a glTF 2.0 binary file.
    """
    path = pathlib.Path(path)
    data = bytearray(path.read_bytes())
    document, bin_offset, _ = _chunks(data)
    done, repaired = set(), 0
    for mesh in document.get("meshes", []):
        for primitive in mesh.get("primitives", []):
            attributes = primitive.get("attributes", {})
            if "TANGENT" not in attributes or attributes["TANGENT"] in done:
                continue
            done.add(attributes["TANGENT"])
            tangents = _float_rows(data, document, bin_offset, attributes["TANGENT"], 4)
            if tangents is None:
                continue
            xyz = tangents[:, :3].astype(np.float64)
            length = np.linalg.norm(xyz, axis=1)
            has_direction = np.isfinite(xyz).all(axis=1) & (length > _UNIT_TOLERANCE)
            bad = ~has_direction | (np.abs(length - 1.0) > _UNIT_TOLERANCE) | ~(np.abs(tangents[:, 3]) == 1.0)
            if not bad.any():
                continue
            rows = np.nonzero(bad)[0]
            degenerate, scalable = rows[~has_direction[rows]], rows[has_direction[rows]]
            tangents[scalable, :3] = xyz[scalable] / length[scalable, None]
            if len(degenerate):
                normals = _float_rows(data, document, bin_offset, attributes["NORMAL"], 3) \
                    if "NORMAL" in attributes else None
                around = normals[degenerate] if normals is not None else np.zeros((len(degenerate), 3))
                tangents[degenerate, :3] = _orthogonal_unit(np.nan_to_num(around))
            w = np.nan_to_num(tangents[rows, 3].astype(np.float64))
            tangents[rows, 3] = np.where(w < 0, -1.0, 1.0)
            repaired += len(rows)
    if repaired:
        with atomic_path(path) as temporary:
            temporary.write_bytes(bytes(data))
    return repaired
