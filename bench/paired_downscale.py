"""The uniform downscale measured at the image memory of every shaded point of the other methods (issue 23).

``bench.compare --shaded`` compares methods at equal image memory by interpolating each method's log q between
its own measured points. The shaded q of one layout does not fall steadily with its image side: the downscale's
moves by up to 20 % between sides one pixel apart (docs/research/2026-11-30-avocado-paired-downscale.md), so the
downscale interpolated to a memory is one side's luck. The downscale exists at every memory: this measures it at
exactly the memory each point of the other methods took, so that each comparison is between two measured renders
of the same image memory, and summarizes the ratios.

Usage (from /work, the repository's parent folder)::

    main/.venv/bin/python -m perceptual_uv.bench.paired_downscale shared/models/Avocado \\
        --results main/docs/results/shaded/Avocado_shaded.json --out OUT_DIR [--methods ours,MINIMUM_STRETCH]

Writes ``OUT_DIR/<model>_paired.json`` after every measurement (a run that stops resumes from it) and
``OUT_DIR/<model>_paired.md``.
"""
import argparse
import json
import pathlib
import sys

import numpy as np

__all__ = ["points_to_pair", "paired_table", "paired_markdown", "main"]


def points_to_pair(results, methods):
    """``(method, target_cost, memory)`` of every shaded point of ``methods`` in a compare ``results`` dict
    (``results[method]["points"]``, each with ``target_cost`` and ``memory_ratio``), in that order."""
    pairs = []
    for method in methods:
        if method not in results:
            raise ValueError(f"the results hold no method {method!r} (they hold {', '.join(results)})")
        for point in sorted(results[method]["points"], key=lambda point: point["target_cost"]):
            if point.get("memory_ratio"):
                pairs.append((method, float(point["target_cost"]), float(point["memory_ratio"])))
    return pairs


def paired_table(results, downscale, methods):
    """Per method, its points with the downscale measured at their memory.

    Parameters
    ----------
    results : dict
        Compare results (``results[method]["points"]``).
    downscale : dict
        ``"<memory>"`` (``repr`` of the float) -> the downscale's measured point (``q``, ``memory_ratio``).
    methods : sequence of str

    Returns
    -------
    dict
        Per method a list of rows ``target_cost``, ``memory``, ``q``, ``downscale_memory``, ``downscale_q``,
        ``ratio`` (q over the downscale's), for the points whose downscale was measured; and under
        ``"geometric_mean"`` per method the geometric mean of its ratios (None without rows).
    """
    table, means = {}, {}
    for method in methods:
        rows = []
        for point in sorted(results[method]["points"], key=lambda point: point["target_cost"]):
            memory = float(point["memory_ratio"]) if point.get("memory_ratio") else None
            measured = downscale.get(repr(memory)) if memory is not None else None
            if measured is None:
                continue
            rows.append(dict(target_cost=float(point["target_cost"]), memory=memory, q=float(point["q"]),
                             downscale_memory=float(measured["memory_ratio"]), downscale_q=float(measured["q"]),
                             ratio=float(point["q"]) / float(measured["q"])))
        table[method] = rows
        means[method] = float(np.exp(np.mean(np.log([row["ratio"] for row in rows])))) if rows else None
    table["geometric_mean"] = means
    return table


def paired_markdown(model, table, methods):
    lines = [f"## {model}: each point against the uniform downscale at its own image memory", "",
             "| method | texel cost | memory | q | downscale q (its memory) | q / downscale's |",
             "|---|---|---|---|---|---|"]
    for method in methods:
        for row in table[method]:
            lines.append(f"| {method} | {row['target_cost']:g} | {row['memory']:.3f} | {row['q']:.4g} | "
                         f"{row['downscale_q']:.4g} ({row['downscale_memory']:.3f}) | {row['ratio']:.3f} |")
    lines += [""] + [f"- {method}: geometric mean of q / downscale's q {mean:.3f} over {len(table[method])} points"
                     for method, mean in table["geometric_mean"].items() if mean is not None]
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="the model's folder or file")
    parser.add_argument("--results", required=True, help="the model's <model>_shaded.json from bench.compare --shaded")
    parser.add_argument("--out", required=True)
    parser.add_argument("--methods", default="ours,MINIMUM_STRETCH")
    args = parser.parse_args(argv)
    from .compare import _models

    models = _models([args.model])
    if len(models) != 1:
        print(f"paired_downscale: {args.model} holds {len(models)} model files, not one", file=sys.stderr)
        return 2
    try:
        data = json.loads(pathlib.Path(args.results).read_text())
    except (OSError, ValueError) as error:
        print(f"paired_downscale: cannot read {args.results}: {error}", file=sys.stderr)
        return 2
    if not isinstance(data, dict) or not data.get("table", {}).get("shaded") or "results" not in data:
        print(f"paired_downscale: {args.results} is not a shaded comparison", file=sys.stderr)
        return 2
    methods = [method for method in args.methods.split(",") if method]
    try:
        pairs = points_to_pair(data["results"], methods)
    except ValueError as error:
        print(f"paired_downscale: {error}", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = models[0].stem
    file = out / f"{stem}_paired.json"
    measured = json.loads(file.read_text())["downscale"] if file.is_file() else {}

    def write():
        table = paired_table(data["results"], measured, methods)
        file.write_text(json.dumps(dict(model=stem, results=str(args.results), downscale=measured, table=table),
                                   indent=1))
        (out / f"{stem}_paired.md").write_text(paired_markdown(stem, table, methods))

    to_measure = sorted({memory for _, _, memory in pairs if repr(memory) not in measured})
    if to_measure:
        import bpy

        from ..bridge.batch import textured_objects
        from ..bridge.evaluate_shaded import evaluate_shaded, shaded_reference
        from ..bridge.mesh_io import import_model

        bpy.ops.wm.read_factory_settings(use_empty=True)
        import_model(models[0])
        objects = textured_objects()
        source = objects[0].data.uv_layers.active.name
        screen = int(data["table"]["screen_pixels"])
        reference = shaded_reference(objects, source, screen_pixels=screen)
        for number, memory in enumerate(to_measure, 1):
            result = evaluate_shaded(objects, source, reference_uv=source, costs=[memory], screen_pixels=screen,
                                     reference=reference, sizing="memory")
            point = result["points"][0]
            measured[repr(memory)] = dict(q=point["q"], memory_ratio=point["memory_ratio"],
                                          resolution=point["resolution"], maps=point["maps"], time_s=point["time_s"])
            write()
            print(f"[{number}/{len(to_measure)}] {stem}: downscale at memory {memory:.4f}: q {point['q']:.4g}",
                  file=sys.stderr, flush=True)
    write()
    print(paired_markdown(stem, paired_table(data["results"], measured, methods), methods))
    return 0


if __name__ == "__main__":
    sys.exit(main())
