"""Benchmark of the whole pipeline: every stage's time, ms per face, the longest step, peak memory.

Usage::

    .venv/bin/python bench/pipeline.py --models ../shared/models/spot ../shared/models/bob \
        [--against REV] [--workers 2] [--iterations 100] [--operator] [--set NAME=VALUE ...] [--json OUT.json]

Each model runs in a fresh process (``--models`` takes model folders or files) at the default settings, driving the
job that ``optimize`` and the modal operator run (every texture of the file, one run each:
``bridge.texture_sets.iter_optimize_textures``) the way the operator does: one ``next`` per step. Printed per model
and revision: the stage times of the report (``read`` is everything before the triangle-wise stage), the
triangle-wise stage in ms per optimized face, the longest single step of the generator and the stage it belongs to
(the interface freezes for as long as one step takes), and the peak memory of the run's whole process tree (the
pipeline process and its worker or bake processes): the sum of their resident sizes, sampled every 0.1 s (a new
process found within a second), and the sum of their proportional set sizes, which counts the pages they share (the
workers' shared arrays) once, sampled every second and once per stage (a peak shorter than that may be missed), with
the stage it came in and how it splits between the pipeline process and the others; below each row, the five longest
steps with the stage and message of the progress report they follow, and how many cores were busy on average during
each stage (the CPU time of the whole process tree over the stage's wall time: where it stays below the cores, a
stage waits on one process), and the share of a core the sampler itself took. ``--json`` also holds each stage's
peak (``peak_by_stage``, proportional) and CPU and wall seconds (``cpu_by_stage``).

``--operator`` runs with the settings the modal operator adds to the defaults (``bake_in_background``), the way
"Optimize UVs" drives the pipeline in the interface; ``--set NAME=VALUE`` sets any field of
``core.settings.OptimizeSettings`` (the value read as a Python literal, else as a string). A revision whose
``OptimizeSettings`` lacks a field runs without it.

With ``--against REV`` the same models also run on another git revision of this repository, checked out once
into a worktree under the system's temporary folder, in the same session, alternating revision by revision per
model, and the ratios ``this / REV`` are printed: these machines are noisy, only ratios measured in one run
count. Each revision first optimizes the bundled spot model once at 10 evaluations per face, so that numba's
compile cache is warm for both and no measured run pays for compilation.
"""
import argparse
import contextlib
import hashlib
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parent.parent
WARMUP_MODEL = REPO / "tests" / "data" / "spot" / "spot_triangulated.obj"
# How often the sampler reads the proportional set sizes and walks /proc for the process tree: smaps_rollup walks
# a process's page tables (7-22 ms per process of a run), so reading it every 0.1 s would take about a sixth of a
# core from the run it measures, whose workers fill the cores. The resident sizes (/proc/PID/statm, a counter)
# and the CPU times of the processes known are read every 0.1 s.
PROPORTIONAL_SECONDS = 1.0

STAGES = ("read", "triangle", "mesh", "pack", "bake", "total")


def model_file(path):
    """The model file ``path`` names: itself, or the first model file (by name) in the folder."""
    # Imported here: a run of another revision (--against) imports this script with that revision's package.
    from perceptual_uv.core.settings import MODEL_SUFFIXES

    path = pathlib.Path(path)
    if path.is_file():
        return path
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in MODEL_SUFFIXES) if path.is_dir() else []
    if not files:
        raise SystemExit(f"no model file ({', '.join(MODEL_SUFFIXES)}) in {path}")
    return files[0]


def _tuples(value):
    """``value`` with JSON's lists turned back into the tuples the frozen settings hold."""
    return tuple(_tuples(item) for item in value) if isinstance(value, list) else value


def run_pipeline(path, settings_options, stage_file=None):
    """Optimize ``path`` in this process, driving the generator step by step; a dict of measurements.

    Run inside the child process, with the package of the revision under test on ``sys.path``. The name of the
    stage running is written to ``stage_file`` at each change of stage, for the parent's memory samples.
    """
    def enter(stage_name):
        if stage_file is not None:
            pathlib.Path(stage_file).write_text(stage_name)

    import bpy

    from perceptual_uv.bridge.mesh_io import import_model
    from perceptual_uv.core.settings import OptimizeSettings

    enter("import")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    started = time.perf_counter()
    import_model(path)
    imported = time.perf_counter() - started
    output_dir = tempfile.TemporaryDirectory(prefix="perceptual_uv-bench-")
    known = {name: _tuples(value) for name, value in settings_options.items()  # an older revision may lack one
             if name in OptimizeSettings.__dataclass_fields__}
    settings = OptimizeSettings(**known)
    try:  # the job `optimize` and the Optimize UVs button run: every texture of the file
        from perceptual_uv.bridge.texture_sets import combined_report, iter_optimize_textures
    except ImportError:  # a revision from before files of several textures ran
        from perceptual_uv.bridge.batch import textured_objects
        from perceptual_uv.bridge.pipeline import optimize_objects

        pipeline = optimize_objects(textured_objects(), settings, output_dir=output_dir.name)
    else:
        pipeline = iter_optimize_textures(list(bpy.context.scene.objects), settings, output_dir=output_dir.name)
    durations = []  # (seconds, stage and message of the step's start)
    step_started, stage = time.perf_counter(), "start"
    while True:
        try:
            progress = next(pipeline)
        except StopIteration as finished:
            result = finished.value
            durations.append((time.perf_counter() - step_started, stage))
            break
        durations.append((time.perf_counter() - step_started, stage))
        if not stage.startswith(f"{progress.stage}:"):
            enter(progress.stage)
        stage = f"{progress.stage}: {progress.message}"
        step_started = time.perf_counter()
    durations.sort(reverse=True)
    longest, longest_stage = durations[0]
    steps = len(durations)
    output_dir.cleanup()
    if isinstance(result, list):  # iter_optimize_textures: (objects, result) per texture
        runs = [run.report for _, run in result]
        report = runs[0] if len(runs) == 1 else combined_report(runs)
    else:
        runs, report = [result.report], result.report
    times = dict(report["times_s"])
    times["read"] = times["total"] - sum(times.get(name, 0.0) for name in ("triangle", "mesh", "pack", "bake"))
    optimized = report.get("optimized_triangles", report["faces"])
    return {"model": str(path), "faces": report["faces"], "optimized_faces": optimized,
            "import_s": imported, "times_s": times,
            "triangle_ms_per_face": 1000 * times["triangle"] / max(optimized, 1),
            "longest_step_s": longest, "longest_step_stage": longest_stage.split(":")[0], "steps": steps,
            "longest_steps": [[round(seconds, 3), where] for seconds, where in durations[:5]],
            "textures": len(runs), **{key: [run[key] for run in runs] if len(runs) > 1 else report[key]
                                      for key in ("resolution", "relative_cost")}}


def _children():
    """Parent pid -> child pids, from /proc."""
    tree = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        tree.setdefault(int(fields[1]), []).append(int(entry))
    return tree


def _process_memory(pid, page, proportional=True):
    """``(resident, proportional)`` bytes of one process. The proportional set size (``Pss`` of
    /proc/PID/smaps_rollup) splits each shared page between the processes that map it, so the sum over a process
    tree counts the workers' shared arrays once; where the kernel has no smaps_rollup, or without
    ``proportional``, it is the resident size."""
    with open(f"/proc/{pid}/statm") as statm:
        resident = int(statm.read().split()[1]) * page
    if not proportional:
        return resident, resident
    try:
        with open(f"/proc/{pid}/smaps_rollup") as rollup:
            for line in rollup:
                if line.startswith("Pss:"):
                    return resident, int(line.split()[1]) * 1024
    except OSError:
        pass
    return resident, resident


def _tree_pids(pid, tree):
    """``pid`` and its descendants in ``tree`` (parent pid -> child pids, :func:`_children`), ``pid`` first."""
    pids, stack = [], [pid]
    while stack:
        current = stack.pop()
        pids.append(current)
        stack.extend(tree.get(current, []))
    return pids


def tree_memory(pid, tree=None, *, proportional=True):
    """Memory of ``pid`` and of its descendants: ``(own, descendants, live descendants)``, ``own`` and
    ``descendants`` each ``(resident, proportional)`` bytes (zeros once it is gone). ``tree`` as from
    :func:`_children`, read now by default; without ``proportional`` the proportional sizes are the resident
    ones (reading them walks each process's page tables: milliseconds per process)."""
    own, others, count = (0, 0), (0, 0), 0
    page = os.sysconf("SC_PAGE_SIZE")
    for current in _tree_pids(pid, _children() if tree is None else tree):
        try:
            memory = _process_memory(current, page, proportional)
        except OSError:
            memory = None
        if current == pid:
            own = memory or (0, 0)
        elif memory is not None:
            others, count = (others[0] + memory[0], others[1] + memory[1]), count + 1
    return own, others, count


def tree_cpu_ticks(pid, tree=None):
    """Clock ticks of CPU time (user + system) used so far by ``pid`` and by each of its live descendants:
    ``{pid: ticks}``. ``tree`` as from :func:`_children`, read now by default."""
    ticks = {}
    for current in _tree_pids(pid, _children() if tree is None else tree):
        try:
            with open(f"/proc/{current}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
            ticks[current] = int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15 of stat)
        except (OSError, IndexError, ValueError):
            pass
    return ticks


def _peak_entry(own, others, count):
    return {"total_gib": (own + others) / 2 ** 30, "pipeline_gib": own / 2 ** 30, "others_gib": others / 2 ** 30,
            "other_processes": count}


def measure(tree, path, settings_options):
    """Run ``path`` in a child process on the package at ``tree``; its measurements and peak tree memory."""
    tree_hash = hashlib.sha1(str(tree).encode()).hexdigest()[:12]
    package_root = pathlib.Path(tempfile.gettempdir()) / f"perceptual_uv-bench-path-{tree_hash}"
    package_root.mkdir(exist_ok=True)
    link = package_root / "perceptual_uv"
    if not link.exists():
        link.symlink_to(tree, target_is_directory=True)
    env = dict(os.environ, PYTHONPATH=str(package_root))
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as handle:
        out = pathlib.Path(handle.name)
    stage_file = out.with_suffix(".stage")
    command = [sys.executable, str(pathlib.Path(__file__).resolve()), "--run-one", str(path), "--json", str(out),
               "--settings", json.dumps(settings_options), "--stage-file", str(stage_file)]
    child = subprocess.Popen(command, env=env, cwd=str(tree), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             text=True)
    # stage -> (total, own, others, count) in proportional bytes at the stage's highest total; the resident sum too
    peaks, stage, peak_resident = {}, "start", 0
    # stage -> [CPU seconds of the whole tree, wall seconds], from the ticks each process used between samples (a
    # process that ends between two samples loses at most its last 0.1 s)
    busy, last_ticks, last_sample, tick = {}, {}, time.perf_counter(), os.sysconf("SC_CLK_TCK")
    # The proportional sizes at most every PROPORTIONAL_SECONDS and once in every stage (see the constant)
    proportional_due, proportional_stage = last_sample, None
    sampler_cpu = time.process_time()
    while child.poll() is None:
        proportional = last_sample >= proportional_due or stage != proportional_stage
        if proportional:
            # The process tree, from one walk of /proc (about 3 ms) at the same pace: a process found up to a
            # second late is booked its whole CPU time from its start; a process gone is skipped.
            processes = _children()
            proportional_due, proportional_stage = last_sample + PROPORTIONAL_SECONDS, stage
        own, others, count = tree_memory(child.pid, processes, proportional=proportional)
        ticks, now = tree_cpu_ticks(child.pid, processes), time.perf_counter()
        entry = busy.setdefault(stage, [0.0, 0.0])
        entry[0] += sum(max(value - last_ticks.get(pid, 0), 0) for pid, value in ticks.items()) / tick
        entry[1] += now - last_sample
        last_ticks, last_sample = ticks, now
        with contextlib.suppress(OSError):
            stage = stage_file.read_text().strip() or stage
        peak_resident = max(peak_resident, own[0] + others[0])
        if proportional and own[1] + others[1] > peaks.get(stage, (-1,))[0]:
            peaks[stage] = (own[1] + others[1], own[1], others[1], count)
        time.sleep(0.1)
    sampler_cpu = time.process_time() - sampler_cpu
    errors = child.stderr.read()
    stage_file.unlink(missing_ok=True)
    if child.returncode != 0:
        raise SystemExit(f"{path} on {tree} failed (exit {child.returncode}):\n{errors[-2000:]}")
    result = json.loads(out.read_text())
    out.unlink()
    result["peak_by_stage"] = {name: _peak_entry(*values[1:]) for name, values in peaks.items()}
    result["peak_stage"] = max(peaks, key=lambda name: peaks[name][0]) if peaks else "none"
    result["peak_pss_gib"] = peaks[result["peak_stage"]][0] / 2 ** 30 if peaks else 0.0
    result["peak_rss_gib"] = peak_resident / 2 ** 30
    result["sampler_cores"] = sampler_cpu / max(sum(wall for _, wall in busy.values()), 1e-9)
    result["cpu_by_stage"] = {name: {"cpu_s": cpu, "wall_s": wall, "cores_busy": cpu / wall if wall else 0.0}
                              for name, (cpu, wall) in busy.items()}
    return result


def worktree(revision):
    """A worktree of ``revision`` (a commit, kept under the temporary folder and reused across runs)."""
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", f"{revision}^{{commit}}"],
                            capture_output=True, text=True)
    if commit.returncode != 0:
        raise SystemExit(f"--against {revision}: not a revision of {REPO}")
    commit = commit.stdout.strip()
    folder = pathlib.Path(tempfile.gettempdir()) / f"perceptual_uv-bench-{commit[:12]}"
    if not (folder / "__init__.py").exists():
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "--force", str(folder), commit],
                       check=True, capture_output=True)
    return folder, commit[:12]


OPERATOR_SETTINGS = {"bake_in_background": True}  # what operators.optimize_uvs adds when it runs modal


def setting_option(text):
    """``NAME=VALUE`` of ``--set`` as ``(name, value)``, the value a Python literal if it reads as one."""
    import ast

    name, separator, value = text.partition("=")
    if not separator or not name.isidentifier():
        raise argparse.ArgumentTypeError(f"{text!r}: expected NAME=VALUE")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


def _steps(result):
    """The five longest steps of ``result``, one line each."""
    return [f"      {seconds:6.3f} s  {where[:110]}" for seconds, where in result.get("longest_steps", [])]


def _row(label, result):
    times = result["times_s"]
    stages = " ".join(f"{name} {times.get(name, float('nan')):7.1f}" for name in STAGES)
    peak = result.get("peak_by_stage", {}).get(result.get("peak_stage"))
    where = (f", proportional {result['peak_pss_gib']:.2f} ({result['peak_stage']}: pipeline {peak['pipeline_gib']:.2f}"
             f" + {peak['other_processes']} other processes {peak['others_gib']:.2f})") if peak else ""
    return (f"  {label:<14} {stages}  {result['triangle_ms_per_face']:7.1f} ms/face  longest step "
            f"{result['longest_step_s']:6.2f} s ({result['longest_step_stage']})  peak {result['peak_rss_gib']:.2f} GiB"
            f"{where}")


def _busy_row(result):
    """Cores busy on average during each stage (CPU seconds of the process tree over wall seconds)."""
    stages = result.get("cpu_by_stage", {})
    parts = [f"{name} {stages[name]['cores_busy']:.2f}" for name in ("read", "triangle", "mesh", "pack", "bake")
             if name in stages and stages[name]["wall_s"] > 0.5]
    if not parts:
        return ""
    sampler = f" (this benchmark's sampler: {result['sampler_cores']:.3f})" if "sampler_cores" in result else ""
    return f"      cores busy (of {os.cpu_count()}): " + ", ".join(parts) + sampler


def _ratio_row(result, reference):
    ratios = []
    for name in STAGES:
        ours, theirs = result["times_s"].get(name), reference["times_s"].get(name)
        ratios.append(f"{name} {ours / theirs:7.2f}" if ours is not None and theirs else f"{name}     n/a")
    ms = result["triangle_ms_per_face"] / max(reference["triangle_ms_per_face"], 1e-9)
    step = result["longest_step_s"] / max(reference["longest_step_s"], 1e-9)
    memory = result["peak_rss_gib"] / max(reference["peak_rss_gib"], 1e-9)
    if "peak_pss_gib" in result and "peak_pss_gib" in reference:
        memory = f"{memory:.2f}, proportional {result['peak_pss_gib'] / max(reference['peak_pss_gib'], 1e-9):.2f}"
    else:
        memory = f"{memory:.2f}"
    return f"  {'ratio':<14} {' '.join(ratios)}  {ms:7.2f} ms/face  longest step {step:6.2f}    peak {memory}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", help="model folders or files")
    parser.add_argument("--against", help="another git revision to measure in the same run")
    parser.add_argument("--workers", type=int, default=0, help="worker processes (0: one per core)")
    parser.add_argument("--iterations", type=int, default=None, help="evaluations per face (default: the default)")
    parser.add_argument("--operator", action="store_true",
                        help="the settings of the modal operator (bake in a background process)")
    parser.add_argument("--set", dest="overrides", action="append", type=setting_option, default=[],
                        metavar="NAME=VALUE", help="set a field of OptimizeSettings (repeatable)")
    parser.add_argument("--no-warmup", action="store_true", help="skip the compile warm-up run per revision")
    parser.add_argument("--json", type=pathlib.Path, help="write all measurements here")
    parser.add_argument("--run-one", help=argparse.SUPPRESS)
    parser.add_argument("--settings", default="{}", help=argparse.SUPPRESS)
    parser.add_argument("--stage-file", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.run_one:  # the child process
        result = run_pipeline(args.run_one, json.loads(args.settings), args.stage_file)
        args.json.write_text(json.dumps(result))
        return 0
    if not args.models:
        parser.error("--models is required")

    settings = {"workers": args.workers, "reuse_triangle_results": False}
    if args.iterations is not None:
        settings["iterations"] = args.iterations
    if args.operator:
        settings.update(OPERATOR_SETTINGS)
    settings.update(args.overrides)
    models = []
    for path in args.models:
        if not pathlib.Path(path).exists():
            print(f"skipping {path}: not found", file=sys.stderr)
            continue
        models.append(model_file(pathlib.Path(path).resolve()))  # each revision runs in its own folder
    trees = [("this", REPO)]
    if args.against:
        folder, commit = worktree(args.against)
        trees.append((commit, folder))
    if not args.no_warmup:
        for label, tree in trees:
            print(f"warm-up on {label}", flush=True)
            measure(tree, WARMUP_MODEL, dict(settings, iterations=10))
    results = {}
    for path in models:
        print(f"{path.parent.name}/{path.name}", flush=True)
        for label, tree in trees:
            result = measure(tree, path, settings)
            results.setdefault(path.parent.name, {})[label] = result
            print(_row(label, result), flush=True)
            print(_busy_row(result), flush=True)
            print("\n".join(_steps(result)), flush=True)
        if args.against:
            print(_ratio_row(results[path.parent.name]["this"], results[path.parent.name][trees[1][0]]), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"settings": settings, "against": args.against, "results": results},
                                        indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
