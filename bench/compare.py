"""Compare UV maps by the paper's Sec. 5.1 evaluation: q_r-c_r plots, q_r / E_iso tables, a Table-1 style table,
and render crops at c_r = 0.3 (input vs ours).

Usage (from /work)::

    main/.venv/bin/python -m perceptual_uv.bench.compare --models DIR_OR_FILE... --costs 0.1,0.2,0.3,0.5 \\
        --out main/docs/results --evaluations 30 [--methods input,repacked,...] [--screen 512]

Every q is reported with its screen size (20 dodecahedron views).
"""

import argparse
import json
import pathlib
import sys
import time

import numpy as np

METHODS = ("input", "repacked", "ANGLE_BASED", "CONFORMAL", "MINIMUM_STRETCH", "SSP", "SSPOP", "ours",
           "ours_common", "ours_identity")
MODEL_SUFFIXES = (".glb", ".gltf", ".obj", ".blend")


def _models(paths):
    out = []
    for p in map(pathlib.Path, paths):
        if p.is_dir():
            out += sorted(f for f in p.rglob("*") if f.suffix.lower() in MODEL_SUFFIXES)
        elif p.suffix.lower() in MODEL_SUFFIXES:
            out.append(p)
    return out


def compare_model(path, *, costs, methods, evaluations, screen, epsilon, out):
    import bpy

    from ..bridge import baselines
    from ..bridge.evaluate import evaluate_uv_map, render_views
    from ..bridge.mesh_io import import_model

    import_model(path)
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH" and o.data.uv_layers]
    source = objects[0].data.uv_layers.active.name
    faces = sum(len(o.data.polygons) for o in objects)
    verts = sum(len(o.data.vertices) for o in objects)
    times, names = {}, {}
    triangles = None
    for method in methods:
        start = time.perf_counter()
        if method == "input":
            names[method] = source
        elif method == "repacked":
            baselines.repacked_input(objects, source_uv=source, name="Repacked")
            names[method] = "Repacked"
        elif method in baselines.BLENDER_METHODS:
            baselines.blender_unwrap(objects, source_uv=source, method=method)
            names[method] = method
        elif method == "SSP":
            baselines.ssp_uv(objects, source_uv=source)
            names[method] = "SSP"
        elif method == "SSPOP":
            baselines.sspop_uv(objects, source_uv=source)
            names[method] = "SSPOP"
        elif method.startswith("ours"):
            if triangles is None:
                triangles, times["triangle"] = baselines.triangle_targets(
                    objects, source_uv=source, epsilon=epsilon, evaluations=evaluations)
            kw = {"ours": {}, "ours_common": {"formulation": "common"},
                  "ours_identity": {"weights": "identity"}}[method]
            t = baselines.perceptual_uv(objects, source_uv=source, triangles=triangles, name=method, **kw)
            if method == "ours":
                times["mesh"] = t["mesh"]
            names[method] = method
        times[method] = time.perf_counter() - start
    reference = render_views(objects, uv_name=source, screen_pixels=screen)
    results = {}
    for method, uv_name in names.items():
        results[method] = evaluate_uv_map(objects, uv_name, reference_uv=source, costs=costs, screen_pixels=screen,
                                          reference_views=reference)
        print(f"{path.stem} {method}: " + ", ".join(f"c {p['relative_cost']:.3f} q {p['q']:.4g}"
                                                     for p in results[method]["points"]), flush=True)
    stem = path.stem
    _plot(results, out / f"{stem}_q_vs_c.png", stem, screen)
    _crops(objects, names, source, reference, out / f"{stem}_crops_c030.png", screen)
    r_in = results[methods[0]]["reference_resolution"]
    lines = [f"## {stem}", "",
             f"#V {verts} / #F {faces}, input r {r_in}, epsilon {epsilon}, {evaluations} evaluations per triangle, "
             f"t_triangle {times.get('triangle', float('nan')):.1f} s / t_mesh {times.get('mesh', float('nan')):.1f} s, "
             f"q at {screen} px (20 views)", "",
             "| method | " + " | ".join(f"q @ c_r={c}" for c in costs) + " | E_iso |",
             "|---" * (len(costs) + 2) + "|"]
    for method, res in results.items():
        lines.append(f"| {method} | " + " | ".join(f"{p['q']:.4g} (r {p['resolution']})" for p in res["points"])
                     + f" | {res['e_iso']:.4g} |")
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    (out / f"{stem}.json").write_text(json.dumps({"times_s": times, "results": results}, indent=1))
    return "\n".join(lines)


def _plot(results, file, title, screen):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5), dpi=90)
    for method, res in results.items():
        ax.plot([p["relative_cost"] for p in res["points"]], [p["q"] for p in res["points"]], "o-", label=method,
                lw=2 if method == "ours" else 1)
    ax.set_yscale("log")
    ax.set_xlabel("relative cost $c_r$")
    ax.set_ylabel(f"$q_r$ (mean GMSD, 20 views, {screen} px)")
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(file)
    plt.close(fig)


def _crops(objects, names, source, reference, file, screen):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import bpy

    from ..bridge.evaluate import evaluate_uv_map, render_views

    panels = [("reference", reference[0])]
    for method in ("input", "ours"):
        if method not in names:
            continue
        res = evaluate_uv_map(objects, names[method], reference_uv=source, costs=(0.3,), screen_pixels=screen,
                              reference_views=reference, keep_images=True)
        image = res["images"][0]
        view = render_views(objects, uv_name=names[method], image=image, screen_pixels=screen)[0]
        bpy.data.images.remove(image)
        panels.append((f"{method} c_r=0.3", view))
    h = screen // 4
    fig, axes = plt.subplots(1, len(panels), figsize=(3 * len(panels), 3), dpi=80)
    for ax, (label, view) in zip(np.atleast_1d(axes), panels):
        ax.imshow(view[::-1][screen // 2 - h:screen // 2 + h, screen // 2 - h:screen // 2 + h, :3],
                  interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(file)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", required=True)
    parser.add_argument("--costs", default="0.1,0.2,0.3,0.5")
    parser.add_argument("--out", type=pathlib.Path, required=True)
    parser.add_argument("--evaluations", type=int, default=30)
    parser.add_argument("--epsilon", type=float, default=0.01)
    parser.add_argument("--screen", type=int, default=512)
    parser.add_argument("--methods", default=",".join(METHODS))
    args = parser.parse_args(argv)
    costs = [float(c) for c in args.costs.split(",")]
    methods = [m for m in args.methods.split(",") if m]
    unknown = set(methods) - set(METHODS)
    if unknown:
        parser.error(f"unknown methods {sorted(unknown)}; choose from {METHODS}")
    args.out.mkdir(parents=True, exist_ok=True)
    for path in _models(args.models):
        print(compare_model(path, costs=costs, methods=methods, evaluations=args.evaluations, screen=args.screen,
                            epsilon=args.epsilon, out=args.out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
