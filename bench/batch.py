"""Benchmark of the batch command (issue 25): assets per hour with 1 and 2 local Dask workers, and the overhead
of the Dask path against plain ``optimize`` calls, measured in one run on the same assets.

Usage::

    .venv/bin/python bench/batch.py [--models ../shared/models] [--model spot [--model bob ...]] [--copies 2]
        [--iterations 10] [--screen-pixels 32] [--max-screen-pixels 32] [--cost 0.3 | --resolution R]
        [--workers 1,2] [--json OUT.json]

The assets are the model files of the chosen folders of ``--models`` (one model per folder, like the other
benchmarks), each ``--copies`` times: a copy of an .obj gets a comment line appended and a copy of a .gltf an
``extras`` entry, so the batch does not treat the copies as duplicates (.glb and .blend models are used once).
Every run writes into a fresh folder. Steps, all sequential on this machine:

1. ``batch`` with each ``--workers`` count (a new LocalCluster each time, its start-up included);
2. plain: ``python -m perceptual_uv optimize`` once per asset, one after the other (what a shell loop does).

Prints the wall time and assets per hour of each, the scaling ratio (assets per hour with the most workers over
one worker), and the overhead of the Dask path per asset: (batch with 1 worker - plain) / assets, of which the
cluster start-up and the per-task part (batch minus the sum of the children's times in its manifest). With
fewer assets than workers the scaling cannot show. Timings on a shared machine are noisy. Skips cleanly (exit 0)
when the models folder is absent.
"""
import argparse
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from pipeline import model_file as pipeline_model_file  # noqa: E402  (bench/pipeline.py, next to this file)

ROOT = pathlib.Path(__file__).resolve().parents[1]


def model_file(folder):
    """The model file of ``folder`` (bench/pipeline.py's choice), or None when it has none."""
    try:
        return pipeline_model_file(folder)
    except SystemExit:
        return None


def copy_model(source, target_dir, index):
    """Copy a model's folder to ``target_dir``; copy ``index`` > 0 gets a harmless change to its bytes.

    Returns the copied model file, or None when such a copy cannot be made (.glb, .blend)."""
    suffix = source.suffix.lower()
    if index and suffix not in (".obj", ".gltf"):
        return None
    shutil.copytree(source.parent, target_dir)
    copied = target_dir / source.name
    if index and suffix == ".obj":
        with open(copied, "a") as stream:
            stream.write(f"\n# batch benchmark copy {index}\n")
    elif index and suffix == ".gltf":
        data = json.loads(copied.read_text())
        data.setdefault("asset", {}).setdefault("extras", {})["batch_benchmark_copy"] = index
        copied.write_text(json.dumps(data))
    return copied


def settings_args(args):
    size = ["--resolution", str(args.resolution)] if args.resolution else ["--cost", str(args.cost)]
    return ["--iterations", str(args.iterations), "--screen-pixels", str(args.screen_pixels),
            "--max-screen-pixels", str(args.max_screen_pixels), *size]


def run_plain(assets, out, args):
    started = time.perf_counter()
    for asset in assets:
        name = asset.stem
        result = subprocess.run([sys.executable, "-m", "perceptual_uv", "optimize", str(asset), "--out",
                                 str(out / name / f"{name}.blend"), "--report", str(out / name / "report.json"),
                                 "--workers", "1", *settings_args(args)], capture_output=True, text=True)
        if result.returncode != 0:
            raise SystemExit(f"optimize {asset} failed: {result.stderr.strip().splitlines()[-1:]}")
    return time.perf_counter() - started


def run_batch(library, out, workers, args):
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "perceptual_uv", "batch", str(library), "--out", str(out),
                             "--workers", str(workers), "--retries", "0", *settings_args(args)],
                            capture_output=True, text=True)
    wall = time.perf_counter() - started
    if result.returncode != 0:
        raise SystemExit(f"batch with {workers} workers failed ({result.returncode}): {result.stdout[-2000:]}"
                         f"{result.stderr[-2000:]}")
    entries = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    return wall, sum(e["time_s"] for e in entries if not e.get("duplicate_of"))


def cluster_startup(workers):
    """Seconds to start and close a LocalCluster like the batch's, in a fresh process."""
    code = ("import time, logging; t = time.perf_counter(); from distributed import Client, LocalCluster; "
            f"c = LocalCluster(n_workers={workers}, threads_per_worker=1, processes=True, memory_limit=0, "
            "silence_logs=logging.ERROR); Client(c).close(); c.close(); print(time.perf_counter() - t)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(result.stdout.split()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=pathlib.Path, default=ROOT.parent / "shared" / "models")
    parser.add_argument("--model", action="append", help="model folder name (default: every folder)")
    parser.add_argument("--copies", type=int, default=2, help="assets per model (default 2)")
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--screen-pixels", type=int, default=32)
    parser.add_argument("--max-screen-pixels", type=int, default=32)
    parser.add_argument("--cost", type=float, default=0.3)
    parser.add_argument("--resolution", type=int)
    parser.add_argument("--workers", default="1,2", help="comma-separated local worker counts (default 1,2)")
    parser.add_argument("--json", type=pathlib.Path)
    args = parser.parse_args()
    try:
        import distributed  # noqa: F401
    except ImportError:
        print("skipped: the batch command needs Dask: pip install dask distributed")
        return 0
    if not args.models.is_dir():
        print(f"skipped: no models folder at {args.models}")
        return 0
    folders = [args.models / name for name in args.model] if args.model else sorted(
        p for p in args.models.iterdir() if p.is_dir())
    sources = [f for f in (model_file(folder) for folder in folders) if f is not None]
    if not sources:
        print(f"skipped: no model files in {args.models}")
        return 0
    counts = sorted({int(w) for w in args.workers.split(",")})
    with tempfile.TemporaryDirectory(prefix="perceptual-uv-batch-bench-") as scratch:
        scratch = pathlib.Path(scratch)
        library = scratch / "library"
        assets = []
        for source in sources:
            for index in range(max(1, args.copies)):
                copied = copy_model(source, library / f"{source.parent.name}_{index}", index)
                if copied is not None:
                    assets.append(copied)
        n = len(assets)
        print(f"{n} assets from {len(sources)} models ({', '.join(s.parent.name for s in sources)}), "
              f"settings {' '.join(settings_args(args))}")
        results = {}
        for workers in counts:
            wall, children = run_batch(library, scratch / f"batch{workers}", workers, args)
            results[workers] = {"wall_s": wall, "children_s": children, "assets_per_hour": n / wall * 3600}
            print(f"batch, {workers} worker(s): {wall:.1f} s, {n / wall * 3600:.1f} assets/h "
                  f"(children {children:.1f} s in all)")
        plain = run_plain(assets, scratch / "plain", args)
        print(f"plain optimize, one after the other: {plain:.1f} s, {n / plain * 3600:.1f} assets/h")
        startup = cluster_startup(counts[0])
    report = {"assets": n, "models": [s.parent.name for s in sources], "settings": settings_args(args),
              "plain_s": plain, "plain_assets_per_hour": n / plain * 3600, "batch": results,
              "cluster_startup_s": startup}
    if 1 in results:
        one = results[1]
        report["overhead_per_asset_s"] = (one["wall_s"] - plain) / n
        report["task_overhead_per_asset_s"] = (one["wall_s"] - one["children_s"] - startup) / n
        print(f"Dask path overhead per asset (batch with 1 worker - plain) / {n}: "
              f"{report['overhead_per_asset_s']:.2f} s; cluster start-up and close {startup:.1f} s once; "
              f"per task beyond the child {report['task_overhead_per_asset_s']:.2f} s")
        print(f"ratio batch 1 worker / plain: {one['wall_s'] / plain:.3f}")
    if len(counts) > 1:
        low, high = results[counts[0]], results[counts[-1]]
        report["scaling"] = high["assets_per_hour"] / low["assets_per_hour"]
        print(f"scaling: assets/h with {counts[-1]} workers / with {counts[0]}: {report['scaling']:.2f} "
              f"(ideal {counts[-1] / counts[0]:.0f}; this machine has {os.cpu_count()} cores)")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
