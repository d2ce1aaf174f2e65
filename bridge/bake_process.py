# SPDX-License-Identifier: GPL-3.0-or-later
"""Bake the maps of :func:`.bake.iter_bake_maps` in a background Blender process, so the interface never waits.

A Cycles bake is one uninterrupted bpy call (about a second for a 1-2k map): run by the modal operator in
Blender's own process it freezes the interface for as long. Here the parent hands the bake to a child process and
keeps yielding while it runs:

1. The parent writes the objects and everything they reference (meshes with both UV maps, materials, node groups,
   images: packed ones with their data, file images with absolute paths) into a temporary .blend with
   ``bpy.data.libraries.write``, and the pixels of images that exist only in memory (generated or edited and not
   saved, ``is_dirty``; or whose file is gone) as ``.npy`` files, since a .blend does not hold them.
2. The child (the same interpreter the triangle-wise workers use, ``core.spawn._python_executable``, with
   ``import bpy``; or Blender itself, ``bpy.app.binary_path -b --factory-startup``) imports this package the way
   the workers do (``core.spawn._BOOTSTRAP``), loads the objects into an empty file, gives the in-memory
   images their pixels, finds each map's record again (:func:`_find_record`) and runs the same code as the
   parent would (:func:`.bake.bake_map_pixels`), writing each map's float32 pixels as an ``.npy`` file.
3. The parent yields every 0.1 s while the child runs (the number of maps written so far is the progress), then
   turns the pixels into images exactly as the in-process bake does (:func:`.bake._new_image`).

Closing the generator kills the child; a child that fails raises a ValueError with its message when the bake
refused the input (as in this process), otherwise a RuntimeError with its last line of error output; the
temporary folder is removed in every case.
"""
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

from ..core.atomic import atomic_path
from ..core.progress import InThread, report_while_waiting

__all__ = ["iter_bake_in_background", "WAIT_SECONDS"]

# Seconds between two yields while the child bakes (the modal operator's slice is 0.1 s).
WAIT_SECONDS = 0.1
_BLEND = "objects.blend"
_MANIFEST = "manifest.json"
_ERROR = "error.json"
_DONE = "done"


def _images_of(objects):
    """Every image the objects' materials reference (top level and inside node groups), once each."""
    from .map_reads import _all_nodes

    images = {}
    for obj in objects:
        for slot in obj.material_slots:
            material = slot.material
            if material is None or material.node_tree is None:
                continue
            for node in _all_nodes(material.node_tree):
                if node.type == "TEX_IMAGE" and node.image is not None:
                    images.setdefault(node.image.name, node.image)
    return list(images.values())


def _only_in_memory(image):
    """True when a written .blend would not give ``image``'s current pixels back: generated or edited and not
    saved or packed since (``is_dirty``), or a file image whose file is gone."""
    import bpy

    if image.is_dirty:
        return True
    if image.source == "FILE" and image.packed_file is None:
        return not os.path.isfile(bpy.path.abspath(image.filepath_raw, library=image.library))
    return False


def _write_inputs(folder, objects, maps, *, source_uv, target_uv, resolutions, margins):
    """Write what the child needs into ``folder``: the .blend, the in-memory images' pixels, the manifest."""
    import bpy

    from .cycles_bake import target_size
    from .map_reads import bake_kind

    bpy.data.libraries.write(os.path.join(folder, _BLEND), set(objects), fake_user=True, path_remap="ABSOLUTE")
    pixels = {}
    for number, image in enumerate(_images_of(objects)):
        if _only_in_memory(image):
            path = os.path.join(folder, f"image_{number}.npy")
            values = np.empty(len(image.pixels), dtype=np.float32)
            image.pixels.foreach_get(values)
            np.save(path, values)
            pixels[image.name] = path
    manifest = {
        "blend": os.path.join(folder, _BLEND),
        "objects": [obj.name for obj in objects],
        "source_uv": source_uv,
        "target_uv": target_uv,
        "images": pixels,
        "maps": [{"image": record.image.name, "kind": bake_kind(record), "role": record.role,
                  "resolution": list(target_size(resolution)), "margin": int(margin)}
                 for record, resolution, margin in zip(maps, resolutions, margins)],
    }
    with open(os.path.join(folder, _MANIFEST), "w", encoding="utf-8") as file:
        json.dump(manifest, file)


def _child_code(folder):
    """The Python source the child runs: this package imported as the workers import it, then :func:`_run`."""
    from ..core.spawn import _BOOTSTRAP, _package_parents

    # The parent's module paths too: inside Blender the extension's wheels live on a path a factory-startup
    # Blender does not add by itself.
    return (f"import sys\nsys.path.extend(p for p in {list(sys.path)!r} if p not in sys.path)\n"
            f"parents = {_package_parents()!r}\nmodule_name = {__name__!r}\nstate = {{'folder': {folder!r}}}\n"
            + _BOOTSTRAP)


def _child_command(code):
    """The command line of the child: Blender in background mode when this is Blender, otherwise a Python
    interpreter that imports bpy as a module (the one the triangle-wise workers use)."""
    import bpy

    from ..core.spawn import _python_executable

    binary = bpy.app.binary_path
    if binary and os.path.isfile(binary) and "blender" in os.path.basename(binary).lower():
        return [binary, "-b", "--factory-startup", "--python-exit-code", "1", "--python-expr", code]
    python = _python_executable()
    if python is None:
        raise RuntimeError("the background bake found no Python interpreter to run in; bake in this process")
    return [python, "-c", code]


def _last_line(path):
    with contextlib.suppress(OSError):
        with open(path, encoding="utf-8", errors="replace") as file:
            lines = [line.strip() for line in file if line.strip()]
        if lines:
            return lines[-1]
    return "no error output"


def _failure(folder, returncode):
    """The exception for a child that ended without its results."""
    error_path = os.path.join(folder, _ERROR)
    if os.path.isfile(error_path):
        with open(error_path, encoding="utf-8") as file:
            error = json.load(file)
        if error["type"] == "ValueError":
            return ValueError(error["message"])
        return RuntimeError(f"the background bake failed: {error['type']}: {error['message']}")
    return RuntimeError(f"the background bake process ended with exit code {returncode}: "
                        f"{_last_line(os.path.join(folder, 'stderr.txt'))}")


def _iter_import_workers_module(total):
    """Import ``core.trianglewise`` (its first import loads numba: about a second) in a thread, yielding
    ``(0, total)`` every :data:`WAIT_SECONDS` meanwhile; nothing when it is imported already."""
    import importlib
    import importlib.util

    from ..core.progress import InThread

    name = importlib.util.resolve_name("..core.trianglewise", __package__)
    if name not in sys.modules:
        for _ in InThread(importlib.import_module, name, interval=WAIT_SECONDS).wait():
            yield 0, total


def iter_bake_in_background(objects, maps, *, source_uv, target_uv, resolutions, margins,
                            wait_seconds=WAIT_SECONDS):
    """Bake ``maps`` of ``objects`` in a child process: yields ``(done, total)`` maps every ``wait_seconds`` while
    it runs; returns per map ``(pixels, use_alpha)`` as :func:`.bake.bake_map_pixels` gives them.

    Parameters are those of :func:`.bake.iter_bake_maps` (one margin per map). Writing the inputs takes one
    step (milliseconds for a .blend; an image only in memory is copied out, 0.03 s per 2k RGBA image).

    Raises
    ------
    ValueError
        The child's bake refused the input (the message of the in-process bake).
    RuntimeError
        The child failed otherwise or could not start: its last line of error output.
    """
    total = len(maps)
    yield from _iter_import_workers_module(total)
    folder = tempfile.mkdtemp(prefix="perceptual_uv-bake-")
    process = None
    try:
        _write_inputs(folder, objects, maps, source_uv=source_uv, target_uv=target_uv, resolutions=resolutions,
                      margins=margins)
        yield 0, total
        with open(os.path.join(folder, "stderr.txt"), "wb") as stderr:
            process = subprocess.Popen(_child_command(_child_code(folder)), stdin=subprocess.DEVNULL,
                                       stdout=subprocess.DEVNULL, stderr=stderr, cwd=folder)
        while True:
            try:
                process.wait(timeout=wait_seconds)
                break
            except subprocess.TimeoutExpired:
                done = sum(os.path.isfile(os.path.join(folder, f"map_{number}.npy")) for number in range(total))
                yield done, total
        if process.returncode != 0 or not os.path.isfile(os.path.join(folder, _DONE)):
            raise _failure(folder, process.returncode)
        results = []
        for number in range(total):
            with open(os.path.join(folder, f"map_{number}.json"), encoding="utf-8") as file:
                use_alpha = json.load(file)["alpha"]
            # a 4k map's pixels are a quarter gigabyte: read in a thread while the stage yields
            pixels = yield from report_while_waiting(
                InThread(_load_pixels, os.path.join(folder, f"map_{number}.npy")).wait(), (total, total))
            results.append((pixels, bool(use_alpha)))
        return results
    finally:
        if process is not None and process.poll() is None:
            process.kill()
            process.wait()
        shutil.rmtree(folder, ignore_errors=True)


def _load_pixels(path):
    """The float32 pixels the child wrote to ``path``."""
    return np.load(path)


# ---- the child --------------------------------------------------------------------------------------------------

def _find_record(objects, source_uv, wanted):
    """The record of the map ``wanted`` describes (image name, bake kind, role) among the loaded objects'
    materials, met in the order ``material_copy.read_maps`` meets them, so it is the parent's record."""
    from .map_reads import bake_kind
    from .material import read_object_materials

    fallback = None
    for obj in objects:
        for reading in read_object_materials(obj, source_uv=source_uv):
            for record in reading.maps:
                if record.image.name == wanted["image"] and bake_kind(record) == wanted["kind"]:
                    if record.role == wanted["role"]:
                        return record
                    fallback = fallback or record
    if fallback is None:
        raise RuntimeError(f"map '{wanted['image']}' ({wanted['role']}) not found in the objects' materials")
    return fallback


def _run(folder):
    """The child's work: load the objects, bake every map of the manifest, write the pixels."""
    import bpy

    from .bake import bake_map_pixels

    with open(os.path.join(folder, _MANIFEST), encoding="utf-8") as file:
        manifest = json.load(file)
    bpy.ops.wm.read_factory_settings(use_empty=True)  # nothing of the startup file clashes with the names
    with bpy.data.libraries.load(manifest["blend"], link=False) as (_, loaded):
        loaded.objects = list(manifest["objects"])
    objects = [bpy.data.objects[name] for name in manifest["objects"]]
    for name, path in manifest["images"].items():
        bpy.data.images[name].pixels.foreach_set(np.load(path))
    source_uv, target_uv = manifest["source_uv"], manifest["target_uv"]
    for number, wanted in enumerate(manifest["maps"]):
        record = _find_record(objects, source_uv, wanted)
        pixels, use_alpha = bake_map_pixels(objects, record, source_uv=source_uv, target_uv=target_uv,
                                            resolution=wanted["resolution"], margin=wanted["margin"])
        with open(os.path.join(folder, f"map_{number}.json"), "w", encoding="utf-8") as file:
            json.dump({"alpha": bool(use_alpha)}, file)
        with atomic_path(os.path.join(folder, f"map_{number}.npy")) as temporary:
            np.save(temporary, pixels)
    with open(os.path.join(folder, _DONE), "w", encoding="utf-8"):
        pass


def _worker_init(state):
    """Entry point of the child (``core.spawn._BOOTSTRAP`` calls it with ``{"folder": ...}``): runs
    :func:`_run` and, when it fails, writes the error's type and message for the parent before re-raising."""
    try:
        _run(state["folder"])
    except BaseException as error:
        with open(os.path.join(state["folder"], _ERROR), "w", encoding="utf-8") as file:
            json.dump({"type": type(error).__name__, "message": str(error)}, file)
        raise
