# SPDX-License-Identifier: GPL-3.0-or-later
"""The batch commands behind the CLI: open a model, run the pipeline, write the result and the report.

Outputs are written to temporary names and renamed at the very end, so an interrupted or failed run leaves no
partial files behind.
"""
import contextlib
import json
import os
import pathlib
import sys
import tempfile
import threading
import time

import bpy

from ..core.atomic import atomic_path
from ..core.progress import format_seconds
from .texture_parts import merge_parts, remove_parts, split_by_texture

__all__ = ["textured_objects", "texture_groups", "optimize_file", "combined_report", "evaluate_file"]


# Longest time the CLI stays silent during a run.
PROGRESS_INTERVAL_S = 5.0


def _log(message):
    print(message, file=sys.stderr, flush=True)


def textured_objects(object_name=None):
    """The mesh objects of the scene that show one image texture: ``object_name`` alone, or all that share it
    (:func:`texture_groups`).

    Raises
    ------
    ValueError
        No such object, no textured mesh, or meshes with different textures (the message lists them).
    """
    if object_name is not None:
        obj = bpy.data.objects.get(object_name)
        if obj is None:
            names = ", ".join(sorted(o.name for o in bpy.data.objects if o.type == "MESH"))
            raise ValueError(f"no object '{object_name}' in the file (meshes: {names or 'none'})")
        return [obj]
    groups = texture_groups()
    if len(groups) > 1:
        listing = "; ".join(f"{image.name}: {', '.join(o.name for o in objs)}" for image, objs in groups)
        raise ValueError(f"the meshes use {len(groups)} different textures ({listing}); pick one with --object")
    return groups[0][1]


def texture_groups(*, exclude=()):
    """The mesh objects of the scene (but those named in ``exclude``) grouped by the image texture they show, in
    the images' name order.

    The texture is the one that frames a run (:func:`.material.loss_image_nodes`), a mesh's the one of its first
    slot that has one: the base colour's image, and for meshes none of whose materials has one, their largest
    map's (a part with a normal or roughness map and a constant colour is a texture of its own); meshes that read
    no image (an armature's bone shape, a helper, an untextured part beside textured ones) are not part of the
    model.

    Returns
    -------
    list of (bpy.types.Image, list of bpy.types.Object)

    Raises
    ------
    ValueError
        No mesh of the scene shows an image texture.
    """
    from .material import loss_image_nodes

    first_image = {}  # each mesh in the group of its first slot's texture

    def add_first_images(meshes):
        slots = [(obj, slot.material) for obj in meshes for slot in obj.material_slots]
        for (obj, _), node in zip(slots, loss_image_nodes(material for _, material in slots)):
            if node is not None:
                first_image.setdefault(obj.name, (obj, node.image))

    meshes = [obj for obj in bpy.context.scene.objects if obj.type == "MESH" and obj.name not in exclude]
    add_first_images(meshes)
    add_first_images([obj for obj in meshes if obj.name not in first_image])
    groups = {}
    for obj, image in first_image.values():
        groups.setdefault(image.name, (image, []))[1].append(obj)
    if not groups:
        raise ValueError("no mesh in the file has a material that reads an image texture through a UV map: there "
                         "is no texture to optimize for")
    return [groups[name] for name in sorted(groups)]


class _ProgressLines:
    """Progress lines on stderr: at every stage change and end, and at least every ``interval`` seconds.

    A thread prints the latest progress when no line came for ``interval`` seconds, so a pipeline log never goes
    quiet; when the pipeline has not yielded for half of that or more (one long step, such as packing or the
    bake), the line says how long that step has run.
    """

    def __init__(self, interval=PROGRESS_INTERVAL_S):
        self.interval = interval
        self._latest = None
        self._stage = None
        self._printed = self._changed = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._heartbeat, name="perceptual_uv-progress", daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def update(self, progress):
        with self._lock:
            now = time.monotonic()
            self._latest, self._changed = progress, now
            if (progress.stage != self._stage or progress.done == progress.total
                    or now - self._printed >= self.interval):
                self._stage = progress.stage
                self._print(progress, now)

    def _print(self, progress, now, waiting=None):
        long_step = waiting is not None and waiting >= self.interval / 2
        suffix = f" (this step running for {format_seconds(waiting)})" if long_step else ""
        _log(f"[{progress.stage}] {progress.line()}{suffix}")
        self._printed = now

    def _heartbeat(self):
        while not self._stop.wait(min(1.0, self.interval)):
            with self._lock:
                now = time.monotonic()
                if self._latest is not None and now - self._printed >= self.interval:
                    self._print(self._latest, now, waiting=now - self._changed)


def _writable_folder(folder):
    """Create ``folder`` if needed and check that files can be created in it; ValueError otherwise."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as error:
        raise ValueError(f"cannot write into the output folder {folder}: {error.strerror or error}") from None
    return folder


def optimize_file(args):
    """``optimize``: see DESIGN's CLI contract; ``args`` comes from :func:`perceptual_uv.cli.parse_args`.

    Without ``--object``, a file whose meshes show several textures (a material set per part) gets one run per
    texture (:func:`texture_groups`), one after the other, into one output; every run's refusals come before the
    first run starts, and the report is :func:`combined_report` of theirs. An object whose slots show several
    textures runs as one temporary part per texture (:mod:`.texture_parts`), merged back after the runs.
    """
    from .mesh_io import import_model

    out = pathlib.Path(args.out).resolve()
    images_dir = _writable_folder(out.parent)  # checked before the (long) run, not after it
    if args.report:
        _writable_folder(pathlib.Path(args.report).resolve().parent)
    import_model(args.input)
    groups, parts = _groups_and_parts(args.object)
    shown = _part_labels(parts)
    runs, saved = [], []
    try:
        if len(groups) > 1:
            _check_groups([objects for _, objects in groups], args.uv)
        for number, (image, objects) in enumerate(groups, start=1):
            if len(groups) > 1:
                _log(f"texture {number} of {len(groups)}: '{image.name}' on "
                     f"{', '.join(shown.get(obj.name, obj.name) for obj in objects)}")
            result = _run_pipeline(objects, args, images_dir)
            runs.append((objects, result))
            saved += _saved_files(result.report)
            for note in result.report.get("notes", []):
                _log(f"note: {note}")
            for warning in result.report.get("warnings", []):
                _log(f"warning: {warning}")
        if parts:
            runs = _merge_parts(parts, runs, args.settings.epsilon)
            parts = []
        reports = [result.report for _, result in runs]
        report = dict(reports[0] if len(reports) == 1 else combined_report(reports), input=str(args.input),
                      output=str(out))
        with atomic_path(out) as temporary:
            try:
                if out.suffix.lower() == ".glb":
                    from .gltf_export import export_glb

                    export_glb(runs, temporary)
                else:
                    bpy.ops.wm.save_as_mainfile(filepath=str(temporary), copy=True, relative_remap=True)
            except RuntimeError as error:  # Blender's save and export report I/O failures this way
                reason = str(error).strip().splitlines()[-1] if str(error).strip() else "unknown error"
                raise ValueError(f"could not write {out}: {reason}") from None
        if args.report:
            with atomic_path(args.report) as temporary:
                temporary.write_text(json.dumps(report, indent=2) + "\n")
    except OSError as error:
        _remove_files(saved)
        raise ValueError(f"could not write the output: {error}") from None
    except BaseException:
        _remove_files(saved)
        raise
    finally:
        remove_parts(parts)
    print(f"result: {out}")
    for _, result in runs:
        if result.report.get("image_file"):
            print(f"image:  {result.report['image_file']}")
    if args.report:
        print(f"report: {pathlib.Path(args.report).resolve()}")
    return report


def _groups_and_parts(object_name):
    """The runs' groups of objects, each with the texture it shows (:func:`texture_groups`; ``object_name``
    alone when given), and the temporary parts of objects whose slots show several textures
    (:func:`.texture_parts.split_by_texture`: one run per texture, merged back after the runs). The other users of
    a split object's mesh (linked duplicates) are in no group: the mesh is optimized once, through its first user."""
    if object_name is not None:
        (obj,) = textured_objects(object_name)
        parts = split_by_texture(obj) if obj.type == "MESH" else []
        return ([(part.image, [part.part]) for part in parts] if parts else [(None, [obj])]), parts
    parts, split = [], set()
    try:
        for obj in [obj for obj in bpy.context.scene.objects if obj.type == "MESH"]:
            if obj.data.name not in split:
                made = split_by_texture(obj)
                if made:
                    parts += made
                    split.add(obj.data.name)
        groups = texture_groups(exclude={obj.name for obj in bpy.context.scene.objects
                                         if obj.type == "MESH" and obj.data.name in split})
    except BaseException:
        remove_parts(parts)
        raise
    return groups, parts


def _part_labels(parts):
    """How a message names each part: its object and slots."""
    return {part.part.name: f"{part.original.name} (slot{'s' if len(part.slots) > 1 else ''} "
                            f"{', '.join(str(slot + 1) for slot in part.slots)})" for part in parts}


def _merge_parts(parts, runs, epsilon):
    """Move the parts' results onto their objects (:func:`.texture_parts.merge_parts`, which removes the parts)
    and return ``runs`` with each part replaced by its object and the other users of its mesh, in the runs'
    objects and their reports."""
    run_of = {}
    for objects, result in runs:
        for obj in objects:
            run_of[obj.name] = result
    users = {}
    for obj in bpy.context.scene.objects:
        if obj.type == "MESH":
            users.setdefault(obj.data.name, []).append(obj)
    originals = {part.part.name: users[part.original.data.name] for part in parts}
    names = {part.part.name: part.original.name for part in parts}
    (source_uv,) = {run_of[part.part.name].report["source_uv_map"] for part in parts}
    merged = []
    for objects, result in runs:
        kept = []
        for obj in objects:
            for replaced in originals.get(obj.name, [obj]):
                if replaced not in kept:
                    kept.append(replaced)
        result.report["objects"] = list(dict.fromkeys(names.get(name, name) for name in result.report["objects"]))
        merged.append((kept, result))
    merge_parts(parts, [run_of[part.part.name].uv_map for part in parts],
                {material for _, result in runs for material in result.materials}, source_uv=source_uv,
                epsilon=epsilon)
    return merged


def _check_groups(groups, source_uv):
    """Every refusal of the runs on ``groups`` that needs no mesh reading, before the first starts: one that
    fails after others have run would have cost their time for nothing."""
    from .material_copy import read_maps
    from .pipeline import check_objects
    from .read_objects import source_image

    shown_by = {}
    for objects in groups:
        image = source_image(objects)
        for obj in objects:
            other = shown_by.setdefault(obj.data.name, (obj, image))
            if other[1] != image:
                raise ValueError(f"mesh '{obj.data.name}' is shared by objects that show different textures "
                                 f"('{other[0].name}' shows '{other[1].name}', '{obj.name}' shows '{image.name}'): "
                                 "one mesh gets one new UV map; give the objects meshes of their own (Object > "
                                 "Relations > Make Single User > Object & Data) or optimize one with --object")
        objects, _, group_uv = check_objects(objects, source_uv)
        read_maps(objects, group_uv, image)


def _run_pipeline(objects, args, images_dir):
    """Drive one pipeline run to its end with progress lines; returns its result. A cancel or an error takes
    away what the run made (the pipeline's own clean-up) and is raised."""
    from .pipeline import Progress, optimize_objects

    pipeline = optimize_objects(objects, args.settings, source_uv=args.uv, output_dir=str(images_dir))
    try:
        with _ProgressLines() as lines:
            while True:
                progress: Progress = next(pipeline)
                if getattr(args, "interrupted", None) is not None and args.interrupted.is_set():
                    raise KeyboardInterrupt  # a signal whose KeyboardInterrupt a numba compile swallowed
                lines.update(progress)
    except StopIteration as finished:
        return finished.value
    except BaseException:
        pipeline.close()
        raise


def _saved_files(report):
    """The image files a run saved (every new map's), from its report."""
    files = [entry.get("new_image_file") for entry in report.get("maps", [])] + [report.get("image_file")]
    return list(dict.fromkeys(path for path in files if path))


def _remove_files(paths):
    for path in paths:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)


_SUMMED = ("faces", "vertices", "optimized_triangles", "skipped_triangles", "unevaluated_triangles",
           "flipped_triangles", "restored_charts", "stacked_charts")
_SETTINGS = ("epsilon", "target_cost", "cost_measure", "seed", "evaluations_per_triangle")


def combined_report(reports):
    """The report of one ``optimize`` over several textures, from each texture's run report.

    ``textures`` holds the runs' reports as they are (each with its ``resolution``, ``relative_cost``, ``image``,
    ...); the top level has what the file as a whole has: the objects, the counts and times summed, the settings,
    ``triangles_within_bound`` over all optimized triangles, every map (``maps``) with the memory (``memory_ratio``,
    ``image_memory`` {``before``, ``after``} in raw bytes) and file ratios over all of them, ``images`` and
    ``image_files`` per texture, ``uv_map`` when the runs share its name (else None), and the notes and warnings,
    each prefixed with its texture.

    Parameters
    ----------
    reports : sequence of dict
        The runs' reports (:class:`.pipeline.PipelineResult`), in run order.

    Returns
    -------
    dict
    """
    maps = [entry for report in reports for entry in report["maps"]]
    before = sum(entry["raw_bytes_before"] for entry in maps)
    after = sum(entry["raw_bytes_after"] for entry in maps)
    files_before = [entry["file_bytes_before"] for entry in maps]
    files_after = [entry["file_bytes_after"] for entry in maps]
    optimized = sum(report["optimized_triangles"] for report in reports)
    times = {}
    for report in reports:
        for key, value in report["times_s"].items():
            times[key] = round(times.get(key, 0.0) + value, 3)
    overlaps = {}
    for report in reports:
        for key, value in report["overlapping_pairs"].items():
            overlaps[key] = overlaps.get(key, 0) + value
    uv_maps = {report["uv_map"] for report in reports}

    def labelled(key):  # by the texture's input image (the first map's)
        return [f"texture '{report['maps'][0]['image']}': {line}" for report in reports
                for line in report.get(key, [])]

    return {
        "objects": list(dict.fromkeys(name for report in reports for name in report["objects"])),
        **{key: sum(report[key] for report in reports) for key in _SUMMED},
        **{key: reports[0][key] for key in _SETTINGS},
        "times_s": times,
        "overlapping_pairs": overlaps,
        "triangles_within_bound": (sum(report["triangles_within_bound"] * report["optimized_triangles"]
                                       for report in reports) / optimized if optimized else None),
        "uv_map": uv_maps.pop() if len(uv_maps) == 1 else None,
        "images": [report["image"] for report in reports],
        "image_files": [report["image_file"] for report in reports],
        "maps": maps,
        "image_memory": {"before": before, "after": after},
        "memory_ratio": after / before if before else None,
        "file_ratio": (sum(files_after) / sum(files_before) if None not in files_before + files_after
                       and sum(files_before) else None),
        "notes": labelled("notes"),
        "warnings": labelled("warnings"),
        "textures": list(reports),
    }


def _evaluated_group(groups, labels, texture):
    """The meshes ``evaluate`` measures, of ``groups`` (:func:`_groups_and_parts`): those that show the image
    named ``texture``, or, when None, those of the file's only texture."""
    listing = "; ".join(f"{image.name}: {', '.join(labels.get(o.name, o.name) for o in objs)}"
                        for image, objs in groups)
    if texture is not None:
        chosen = [objects for image, objects in groups if image.name == texture]
        if not chosen:
            raise ValueError(f"no mesh shows an image '{texture}' (the textures and their meshes: {listing})")
        return chosen[0]
    if len(groups) > 1:
        raise ValueError(f"the meshes use {len(groups)} different textures ({listing}); evaluate one at a time "
                         "with --texture IMAGE")
    return groups[0][1]


def evaluate_file(args):
    """``evaluate``: q_r at each relative cost and E_iso of a UV map (paper Sec. 5.1), JSON and a plot.

    Parameters
    ----------
    args : argparse.Namespace
        ``input``, ``uv``, ``ref_uv`` (None: the active UV map), ``costs``, ``json``, ``plot``, ``shaded``,
        ``screen``.

    Returns
    -------
    dict
        The result of :func:`bridge.evaluate.evaluate_uv_map` (with ``shaded``:
        :func:`bridge.evaluate_shaded.evaluate_shaded`, q_r per map included) with ``input`` added.

    Raises
    ------
    ValueError
        No textured mesh object, or a UV map missing on an object.
    """
    from .evaluate import evaluate_uv_map
    from .material_copy import original_materials
    from .mesh_io import import_model

    import_model(args.input)
    # A file an optimize run wrote shows the material copies: the evaluation compares against what the run read.
    # An object whose slots show several textures is measured per texture, on the part of its faces that show it.
    with original_materials([obj for obj in bpy.context.scene.objects if obj.type == "MESH"]):
        groups, parts = _groups_and_parts(None)
        try:
            objects = [obj for obj in _evaluated_group(groups, _part_labels(parts), getattr(args, "texture", None))
                       if args.uv in obj.data.uv_layers]
            if not objects:
                raise ValueError(f"no textured mesh object in {args.input} has a UV map '{args.uv}'")
            ref_uv = args.ref_uv or objects[0].data.uv_layers.active.name
            screen = getattr(args, "screen", 512)
            if getattr(args, "shaded", False):
                from .evaluate_shaded import evaluate_shaded

                result = evaluate_shaded(objects, args.uv, reference_uv=ref_uv, costs=args.costs,
                                         screen_pixels=screen)
            else:
                result = evaluate_uv_map(objects, args.uv, reference_uv=ref_uv, costs=args.costs,
                                         screen_pixels=screen)
        finally:
            remove_parts(parts)
    result["input"] = str(pathlib.Path(args.input).resolve())
    for p in result["points"]:
        if "maps" in p:
            per_map = ", ".join(f"{m['role']} {m['q']:.6g} (r {m['resolution']})" for m in p["maps"])
            print(f"c_r {p['relative_cost']:.4f} (r {p['resolution']}, memory {p['memory_ratio']:.4f}): shaded q "
                  f"{p['q']:.6g}; per map: {per_map} [{result['views']} views, {result['screen_pixels']} px, "
                  f"{result['samples']} samples]")
        else:
            print(f"c_r {p['relative_cost']:.4f} (r {p['resolution']}): q {p['q']:.6g} "
                  f"[{result['views']} views, {result['screen_pixels']} px]")
    print(f"E_iso {result['e_iso']:.6g}")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=2))
        print(f"json: {pathlib.Path(args.json).resolve()}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(4.5, 3.2), dpi=100)
        ax.plot([p["relative_cost"] for p in result["points"]], [p["q"] for p in result["points"]], "o-",
                label=args.uv)
        ax.set_yscale("log")
        ax.set_xlabel("relative cost $c_r$")
        ax.set_ylabel(f"$q_r$ ({'shaded, ' if result.get('mode') == 'shaded' else ''}GMSD, "
                      f"{result['screen_pixels']} px)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot)
        plt.close(fig)
        print(f"plot: {pathlib.Path(args.plot).resolve()}")
    return result
