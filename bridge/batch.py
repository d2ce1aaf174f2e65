# SPDX-License-Identifier: GPL-3.0-or-later
"""The batch commands behind the CLI: open a model, run the pipeline, write the result and the report.

Outputs are written to temporary names and renamed at the very end, so an interrupted or failed run leaves no
partial files behind.
"""
import contextlib
import json
import os
import pathlib
import re
import sys
import tempfile
import threading
import time

import bpy

from ..core.atomic import atomic_path
from ..core.progress import format_seconds
from .texture_sets import texture_groups

__all__ = ["textured_objects", "optimize_file", "evaluate_file"]


# Longest time the CLI stays silent during a run.
PROGRESS_INTERVAL_S = 5.0


def _log(message):
    print(message, file=sys.stderr, flush=True)


def textured_objects(object_name=None):
    """The mesh objects of the scene that show one image texture: ``object_name`` alone, or all that share it
    (:func:`.texture_sets.texture_groups`).

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
    groups = texture_groups(bpy.context.scene.objects)
    if len(groups) > 1:
        raise ValueError(f"the meshes use {len(groups)} different textures ({_listing(groups)}); pick one with "
                         "--object")
    return groups[0][1]


def _listing(groups, labels=None):
    """The textures of ``groups`` and their meshes, for a message (``labels`` names the parts)."""
    labels = labels or {}
    return "; ".join(f"{image.name}: {', '.join(labels.get(o.name, o.name) for o in objs)}" for image, objs in groups)


# A progress message's count and what follows it: ": 12/5856, 9 s left in this stage".
_COUNT = re.compile(r": \d+/\d+\b.*$")


class _ProgressLines:
    """Progress lines on stderr: at every stage change and end, at the first step of each part of a stage (a new
    label: the message without its count, "Measuring the loss of the targets and both fits" of "...: 0/5856, 9 s
    left in this stage"), and at least every ``interval`` seconds.

    A thread prints the latest progress when no line came for ``interval`` seconds, so a pipeline log never goes
    quiet; when the pipeline has not yielded for half of that or more (one long step, such as packing or the
    bake), the line says how long that step has run.
    """

    def __init__(self, interval=PROGRESS_INTERVAL_S):
        self.interval = interval
        self._latest = None
        self._stage = None
        self._label = None
        self._line = None
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
            label = _COUNT.sub("", progress.message)
            # A stage's last steps (its workers stopping) repeat its end: one line for them.
            ended = progress.done == progress.total and self._line != self._text(progress)
            if (progress.stage != self._stage or label != self._label or ended
                    or now - self._printed >= self.interval):
                self._stage, self._label = progress.stage, label
                self._print(progress, now)

    @staticmethod
    def _text(progress):
        return f"[{progress.stage}] {progress.line()}"

    def _print(self, progress, now, waiting=None):
        long_step = waiting is not None and waiting >= self.interval / 2
        suffix = f" (this step running for {format_seconds(waiting)})" if long_step else ""
        self._line = self._text(progress)
        _log(f"{self._line}{suffix}")
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

    The scene's meshes (``--object``: that one) are optimized one texture at a time into one output
    (:func:`.texture_sets.iter_optimize_textures`); with several textures the report is
    :func:`.texture_sets.combined_report` of the runs'.
    """
    from .mesh_io import import_model
    from .texture_sets import combined_report, iter_optimize_textures

    out = pathlib.Path(args.out).resolve()
    images_dir = _writable_folder(out.parent)  # checked before the (long) run, not after it
    if args.report:
        _writable_folder(pathlib.Path(args.report).resolve().parent)
    import_model(args.input)
    objects = textured_objects(args.object) if args.object is not None else list(bpy.context.scene.objects)
    runs = _drive(iter_optimize_textures(objects, args.settings, source_uv=args.uv, output_dir=str(images_dir)),
                  args)
    reports = [result.report for _, result in runs]
    saved = [path for report in reports for path in _saved_files(report)]
    try:
        report = dict(reports[0] if len(reports) == 1 else combined_report(reports), input=str(args.input),
                      output=str(out))
        for note in report.get("notes", []):
            _log(f"note: {note}")
        for warning in report.get("warnings", []):
            _log(f"warning: {warning}")
        with atomic_path(out) as temporary:
            try:
                if out.suffix.lower() == ".glb":
                    from .gltf_export import export_glb

                    export_glb(runs, temporary)
                elif out.suffix.lower() == ".fbx":
                    from .fbx_export import export_fbx

                    export_fbx(runs, temporary)
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
    print(f"result: {out}")
    for path in report.get("image_files", [report.get("image_file")]):
        if path:
            print(f"image:  {path}")
    if args.report:
        print(f"report: {pathlib.Path(args.report).resolve()}")
    return report


def _drive(job, args):
    """Drive a pipeline generator to its end with progress lines; returns its result. A cancel or an error
    closes it (what it made is removed) and is raised."""
    from .pipeline import Progress

    try:
        with _ProgressLines() as lines:
            while True:
                progress: Progress = next(job)
                if getattr(args, "interrupted", None) is not None and args.interrupted.is_set():
                    raise KeyboardInterrupt  # a signal whose KeyboardInterrupt a numba compile swallowed
                lines.update(progress)
    except StopIteration as finished:
        return finished.value
    except BaseException:
        job.close()
        raise


def _saved_files(report):
    """The image files a run saved (every new map's), from its report."""
    files = [entry.get("new_image_file") for entry in report.get("maps", [])] + [report.get("image_file")]
    return list(dict.fromkeys(path for path in files if path))


def _remove_files(paths):
    for path in paths:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)


def _evaluated_group(groups, labels, texture):
    """The meshes ``evaluate`` measures, of ``groups`` (:func:`.texture_sets.groups_and_parts`): those that show
    the image named ``texture``, or, when None, those of the file's only texture."""
    listing = _listing(groups, labels)
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
    from .material_copy import copy_aspects, original_materials, slots_aspect
    from .mesh_io import import_model
    from .texture_parts import remove_parts
    from .texture_sets import groups_and_parts, part_labels

    import_model(args.input)
    # A file an optimize run wrote shows the material copies: the evaluation compares against what the run read.
    # An object whose slots show several textures is measured per texture, on the part of its faces that show it.
    meshes = [obj for obj in bpy.context.scene.objects if obj.type == "MESH"]
    # the image shape the run packed the UV map for: each cost's images keep it, so texels stay square
    aspects = copy_aspects([obj for obj in meshes if args.uv in obj.data.uv_layers], args.uv)
    with original_materials(meshes):
        groups, parts = groups_and_parts(list(bpy.context.scene.objects))
        try:
            objects = [obj for obj in _evaluated_group(groups, part_labels(parts), getattr(args, "texture", None))
                       if args.uv in obj.data.uv_layers]
            if not objects:
                raise ValueError(f"no textured mesh object in {args.input} has a UV map '{args.uv}'")
            ref_uv = args.ref_uv or objects[0].data.uv_layers.active.name
            screen = getattr(args, "screen", 512)
            if getattr(args, "shaded", False):
                from .evaluate_shaded import evaluate_shaded

                result = evaluate_shaded(objects, args.uv, reference_uv=ref_uv, costs=args.costs,
                                         screen_pixels=screen, aspect=slots_aspect(objects, aspects))
            else:
                result = evaluate_uv_map(objects, args.uv, reference_uv=ref_uv, costs=args.costs,
                                         screen_pixels=screen, aspect=slots_aspect(objects, aspects))
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
