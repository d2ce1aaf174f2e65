"""Benchmark of the mesh-wise solver (core.meshwise) on real models with targets drawn from the box of Eq. 14.

Usage::

    .venv/bin/python bench/meshwise.py --model ../shared/models/spot [--model DIR ...] [--json OUT.json]
        [--seed 0] [--max-iterations 100] [--weights perceptual|identity] [--formulation perceptual|common]

Each model is loaded through Blender's importers (bridge.mesh_io, the pipeline's own input path). Targets are
random: alpha, beta uniform in [0, pi/2), lambda1, lambda2 uniform in [0.05, 1], w_R, w_S uniform in [0, 1]
(the triangle-wise stage is too slow to run here on whole models). Per model it prints and writes faces,
chart vertices, charts, iterations, seconds, ms per face, flipped and degenerate triangles, overlapping UV
pairs before and after (within / between charts), the fit energy (Eq. 16, area-weighted) at the input map and
at the result, and the objective history's first and last values. Timings on a shared machine are noisy.
"""
import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))

from perceptual_uv.core.charts import uv_topology  # noqa: E402
from perceptual_uv.core.deformation import jacobian  # noqa: E402
from perceptual_uv.core.meshwise import solve_meshwise  # noqa: E402
from perceptual_uv.core.meshwise_local import fit_energy  # noqa: E402
from perceptual_uv.core.overlap import count_overlaps  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from pipeline import model_file  # noqa: E402  (bench/pipeline.py, next to this file)


def random_box_targets(m, seed):
    rng = np.random.default_rng(seed)
    params = np.column_stack([rng.uniform(0, np.pi / 2, m), rng.uniform(0.05, 1, m), rng.uniform(0.05, 1, m),
                              rng.uniform(0, np.pi / 2, m)])
    return params, rng.uniform(0, 1, m), rng.uniform(0, 1, m)


def run(path, args):
    from perceptual_uv.bridge.mesh_io import load_textured_mesh

    mesh, _, _ = load_textured_mesh(path)
    F, uv = mesh.F, mesh.uv
    m = len(F)
    params, w_R, w_S = random_box_targets(m, args.seed)
    topology = uv_topology(F, uv)
    overlaps_in = count_overlaps(uv, topology.face_chart)

    started = time.perf_counter()
    result = solve_meshwise(F, uv, params, w_R, w_S, weights=args.weights, formulation=args.formulation,
                            max_iterations=args.max_iterations)
    seconds = time.perf_counter() - started

    clock = time.perf_counter()
    overlaps_out = count_overlaps(result.uv, result.topology.face_chart)
    overlap_seconds = time.perf_counter() - clock

    R_bar, S_bar = jacobian(params)
    if args.weights == "identity":
        w_R = w_S = np.ones(m)
    area = np.abs(np.cross(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]))
    valid = area > 0
    weight = np.where(valid, area / area[valid].mean(), 0.0)
    at_input, _ = fit_energy(np.tile(np.eye(2), (m, 1, 1)), R_bar, S_bar, w_R, w_S, formulation=args.formulation)
    return {
        "model": path.parent.name,
        "file": path.name,
        "faces": m,
        "chart_vertices": result.topology.n_vertices,
        "charts": result.topology.n_charts,
        "mirrored_charts": int(np.sum(result.topology.chart_orientation < 0)),
        "iterations": result.iterations,
        "converged": result.converged,
        "seconds": seconds,
        "ms_per_face": 1000.0 * seconds / m,
        "flipped": result.flipped,
        "degenerate": result.degenerate,
        "overlapping_pairs_input": overlaps_in.total,
        "overlapping_pairs": overlaps_out.total,
        "overlapping_pairs_within_charts": overlaps_out.within_charts,
        "overlapping_pairs_between_charts": overlaps_out.between_charts,
        "overlap_seconds": overlap_seconds,
        "fit_energy_input": float(np.sum(weight * at_input)),
        "fit_energy": result.fit_energy,
        "objective_first": float(result.energy_history[0]),
        "objective_last": float(result.energy_history[-1]),
        "barrier_weight": result.barrier_weight,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", action="append", required=True, help="model folder or file (repeatable)")
    parser.add_argument("--json", type=pathlib.Path, help="write the rows as a JSON list")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-iterations", type=int, default=100)
    parser.add_argument("--weights", choices=("perceptual", "identity"), default="perceptual")
    parser.add_argument("--formulation", choices=("perceptual", "common"), default="perceptual")
    args = parser.parse_args(argv)

    # Compile (or load from numba's cache) the overlap kernel outside the timings.
    count_overlaps(np.array([[[0.0, 0], [1, 0], [0, 1]], [[0.1, 0.1], [0.5, 0.1], [0.1, 0.5]]]))

    rows = []
    header = (f"{'model':<24}{'faces':>7}{'charts':>7}{'iter':>6}{'s':>8}{'ms/face':>9}{'flip':>6}{'degen':>6}"
              f"{'ovl in':>8}{'ovl out':>9}{'fit in':>11}{'fit out':>11}")
    print(header)
    for folder in args.model:
        row = run(model_file(folder), args)
        rows.append(row)
        print(f"{row['model']:<24}{row['faces']:>7}{row['charts']:>7}{row['iterations']:>6}{row['seconds']:>8.2f}"
              f"{row['ms_per_face']:>9.3f}{row['flipped']:>6}{row['degenerate']:>6}"
              f"{row['overlapping_pairs_input']:>8}{row['overlapping_pairs']:>9}"
              f"{row['fit_energy_input']:>11.4g}{row['fit_energy']:>11.4g}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    worst = max(row["ms_per_face"] for row in rows)
    print(f"worst ms per face {worst:.3f} (target <= 0.5), flipped total {sum(r['flipped'] for r in rows)}")


if __name__ == "__main__":
    main()
