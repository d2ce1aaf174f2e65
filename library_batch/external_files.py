# SPDX-License-Identifier: GPL-3.0-or-later
"""The files a model file reads besides itself, by format, read off its bytes without the format's library: what
a batch hashes into an asset's content key (:func:`.inputs.content_key`) and counts as its input."""
import functools
import json
import os
import pathlib
import re
import struct
import urllib.parse

__all__ = ["external_files", "forget_folder_listings"]

_USD_LAYERS = (".usd", ".usda", ".usdc")


def external_files(path):
    """Files a model reads besides itself: an .obj's material libraries and their maps, a .gltf's buffers and
    images (data: URIs excluded), the image files an .fbx names that Blender's FBX importer would load
    (:func:`_fbx_images`), the layers and images a .usd/.usda/.usdc layer names (:func:`_usd_files`). A .blend's
    linked images are not listed (reading them needs Blender); its packed images, an .fbx's embedded ones and
    everything in a .usdz are part of its bytes.

    Returns
    -------
    list of pathlib.Path
        Possibly missing files, in the order they are named.
    """
    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    files = []
    if suffix == ".gltf":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return []
        for item in list(data.get("buffers", [])) + list(data.get("images", [])):
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:"):
                files.append(path.parent / urllib.parse.unquote(uri))
    elif suffix == ".obj":
        try:
            lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError:
            return []
        for line in lines:
            if line.startswith("mtllib "):
                library = path.parent / line[len("mtllib "):].strip()
                files.append(library)
                try:
                    material_lines = library.read_text(encoding="utf-8", errors="replace").splitlines()
                except OSError:
                    continue
                for entry in material_lines:
                    words = entry.split()
                    if len(words) >= 2 and (words[0].lower().startswith("map_")
                                            or words[0].lower() in ("bump", "disp", "decal", "refl", "norm")):
                        files.append(library.parent / words[-1])
    elif suffix == ".fbx":
        files = _fbx_images(path)
    elif suffix in _USD_LAYERS:
        files = _usd_files(path, set())
    unique = {}  # each file once, by the first name it is given
    for file in files:
        unique.setdefault(file.resolve(), file)
    return list(unique.values())


# An image file's extension; in an FBX file, the bytes that end the name before it: binary FBX keeps strings as
# length-prefixed bytes (the prefix and the property's type code are cut off by the control bytes around them),
# ASCII FBX in double quotes.
_IMAGE_EXTENSION = re.compile(rb"\.(?:png|jpe?g|tga|tiff?|bmp|exr|hdr|webp|dds|psd|gif)", re.IGNORECASE)
_FBX_NAME_END = re.compile(rb'[\x00-\x1f"*<>?|]')
_FBX_LONGEST_NAME = 1024


def _fbx_images(path):
    """The image files an FBX file names (its textures' ``FileName`` and ``RelativeFilename``), found as Blender's
    FBX importer finds them: the relative name next to the file, the absolute name, else a file of that name
    anywhere below the file's folder (its image search). Names it finds nowhere are left out: the importer leaves
    those textures out too."""
    try:
        data = path.read_bytes()
    except OSError:
        return []
    folder = path.parent
    found = []
    for match in _IMAGE_EXTENSION.finditer(data):
        start = max(0, match.start() - _FBX_LONGEST_NAME)
        before = data[start:match.start()]
        ends = list(_FBX_NAME_END.finditer(before))
        name = before[ends[-1].end() if ends else 0:] + match.group()
        name = name.decode("utf-8", errors="replace").strip().replace("\\", "/")
        if name == match.group().decode():  # an extension alone: no name
            continue
        named = folder / name  # an absolute name stays itself
        if named.is_file():
            found.append(named)
        else:
            found += _files_named(str(folder)).get(pathlib.PurePosixPath(name).name.lower(), [])[:1]
    return found


def forget_folder_listings():
    """Look at the folders' files afresh from now on (a batch's plan does, :func:`.inputs.plan_assets`): an .fbx's
    images are searched for in one listing per folder, kept until then."""
    _files_named.cache_clear()


@functools.lru_cache(maxsize=64)
def _files_named(folder):
    """Every file below ``folder`` by its lower-case name (one walk per folder until
    :func:`forget_folder_listings`)."""
    names = {}
    for root, _, files in sorted(os.walk(folder)):
        for name in sorted(files):
            names.setdefault(name.lower(), []).append(pathlib.Path(root) / name)
    return names


def _usd_files(path, seen):
    """The layers (sublayers, references, payloads) and image files a USD layer names, and theirs in turn, as
    paths relative to the layer's folder or absolute (``seen``: the layers already read, resolved)."""
    seen.add(path.resolve())
    try:
        data = path.read_bytes()
    except OSError:
        return []
    names = _usd_crate_tokens(data) if data.startswith(b"PXR-USDC") else re.findall(rb"@([^@\n]+)@", data)
    files = []
    for name in names:
        text = name.decode("utf-8", errors="replace").strip()
        if text.startswith("@") or "://" in text:  # '@@@' quoting, or a resolver's URL
            continue
        suffix = pathlib.PurePosixPath(text).suffix.lower()
        if suffix not in _USD_LAYERS + (".usdz",) and not _IMAGE_EXTENSION.fullmatch(suffix.encode()):
            continue
        named = path.parent / text
        if not named.is_file():
            continue
        files.append(named)
        if suffix in _USD_LAYERS and named.resolve() not in seen:
            files += _usd_files(named, seen)
    return files


def _usd_crate_tokens(data):
    """The tokens of a binary USD layer (the crate format: header, table of contents, a TOKENS section of
    NUL-separated strings, LZ4-compressed from version 0.4.0 on); asset paths are stored as tokens. [] for a
    file this does not read."""
    try:
        version = tuple(data[8:11])
        (contents,) = struct.unpack_from("<q", data, 16)
        (sections,) = struct.unpack_from("<Q", data, contents)
        for number in range(sections):
            name, start, _ = struct.unpack_from("<16sqq", data, contents + 8 + 32 * number)
            if name.rstrip(b"\0") != b"TOKENS":
                continue
            if version < (0, 4, 0):
                (size,) = struct.unpack_from("<Q", data, start + 8)
                raw = data[start + 16:start + 16 + size]
            else:
                _, compressed = struct.unpack_from("<QQ", data, start + 8)
                raw = _fast_decompress(data[start + 24:start + 24 + compressed])
            return raw.split(b"\0")
    except (struct.error, IndexError):
        pass
    return []


def _fast_decompress(source):
    """OpenUSD's ``TfFastCompression``: a chunk count (0: one chunk), then LZ4 blocks (each after its int32 size
    when there are several)."""
    chunks = source[0]
    if chunks == 0:
        return _lz4_block(source[1:])
    out = bytearray()
    at = 1
    for _ in range(chunks):
        (size,) = struct.unpack_from("<i", source, at)
        out += _lz4_block(source[at + 4:at + 4 + size])
        at += 4 + size
    return bytes(out)


def _lz4_block(source):
    """Decompress one LZ4 block (the format's sequences of literals and back references)."""
    out = bytearray()
    at, end = 0, len(source)
    while at < end:
        token = source[at]
        literals, at = _lz4_length(source, at + 1, token >> 4)
        out += source[at:at + literals]
        at += literals
        if at >= end:  # the last sequence has literals only
            break
        offset = source[at] | source[at + 1] << 8
        length, at = _lz4_length(source, at + 2, token & 15)
        first = len(out) - offset
        for index in range(length + 4):  # a reference may overlap the bytes it writes
            out.append(out[first + index])
    return bytes(out)


def _lz4_length(source, at, length):
    """A sequence's length from its token's 4 bits: 15 continues in the bytes at ``at`` (each added, until one
    below 255); returns it and where the bytes after it start."""
    if length == 15:
        while True:
            extra = source[at]
            at += 1
            length += extra
            if extra != 255:
                break
    return length, at
