"""Benchmark of the triangle-wise stage (issue 3, item 10): speed and quality against scikit-optimize.

Usage::

    .venv/bin/python bench/trianglewise.py --model ../shared/models/spot [--faces N] [--evaluations 100] \
        [--workers 0] [--seed 0] [--skopt-sample 30] --json OUT.json

Prints and writes: faces, evaluations per triangle (budget and mean used), wall seconds (worker start-up
included), ms per face, fraction of triangles with E <= epsilon, mean lambda1 * lambda2, and, on a fixed
sample of non-constant triangles (constant one-rings skip the optimization in every backend), the
comparison with the paper's setting (scikit-optimize ``gp_minimize`` on the barrier form Eq. 14) at the
same evaluation budget: ``objective_ratio_vs_skopt`` is the median over triangles where both results satisfy
E <= epsilon of ours / theirs achieved lambda1 * lambda2, and ``speedup_vs_skopt`` the ratio of wall times on
that sample with the same number of workers. The same comparison is printed for the fast engine on the
barrier form, the formulation the default replaces.
"""
import argparse
import json
import os
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from pipeline import model_file as find_model_file  # noqa: E402  (bench/pipeline.py, next to this file)


def load_model(directory):
    """``(V, F, uv, texture)`` of the model file in ``directory`` (read through Blender's importers)."""
    from perceptual_uv.bridge.mesh_io import load_textured_mesh

    path = find_model_file(directory)
    mesh, texture, _ = load_textured_mesh(path)
    return mesh.V, mesh.F, mesh.uv, np.asarray(texture[..., :3], dtype=np.float64), path.name


def _area(result):
    return result.params[:, 1] * result.params[:, 2]


def compare(V, F, uv, luma, sample, *, evaluations, workers, seed, reference):
    """Run the fast engine (default and barrier) on ``sample`` and compare with ``reference``."""
    from perceptual_uv.core.trianglewise import optimize_triangles

    rows = {}
    for name, options in (("fast", {}), ("fast_barrier", {"formulation": "barrier"})):
        started = time.perf_counter()
        result = optimize_triangles(V, F, uv, luma, faces=sample, evaluations=evaluations, workers=workers,
                                    seed=seed, chunk_size=1, **options)
        seconds = time.perf_counter() - started
        both = result.feasible & reference["result"].feasible
        ratio = _area(result)[both] / _area(reference["result"])[both]
        rows[name] = {"seconds": seconds, "objective_ratio": float(np.median(ratio)) if both.any() else None,
                      "ratio_quartiles": np.quantile(ratio, [0.25, 0.75]).tolist() if both.any() else None,
                      "both_feasible": int(both.sum()), "feasible": float(result.feasible.mean()),
                      "mean_area": float(_area(result).mean())}
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="folder with one .obj/.gltf/.glb model")
    parser.add_argument("--faces", type=int, default=None, help="a fixed random sample of N faces (default all)")
    parser.add_argument("--evaluations", type=int, default=100)
    parser.add_argument("--epsilon", type=float, default=0.01)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skopt-sample", type=int, default=30, help="triangles compared with skopt (0: skip)")
    parser.add_argument("--json", required=True)
    args = parser.parse_args(argv)

    from perceptual_uv.core.trianglewise import optimize_triangles

    V, F, uv, texture, model_file = load_model(args.model)
    from perceptual_uv.core.loss import texture_luma

    luma = texture_luma(texture)
    rng = np.random.default_rng(0)
    faces = np.arange(len(F)) if args.faces is None else np.sort(rng.choice(len(F), min(args.faces, len(F)),
                                                                             replace=False))
    started = time.perf_counter()
    result = optimize_triangles(V, F, uv, luma, faces=faces, epsilon=args.epsilon, evaluations=args.evaluations,
                                workers=args.workers, seed=args.seed)
    wall = time.perf_counter() - started
    report = {
        "model": model_file,
        "faces": int(len(faces)),
        "mesh_faces": int(len(F)),
        "evaluations_per_triangle": args.evaluations,
        "evaluations_used_mean": float(result.evaluations.mean()),
        "evaluations_used_mean_nonconstant": float(result.evaluations[~result.is_constant].mean())
        if (~result.is_constant).any() else 0.0,
        "workers": args.workers or os.cpu_count(),
        "wall_seconds": round(wall, 3),
        "ms_per_face": round(1000 * wall / len(faces), 3),
        "constant_fraction": float(result.is_constant.mean()),
        "fraction_within_epsilon": float(np.mean(result.loss <= args.epsilon)),
        "mean_lambda1_lambda2": float(_area(result).mean()),
        "mean_lambda1_lambda2_nonconstant": float(_area(result)[~result.is_constant].mean())
        if (~result.is_constant).any() else None,
        "epsilon": args.epsilon,
        "formulation": result.formulation,
    }
    print(json.dumps(report, indent=1), flush=True)

    if args.skopt_sample:
        candidates = result.faces[~result.is_constant]
        sample = np.sort(np.random.default_rng(1).choice(candidates, min(args.skopt_sample, len(candidates)),
                                                         replace=False))
        started = time.perf_counter()
        theirs = optimize_triangles(V, F, uv, luma, faces=sample, epsilon=args.epsilon,
                                    evaluations=args.evaluations, workers=args.workers, seed=args.seed,
                                    backend="skopt", chunk_size=1)
        skopt_seconds = time.perf_counter() - started
        rows = compare(V, F, uv, luma, sample, evaluations=args.evaluations, workers=args.workers, seed=args.seed,
                       reference={"result": theirs})
        report.update({
            "skopt_sample_faces": sample.tolist(),
            "skopt_seconds": round(skopt_seconds, 3),
            "skopt_feasible": float(theirs.feasible.mean()),
            "skopt_mean_area": float(_area(theirs).mean()),
            "objective_ratio_vs_skopt": rows["fast"]["objective_ratio"],
            "objective_ratio_quartiles_vs_skopt": rows["fast"]["ratio_quartiles"],
            "both_feasible": rows["fast"]["both_feasible"],
            "speedup_vs_skopt": round(skopt_seconds / rows["fast"]["seconds"], 2),
            "fast_seconds_on_sample": round(rows["fast"]["seconds"], 3),
            "fast_mean_area_on_sample": rows["fast"]["mean_area"],
            "barrier_fast_objective_ratio_vs_skopt": rows["fast_barrier"]["objective_ratio"],
            "barrier_fast_ratio_quartiles_vs_skopt": rows["fast_barrier"]["ratio_quartiles"],
            "barrier_fast_mean_area_on_sample": rows["fast_barrier"]["mean_area"],
            "barrier_fast_speedup_vs_skopt": round(skopt_seconds / rows["fast_barrier"]["seconds"], 2),
        })
        print(json.dumps({key: value for key, value in report.items() if key != "skopt_sample_faces"}, indent=1))
    pathlib.Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
