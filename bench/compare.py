"""Compare UV maps by the paper's Sec. 5.1 evaluation: q_r-c_r plots, q_r / E_iso tables, a Table-1 style summary,
the pixel saving of ours, and render crops at c_r = 0.3 (input vs ours).

Usage (from /work, the repo's parent folder)::

    main/.venv/bin/python -m perceptual_uv.bench.compare --models shared/models --costs 0.1,0.2,0.3,0.5 \\
        --out main/docs/results [--evaluations 100] [--epsilons 0.005,0.02] [--methods input,repacked,...] \\
        [--screen 512] [--workers 0] [--cache DIR | --no-cache] [--reuse input,repacked,...] \\
        [--triangles CACHE_DIR] [--seed 0] [--shaded]
    main/.venv/bin/python -m perceptual_uv.bench.compare --summary main/docs/results

Per model: ``<model>_q_vs_c.png``, ``<model>.md``, ``<model>.json`` and ``<model>_crops_c030.png``;
``--summary`` rebuilds ``summary.md`` from every ``<model>.json`` in the folder. Every q is reported with its
screen size (20 dodecahedron views).

The comparison is resumable: every method's result is written to ``<cache>/<model>/<method>-<key>.json`` (default
``<out>/cache``) as soon as it is measured, with ours' UV map next to it, and read back instead of being
recomputed while its key holds. The key (:func:`method_key`) hashes the model's files, the settings that method
depends on, and the source of the code it runs (:data:`METHOD_SOURCES`), so a rerun after a change recomputes
only the methods that change touches, and a run cut off halfway loses only the method it was measuring. Progress
and an ETA go to stderr, one line per model and per method. ``--no-cache`` measures everything again and keeps
nothing. ``--reuse`` takes the listed methods' results from the ``<model>.json`` already in ``--out`` (at least
this run's costs, same screen) whatever the code; the JSON and the table name the reused methods.
``--triangles`` keeps each model's triangle-wise result in a folder (``bridge.baselines.triangle_targets``), so
that a change to the mesh-wise stage or the packing is measured without that stage again; t_triangle is then
the time of the run that wrote it.

Ours and every variant of it (``ours_*``, ``paper``) optimize on what a run of the product sees: every map of the
material, each turned into the loss's planes as the pipeline does (``bridge.baselines.loss_planes``), so a
triangle whose detail is in the normal or roughness map keeps its size. ``ours_luma`` is ours on the base colour's
luma alone (what the loss saw before materials, and the paper's loss): the difference between the two is what the
joint loss does. The flat mode's q_r sees the base colour only; what the other maps gain shows in ``--shaded``.

``--shaded`` evaluates every method in the shaded mode (``bridge.evaluate_shaded``): every map re-baked, the
whole material rendered by Cycles under fixed lights, q_r per map too, plotted against the maps' image memory;
the files are ``<model>_shaded.*`` (use their own ``--out`` folder, so the summary stays per mode). Its method
``downscale`` is the input UV map with every map resized to the cost's share of its own pixels (what
``gltfpack -ts`` and ``gltf-transform resize`` do), through the same bake as every other method; in the flat mode,
which sees the base colour only, it would be the input, so it is shaded-only.
"""

import argparse
import hashlib
import json
import pathlib
import sys
import time

import numpy as np

from ..core.settings import MODEL_SUFFIXES
from .compare_report import (SAVING_REFERENCE_COST, model_markdown, plot_curves, render_crops, wins,
                             write_summary)
from .source_hash import PACKAGE as _PACKAGE
from .source_hash import code_hash, model_hash

METHODS = ("input", "repacked", "ANGLE_BASED", "CONFORMAL", "MINIMUM_STRETCH", "SSP", "SSPOP", "ours", "ours_luma",
           "ours_rotation", "ours_common", "ours_identity", "paper", "ours_no_texel_floor", "ours_no_signal_blend",
           "ours_no_weight_floor", "ours_no_fold_restore", "ours_unstacked", "downscale")
SHADED_ONLY = ("downscale",)
"""Methods measured only with ``--shaded`` (see the module docstring)."""
SIZING = {"downscale": "memory"}
"""How ``bridge.evaluate_shaded`` sizes each method's maps (``texels`` otherwise)."""
OURS_VARIANTS = {"ours": {}, "ours_luma": {}, "ours_common": {"formulation": "common"},
                 "ours_identity": {"weights": "identity"}, "ours_rotation": {"rotation_scale": 1.0},
                 "ours_no_texel_floor": {"min_texels": 0.0}, "ours_no_signal_blend": {"signal_weight": 0.0},
                 "ours_no_weight_floor": {"weight_floor": 0.0}, "ours_no_fold_restore": {"fold_tolerance": 1.0},
                 "ours_unstacked": {"keep_stacks": False},
                 "paper": {"min_texels": 0.0, "signal_weight": 0.0, "weight_floor": 0.0, "rotation_scale": 1.0}}
"""Keyword arguments of ``bridge.baselines.perceptual_uv`` for ours, ``ours_luma`` (ours on the base colour's luma
alone, :data:`LOSS_MAPS`), its Fig. 17 ablations, ours without each of the constants the project added
(``MIN_TEXELS``, ``SIGNAL_WEIGHT``, ``STRETCH_WEIGHT_FLOOR``; a fold tolerance of 1 restores no chart, since a
shared-area fraction cannot grow by more than 1), ours with every chart unstacked (``ours_unstacked``: charts that
share texels in the input get texels of their own, :mod:`core.stacks`), and ``paper``: the paper as written, i.e.
one fit of Eq. 19 with Eq. 17's weights unchanged (no texel floor, no signal-stretch blend, no weight floor) on the
triangle-wise results of :data:`PAPER_TRIANGLES`, then the post-processing, packing and bake every method gets.
Every one of them sees the maps :data:`LOSS_MAPS` gives it."""
PAPER_TRIANGLES = {"formulation": "barrier", "max_screen_pixels": 64, "view_faces": "one_ring"}
"""The triangle-wise stage as written: the barrier form (Eq. 12-14) and App. A's fixed 64 px views of the
one-ring."""
TRIANGLE_OPTIONS = {"paper": PAPER_TRIANGLES}
"""Options of ``core.trianglewise.optimize_triangles`` per method whose triangle-wise stage is not ours'."""
LOSS_MAPS = {"ours_luma": "luma"}
"""What the loss of each of ours' variants sees (``bridge.baselines.loss_planes``), ``"material"`` when not listed:
every map of the material, read and turned into planes as a run of the product does (base colour as luma, normal
maps as their shading, data maps per channel), for the triangle-wise stage, the fit's targets, the choice between
the fits and the bound's fractions alike. ``ours_luma`` sees the base colour's luma alone (the paper's loss): on a
material whose only varying map is the base colour it is ours, and ours' triangle-wise result is reused."""

_PACKED = ("bridge.pack", "core.stacks", "bridge.baselines:_stacks", "bridge.baselines:_face_stack",
           "bridge.baselines:_check", "bridge.baselines:_pack", "bridge.baselines:_write",
           "bridge.baselines:_texture", "bridge.read_objects:source_image", "bridge.material",
           "bridge.baselines:PACK_MARGIN_PIXELS")
_FINISHED = _PACKED + ("core.charts", "core.overlap", "core.meshwise", "core.chart_orientation",
                       "core.chartfit:finish_charts", "bridge.baselines:_finished", "bridge.baselines:_post_counts")
_OURS = _FINISHED + ("core.chartfit", "core.trianglewise", "core.loss", "core.textured", "core.ssp",
                     "bridge.baselines:perceptual_uv", "bridge.baselines:triangle_targets",
                     "bridge.baselines:_triangle_cache_key", "bench.compare:UVMaps.triangles",
                     "bench.compare:OURS_VARIANTS", "bench.compare:TRIANGLE_OPTIONS",
                     "bench.compare:PAPER_TRIANGLES", "bridge.material_copy", "core.loss_planes",
                     "bridge.baselines:loss_planes", "bridge.baselines:LOSS_MAPS", "bench.compare:LOSS_MAPS",
                     "bench.compare:UVMaps.planes")
METHOD_SOURCES = {
    "input": (),
    "repacked": _PACKED + ("bridge.baselines:repacked_input",),
    **{m: _FINISHED + ("bridge.baselines:blender_unwrap", "bridge.baselines:BLENDER_METHODS")
       for m in ("ANGLE_BASED", "CONFORMAL", "MINIMUM_STRETCH")},
    "SSP": _FINISHED + ("core.ssp", "bridge.baselines:ssp_uv"),
    "SSPOP": _FINISHED + ("core.ssp", "bridge.baselines:sspop_uv"),
    **{m: _OURS for m in OURS_VARIANTS},
    "downscale": ("bench.compare:SIZING",),
}
"""The code each method's result depends on, for its cache key (:func:`method_key`), besides the evaluation
(:data:`EVALUATION_SOURCES`). ``"core.ssp"`` is that module and the modules of this package it imports, followed
through their imports; ``"bridge.baselines:ssp_uv"`` is one definition of a module that imports everything, so
that a change to one method there does not recompute the others. ``ours_eps<epsilon>`` depends on what ``ours``
does; a method not listed (a new one) depends on every module of core/ and bridge/ and on this file."""
EVALUATION_SOURCES = ("bridge.evaluate", "bridge.mesh_io", "bridge.material", "bridge.batch:textured_objects",
                      "bridge.texture_sets:texture_groups")
"""What every method's result depends on: the import of the model, the renders, the bakes and q_r."""
SHADED_SOURCES = ("bridge.evaluate_shaded",)
"""What every method's result depends on in addition with ``--shaded`` (the whole-material bake, the copies)."""
KEPT_MAPS = ("ours",)
"""Methods whose UV map is cached with their result: the crops and the pixel saving need it."""


def _models(paths):
    out = []
    for p in map(pathlib.Path, paths):
        if p.is_dir():
            out += sorted(f for f in p.rglob("*") if f.suffix.lower() in MODEL_SUFFIXES)
        elif p.suffix.lower() in MODEL_SUFFIXES:
            out.append(p)
    return out


def _epsilon_method(epsilon):
    return f"ours_eps{epsilon:g}"


class UVMaps:
    """Makes one UV map per method on the objects (the triangle-wise stage runs once per epsilon, options and loss
    planes) and keeps times."""

    def __init__(self, objects, source, *, evaluations, epsilon, workers, cache=None, seed=0):
        self.objects, self.source = objects, source
        self.evaluations, self.epsilon, self.workers, self.seed = evaluations, epsilon, workers, int(seed)
        self.cache = cache  # (folder, model stem) or None
        self.times, self._triangles, self._planes = {}, {}, {}
        self.reports = {}  # per method: what bridge.baselines returned (timings, restored and turned charts)

    def planes(self, method="ours"):
        """The planes ``method``'s loss sees (:data:`LOSS_MAPS`), read once per kind; a kind whose planes are
        those of ``"material"`` (same names and values) is that same stack."""
        from ..bridge import baselines

        maps = LOSS_MAPS.get(method, "material")
        if maps not in self._planes:
            material = None if maps == "material" else self.planes()
            planes = baselines.loss_planes(self.objects, source_uv=self.source, maps=maps)
            if material is not None and planes.names == material.names and all(
                    np.array_equal(a, b) for a, b in zip(planes, material)):
                planes = material
            self._planes[maps] = planes
        return self._planes[maps]

    def triangles(self, epsilon, method="ours"):
        """The triangle-wise result at ``epsilon`` with ``method``'s options (:data:`TRIANGLE_OPTIONS`) on its
        loss planes (:meth:`planes`): run once per epsilon, options and planes, or read from the cache."""
        from ..bridge import baselines

        options = TRIANGLE_OPTIONS.get(method, {})
        planes = self.planes(method)
        label = ("" if planes is self.planes() else f"_{LOSS_MAPS[method]}") + ("" if not options else f"_{method}")
        if (epsilon, label) not in self._triangles:
            cache = None
            if self.cache is not None:
                folder, stem = self.cache
                seed = f"_seed{self.seed}" if self.seed else ""
                cache = folder / f"{stem}_eps{epsilon:g}_n{self.evaluations}{seed}{label}.npz"
            self._triangles[epsilon, label], t = baselines.triangle_targets(
                self.objects, source_uv=self.source, epsilon=epsilon, evaluations=self.evaluations,
                workers=self.workers, seed=self.seed, cache=cache, planes=planes, **options)
            name = "triangle" if epsilon == self.epsilon else f"triangle_eps{epsilon:g}"
            self.times[name + label] = t
        return self._triangles[epsilon, label]

    def make(self, method):
        """Adds the UV map of ``method``; returns its name."""
        from ..bridge import baselines

        objects, source = self.objects, self.source
        start = time.perf_counter()
        name = {"input": source, "downscale": source, "repacked": "Repacked"}.get(method, method)
        report = {}
        if method == "repacked":
            report = baselines.repacked_input(objects, source_uv=source, name=name)
        elif method in baselines.BLENDER_METHODS:
            report = baselines.blender_unwrap(objects, source_uv=source, method=method)
        elif method == "SSP":
            report = baselines.ssp_uv(objects, source_uv=source, name=name)
        elif method == "SSPOP":
            report = baselines.sspop_uv(objects, source_uv=source, name=name)
        elif method not in ("input", "downscale"):  # downscale re-bakes the input UV map (SIZING)
            eps = float(method[len("ours_eps"):]) if method.startswith("ours_eps") else self.epsilon
            triangles = self.triangles(eps, method)
            start = time.perf_counter()  # the triangle-wise time is reported on its own
            report = baselines.perceptual_uv(objects, source_uv=source, triangles=triangles, name=name,
                                             workers=self.workers, planes=self.planes(method),
                                             **OURS_VARIANTS.get(method, {}))
            if method == "ours":
                self.times["mesh"] = report["mesh"]
        self.times[method] = time.perf_counter() - start
        self.reports[method] = report
        return name

    def remove(self, name):
        if name != self.source:
            for obj in self.objects:
                obj.data.uv_layers.remove(obj.data.uv_layers[name])


def method_sources(method, shaded=False):
    """The sources a method's result depends on (:data:`METHOD_SOURCES` and :data:`EVALUATION_SOURCES`, and
    :data:`SHADED_SOURCES` when ``shaded``)."""
    if method.startswith("ours_eps"):
        method = "ours"
    if method not in METHOD_SOURCES:
        every = sorted(".".join(f.relative_to(_PACKAGE).with_suffix("").parts)
                       for folder in ("core", "bridge") for f in (_PACKAGE / folder).glob("*.py"))
        return tuple(every) + ("bench.compare",)
    return METHOD_SOURCES[method] + EVALUATION_SOURCES + (SHADED_SOURCES if shaded else ())


def method_settings(method, *, costs, screen, evaluations, epsilon, shaded=False, seed=0):
    """The settings a method's result depends on (the flat mode's keys carry no ``shaded`` entry, and the
    triangle-wise stage's seed enters ours' keys only when it is not 0, so results measured before ``--seed``
    existed keep their keys)."""
    settings = dict(costs=sorted(float(c) for c in costs), screen=int(screen))
    if shaded:
        from ..bridge.evaluate_shaded import SAMPLES

        settings.update(shaded=True, samples=SAMPLES, sizing=SIZING.get(method, "texels"))
    if method in OURS_VARIANTS or method.startswith("ours_eps"):
        eps = float(method[len("ours_eps"):]) if method.startswith("ours_eps") else float(epsilon)
        settings.update(evaluations=int(evaluations), epsilon=eps, variant=OURS_VARIANTS.get(method, {}),
                        triangle_options=TRIANGLE_OPTIONS.get(method, {}),
                        loss_maps=LOSS_MAPS.get(method, "material"))
        if seed:
            settings.update(seed=int(seed))
    return settings


def method_key(method, *, model, settings, code):
    """The cache key of one method's result: 16 hex digits of the hash of model, settings and code hashes."""
    text = json.dumps(dict(method=method, model=model, settings=settings, code=code), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class ResultCache:
    """One folder per model of per-method results, ``<folder>/<model>/<method>-<key>.json`` (see the module
    docstring); ``folder`` None keeps nothing."""

    def __init__(self, folder, *, costs, screen, evaluations, epsilon, shaded=False, seed=0):
        self.folder = None if folder is None else pathlib.Path(folder)
        self.settings = dict(costs=costs, screen=screen, evaluations=evaluations, epsilon=epsilon, seed=seed)
        self.shaded = bool(shaded)
        if shaded:
            self.settings["shaded"] = True
        self._code, self._models = {}, {}

    def key(self, path, method):
        path = pathlib.Path(path)
        if path not in self._models:
            self._models[path] = model_hash(path)
        if method not in self._code:
            self._code[method] = code_hash(method_sources(method, self.shaded))
        return method_key(method, model=self._models[path], code=self._code[method],
                          settings=method_settings(method, **self.settings))

    def file(self, path, method):
        return None if self.folder is None else \
            self.folder / pathlib.Path(path).stem / f"{method}-{self.key(path, method)}.json"

    def load(self, path, method):
        """The cached entry (``result``, ``times``, and ``uv`` for :data:`KEPT_MAPS`), or None."""
        file = self.file(path, method)
        if file is None or not file.is_file():
            return None
        try:
            entry = json.loads(file.read_text())
            if method in KEPT_MAPS:
                with np.load(file.with_suffix(".npz")) as stored:
                    entry["uv"] = stored["uv"]
        except (OSError, ValueError, KeyError) as error:  # a file cut off by an interrupted run is measured again
            print(f"cache: ignoring {file}: {error}", file=sys.stderr, flush=True)
            return None
        return entry

    def save(self, path, method, *, result, times, uv=None):
        file = self.file(path, method)
        if file is None:
            return
        file.parent.mkdir(parents=True, exist_ok=True)
        if uv is not None:
            _atomic_write(file.with_suffix(".npz"), lambda f: np.savez_compressed(f, uv=uv))
        entry = dict(method=method, key=file.stem.rsplit("-", 1)[1],
                     settings=method_settings(method, **self.settings), result=result, times=times)
        _atomic_write(file, lambda f: f.write(json.dumps(entry, indent=1).encode()))


def _atomic_write(file, write):
    """Write through a temporary file and rename it, so that an interrupted run leaves no half-written file."""
    temporary = file.with_name(file.name + ".part")
    with open(temporary, "wb") as f:
        write(f)
    temporary.replace(file)


class Progress:
    """One line on stderr per model and per method done, with an ETA from the methods measured so far."""

    def __init__(self, to_measure, total):
        self.left, self.total, self.done = to_measure, total, 0
        self.seconds = {}  # method -> seconds of each measurement in this run

    def model(self, index, count, stem, measure, cached):
        print(f"[model {index}/{count}] {stem}: {measure} methods to measure, {cached} cached or reused",
              file=sys.stderr, flush=True)

    def method(self, stem, method, seconds, how):
        self.done += 1
        if how == "measured":
            self.left = max(0, self.left - 1)
            self.seconds.setdefault(method, []).append(seconds)
        print(f"[{self.done}/{self.total}] {stem} {method}: {how} in {seconds:.1f} s; {self.left} to measure, "
              f"ETA {_duration(self.eta())}", file=sys.stderr, flush=True)

    def eta(self):
        """Seconds left: the mean time per measured method of this run for every method still to measure."""
        measured = [t for times in self.seconds.values() for t in times]
        return self.left * float(np.mean(measured)) if measured else None


def _duration(seconds):
    if seconds is None:
        return "unknown"
    return f"{seconds / 60:.0f} min" if seconds >= 90 else f"{seconds:.0f} s"


def _pixel_saving(names, results, evaluate):
    """Relative cost at which ours reaches the input's q_r at c_r = 0.5; extends ours' curve downwards until it
    crosses (at most to c_r = 1/32), so the answer is a measured crossing, not a bound. ``evaluate(name, costs,
    method)`` measures a UV map (the flat or the shaded mode)."""
    from ..core.evaluation import pixel_saving

    if "input" not in results or "ours" not in results:
        return None
    target = [p["q"] for p in results["input"]["points"] if p["target_cost"] == SAVING_REFERENCE_COST]
    if not target:
        return None
    points = results["ours"]["points"]
    while True:
        saving = pixel_saving([p["relative_cost"] for p in points], [p["q"] for p in points], target[0],
                              reference_cost=SAVING_REFERENCE_COST)
        lowest = min(p["target_cost"] for p in points)
        if saving.bracketed != "below" or lowest <= 1 / 32 or "ours" not in names:
            break
        extra = evaluate(names["ours"], (lowest / 2,), "ours")
        points.append(extra["points"][0])
        points.sort(key=lambda p: p["target_cost"])
    return dict(input_q=target[0], relative_cost=saving.relative_cost, pixel_fraction=saving.pixel_fraction,
                position=saving.bracketed)


def _previous_results(file, methods, *, costs, screen, seed=0):
    """Results and making times of ``methods`` from an earlier ``<model>.json``, checked to match this run."""
    if not methods:
        return {}, {}
    if not file.exists():
        raise SystemExit(f"--reuse: {file} does not exist; run these methods once without --reuse")
    data = json.loads(file.read_text())
    missing = [m for m in methods if m not in data["results"]]
    if missing:
        raise SystemExit(f"--reuse: {file} has no results for {missing}")
    measured_seed = data.get("table", {}).get("seed", 0)
    if measured_seed != seed:
        raise SystemExit(f"--reuse: {file} was measured with --seed {measured_seed}, this run has {seed}")
    for method in methods:
        result = data["results"][method]
        # ours' points may go below the costs (the pixel saving's crossing)
        if result["screen_pixels"] != screen or not set(costs) <= {p["target_cost"] for p in result["points"]}:
            raise SystemExit(f"--reuse: {file} has {method} at other costs or another screen size than this run")
    return {m: data["results"][m] for m in methods}, {m: data["times_s"].get(m) for m in methods}


def compare_model(path, *, costs, methods, evaluations, screen, epsilon, epsilons, workers, out, reuse=(),
                  triangles=None, cache=None, progress=None, shaded=False, seed=0):
    """Runs every method on one model file and writes its plot, crops, markdown table and JSON; returns the table.

    With ``shaded`` every method is measured by ``bridge.evaluate_shaded`` (whole material, q_r per map), the
    files are ``<model>_shaded.*``, the plot is against the maps' image memory, and there are no crops.

    The methods in ``reuse`` are read from the ``<model>.json`` already in ``out`` instead of being run;
    ``triangles`` is the folder of cached triangle-wise results, if any; ``cache`` a :class:`ResultCache`
    whose results are taken and to which every method measured is written as soon as it is; ``progress`` a
    :class:`Progress`.
    """
    import bpy

    from ..bridge.batch import textured_objects
    from ..bridge.evaluate import _reported_size, evaluate_uv_map, mesh_arrays, reference_resolution, render_views
    from ..bridge.mesh_io import import_model
    from ..core.cost import texel_cost
    from ..core.evaluation import symmetric_dirichlet

    stem = path.stem + ("_shaded" if shaded else "")
    reused, reused_times = _previous_results(out / f"{stem}.json", [m for m in methods if m in reuse], costs=costs,
                                             screen=screen, seed=seed)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    import_model(path)
    objects = textured_objects()
    source = objects[0].data.uv_layers.active.name
    V, F, uv = mesh_arrays(objects, source)
    r_input = reference_resolution(objects)
    if shaded:
        from ..bridge.evaluate_shaded import evaluate_shaded, shaded_reference

        reference = shaded_reference(objects, source, screen_pixels=screen)

        def evaluate(name, method_costs, method):
            return evaluate_shaded(objects, name, reference_uv=source, costs=method_costs, screen_pixels=screen,
                                   reference=reference, sizing=SIZING.get(method, "texels"), aspect=aspect(method))
    else:
        reference = render_views(objects, uv_name=source, screen_pixels=screen)

        def evaluate(name, method_costs, method):
            return evaluate_uv_map(objects, name, reference_uv=source, costs=method_costs, screen_pixels=screen,
                                   reference_views=reference, aspect=aspect(method))

    def aspect(method):
        """The image shape the method's map was packed for: its report's, or a cached result's; none for the
        input's own map (measured in the input texture's shape, each map's own for the downscale)."""
        return maps.reports.get(method, results.get(method, {})).get("aspect")

    maps = UVMaps(objects, source, evaluations=evaluations, epsilon=epsilon, workers=workers,
                   cache=None if triangles is None else (triangles, path.stem), seed=seed)
    names, results, cached_times, cached = {"input": source}, {}, {}, []
    # Blender keeps at most 8 UV maps per mesh: each map is evaluated as soon as it exists and then removed,
    # except the two the crops and the pixel saving need.
    failures = {}
    for method in list(methods) + [_epsilon_method(e) for e in epsilons]:
        start = time.perf_counter()
        entry = None if method in reused or cache is None else cache.load(path, method)
        if method in reused or entry is not None:
            results[method] = reused[method] if entry is None else entry["result"]
            if entry is not None:
                cached.append(method)
                cached_times.update(entry["times"])
                if "uv" in entry:
                    _write_map(objects, method, entry["uv"])
                    names[method] = method
            if progress:
                progress.method(stem, method, time.perf_counter() - start, "reused" if entry is None else "cached")
            continue
        before = dict(maps.times)
        try:
            names[method] = maps.make(method)
        except ValueError as error:  # a baseline that cannot handle this input is reported, not fatal
            failures[method] = str(error)
            print(f"{path.stem} {method}: FAILED: {error}", flush=True)
            if progress:
                progress.method(stem, method, time.perf_counter() - start, "failed")
            continue
        results[method] = evaluate(names[method], costs, method)
        report = maps.reports.get(method, {})
        post = {k: v for k, v in report.items() if k.endswith("_charts")}
        if post:
            results[method]["post"] = post
        if "above_bound" in report:
            results[method]["above_bound"] = report["above_bound"]
        print(f"{path.stem} {method}: " + ", ".join(f"c {p['relative_cost']:.3f} q {p['q']:.4g}"
                                                     for p in results[method]["points"]), flush=True)
        if cache is not None:
            # this method's times, and for ours the triangle-wise stage's, even when an earlier method ran it
            triangle = "triangle" if method in OURS_VARIANTS else \
                f"triangle_eps{method[len('ours_eps'):]}" if method.startswith("ours_eps") else None
            own = {k: t for k, t in maps.times.items() if before.get(k) != t or k == triangle}
            cache.save(path, method, result=results[method], times=own,
                       uv=mesh_arrays(objects, names[method])[2] if method in KEPT_MAPS else None)
        if progress:
            progress.method(stem, method, time.perf_counter() - start, "measured")
        if method not in ("input", "ours"):
            maps.remove(names.pop(method))  # the input's own map (downscale's) is never removed
    times = {**{m: t for m, t in reused_times.items() if t is not None}, **cached_times, **maps.times}
    extent = len(results["ours"]["points"]) if "ours" in results else 0
    saving = _pixel_saving(names, results, evaluate)
    if cache is not None and "ours" in results and len(results["ours"]["points"]) != extent and "ours" not in reused:
        # the points the pixel saving added below the costs are kept with ours' result
        entry = cache.load(path, "ours")
        if entry is not None:
            cache.save(path, "ours", result=results["ours"], times=entry["times"], uv=entry.get("uv"))
    surface_area = float(symmetric_dirichlet(V, F, uv, full=True)[1]["area"])
    table = dict(model=stem, vertices=len(V), faces=len(F), surface_area=surface_area,
                 input_resolution=_reported_size(*r_input),
                 input_cost=float(texel_cost(uv, r_input)), epsilon=epsilon, evaluations=evaluations, seed=seed,
                 screen_pixels=screen, t_triangle=times.get("triangle"), t_mesh=times.get("mesh"),
                 pixel_saving=saving, beaten_by=wins(results), failures=failures, reused=sorted(reused),
                 cached=sorted(cached))
    if shaded:
        table["shaded"] = True
        plot_curves(results, out / f"{stem}_q_vs_memory.png", stem, screen, x="memory_ratio")
    else:
        plot_curves(results, out / f"{stem}_q_vs_c.png", stem, screen)
        render_crops(objects, names, source, reference, out / f"{stem}_crops_c030.png", screen)
    (out / f"{stem}.md").write_text(model_markdown(table, results, costs))
    (out / f"{stem}.json").write_text(json.dumps({"table": table, "times_s": times, "results": results}, indent=1))
    return (out / f"{stem}.md").read_text()


def _write_map(objects, name, uv):
    """Write a cached UV map (per face corner, in ``mesh_arrays`` order) as UV map ``name``."""
    from ..bridge.baselines import _write

    _write(objects, name, uv)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+")
    parser.add_argument("--costs", default="0.1,0.2,0.3,0.5")
    parser.add_argument("--out", type=pathlib.Path)
    parser.add_argument("--evaluations", type=int, default=100)
    parser.add_argument("--epsilon", type=float, default=0.01)
    parser.add_argument("--epsilons", default="", help="extra epsilon values for ours (Fig. 18), e.g. 0.005,0.02")
    parser.add_argument("--screen", type=int, default=512)
    parser.add_argument("--workers", type=int, default=0, help="triangle-wise workers (0: one per core)")
    parser.add_argument("--methods", help="comma-separated (default: every method of the mode)")
    parser.add_argument("--reuse", default="", help="methods whose results are read from the <model>.json in --out")
    parser.add_argument("--cache", type=pathlib.Path, help="folder of per-method results (default: <out>/cache)")
    parser.add_argument("--no-cache", action="store_true", help="measure every method again and keep nothing")
    parser.add_argument("--triangles", type=pathlib.Path, help="folder that keeps the triangle-wise results")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the triangle-wise stage (ours and its variants, paper); a few seeds show how "
                             "much q_r moves with the optimizer's random choices alone")
    parser.add_argument("--summary", type=pathlib.Path, help="only rebuild summary.md in this folder")
    parser.add_argument("--shaded", action="store_true",
                        help="evaluate the whole material under fixed lights (Cycles) with q_r per map; adds the "
                             "method downscale")
    args = parser.parse_args(argv)
    if args.summary:
        print(write_summary(args.summary))
        return 0
    if not args.models or args.out is None:
        parser.error("--models and --out are required (or --summary FOLDER)")
    costs = [float(c) for c in args.costs.split(",")]
    epsilons = [float(e) for e in args.epsilons.split(",") if e]
    methods = ([m for m in args.methods.split(",") if m] if args.methods else
               [m for m in METHODS if args.shaded or m not in SHADED_ONLY])
    reuse = [m for m in args.reuse.split(",") if m]
    unknown = (set(methods) | set(reuse)) - set(METHODS)
    if unknown:
        parser.error(f"unknown methods {sorted(unknown)}; choose from {METHODS}")
    flat_only = sorted((set(methods) | set(reuse)) & set(SHADED_ONLY)) if not args.shaded else []
    if flat_only:
        parser.error(f"{', '.join(flat_only)} is measured with --shaded only (the flat mode sees the base colour "
                     "alone, on which a downscale of the input is the input)")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.triangles:
        args.triangles.mkdir(parents=True, exist_ok=True)
    cache = ResultCache(None if args.no_cache else args.cache or args.out / "cache", costs=costs, screen=args.screen,
                        evaluations=args.evaluations, epsilon=args.epsilon, shaded=args.shaded, seed=args.seed)
    models = _models(args.models)
    every = list(methods) + [_epsilon_method(e) for e in epsilons]
    to_measure = {path: [m for m in every if m not in reuse and not (cache.folder and cache.file(path, m).is_file())]
                  for path in models}
    progress = Progress(sum(map(len, to_measure.values())), len(models) * len(every))
    for index, path in enumerate(models, 1):
        progress.model(index, len(models), path.stem, len(to_measure[path]), len(every) - len(to_measure[path]))
        print(compare_model(path, costs=costs, methods=methods, evaluations=args.evaluations, screen=args.screen,
                            epsilon=args.epsilon, epsilons=epsilons, workers=args.workers, out=args.out,
                            reuse=reuse, triangles=args.triangles, cache=cache, progress=progress,
                            shaded=args.shaded, seed=args.seed),
              flush=True)
    print(write_summary(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
