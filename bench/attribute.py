"""Where a UV map's whole-model loss comes from: q's GMSD^2 split over regions of the 20 evaluation views.

Usage (from /work, the repo's parent folder)::

    main/.venv/bin/python -m perceptual_uv.bench.attribute --model shared/models/tea_set_01/tea_set_01_1k.gltf \\
        --methods ours,SSPOP,input [--cost 0.3] [--screen 512] [--triangles CACHE_DIR] [--evaluations 100]

For each method, at one relative cost, every pooled cell of every view (GMSD compares 2 x 2 pooled renders) is
put in one region, from a render of triangle ids (``bridge.evaluate.face_id_views``) and the input's charts:

* ``background``: nothing drawn;
* ``silhouette``: drawn, with background within the 3 x 3 pooled cells its gradient reads;
* ``seam``: those cells show two charts of the input UV map (whose cuts every method keeps);
* ``floor`` / ``rest``: inside one chart, on a triangle whose triangle-wise target lies at the box floor
  (lambda1 and lambda2 within 5 % of ``lambda_min``) or not.

Printed per method: q (mean GMSD over the views) and the mean over views of GMSD^2 per region, with its share.
The triangle-wise result is read from (or written to) ``--triangles`` like ``bench.compare``; it decides the
``floor`` region for every method, so regions are the same faces in every row.
"""

import argparse
import pathlib

import numpy as np

REGIONS = ("background", "silhouette", "seam", "floor", "rest")
_READ = 6  # a pooled cell's gradient reads its 3 x 3 pooled neighbours: 6 x 6 screen pixels


def region_labels(face_ids, face_chart, at_floor):
    """(h/2, w/2) region index (into REGIONS) of each pooled cell of one view.

    Parameters
    ----------
    face_ids : (h, w) ndarray of int
        Triangle per pixel, -1 for background.
    face_chart : (m,) ndarray of int
        Chart of each triangle.
    at_floor : (m,) ndarray of bool
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    chart = np.where(face_ids >= 0, face_chart[np.maximum(face_ids, 0)], -1)
    # the window of pooled cell (i, j) is screen rows 2i - 2 .. 2i + 3: origin shifts the 6 x 6 filter there
    highest = maximum_filter(chart, size=_READ, origin=-1, mode="nearest")[::2, ::2]
    lowest = minimum_filter(chart, size=_READ, origin=-1, mode="nearest")[::2, ::2]
    face = face_ids[::2, ::2]
    labels = np.full(face.shape, REGIONS.index("rest"))
    labels[at_floor[np.maximum(face, 0)]] = REGIONS.index("floor")
    labels[highest != lowest] = REGIONS.index("seam")
    labels[lowest < 0] = REGIONS.index("silhouette")
    labels[face < 0] = REGIONS.index("background")
    return labels


def attribute_model(path, *, methods, cost, screen, evaluations, epsilon, triangles):
    import bpy

    from ..bridge.batch import textured_objects
    from ..bridge.evaluate import evaluate_uv_map, face_id_views, mesh_arrays, render_views
    from ..bridge.mesh_io import import_model
    from ..core.charts import uv_topology
    from ..core.evaluation import gmsd_by_region
    from .compare import UVMaps

    bpy.ops.wm.read_factory_settings(use_empty=True)
    import_model(path)
    objects = textured_objects()
    source = objects[0].data.uv_layers.active.name
    _, F, uv = mesh_arrays(objects, source)
    maps = UVMaps(objects, source, evaluations=evaluations, epsilon=epsilon, workers=0,
                   cache=None if triangles is None else (triangles, path.stem))
    result = maps.triangles(epsilon)
    at_floor = result.params[:, 1:3].max(axis=1) <= 1.05 * result.lambda_min
    chart = uv_topology(F, uv).face_chart
    labels = [region_labels(ids, chart, at_floor) for ids in face_id_views(objects, screen_pixels=screen)]
    reference = render_views(objects, uv_name=source, screen_pixels=screen)
    print(f"{path.stem}: c_r {cost}, {screen} px, {len(F)} faces, {at_floor.mean():.0%} at the box floor, "
          f"{chart.max() + 1} charts")
    print(f"| method | q | {' | '.join(REGIONS)} |")
    print("|---|---|" + "---|" * len(REGIONS))
    for method in methods:
        name = maps.make(method)
        point = evaluate_uv_map(objects, name, reference_uv=source, costs=(cost,), screen_pixels=screen,
                                reference_views=reference, keep_views=True)["points"][0]
        shares = np.mean([gmsd_by_region(a, b, lab, len(REGIONS))
                          for a, b, lab in zip(reference, point["rendered"], labels)], axis=0)
        cells = " | ".join(f"{v:.2e} ({v / shares.sum():.0%})" for v in shares)
        print(f"| {method} | {point['q']:.3e} | {cells} |", flush=True)
        maps.remove(name)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, type=pathlib.Path)
    parser.add_argument("--methods", default="ours,SSPOP,input")
    parser.add_argument("--cost", type=float, default=0.3)
    parser.add_argument("--screen", type=int, default=512)
    parser.add_argument("--evaluations", type=int, default=100)
    parser.add_argument("--epsilon", type=float, default=0.01)
    parser.add_argument("--triangles", type=pathlib.Path)
    args = parser.parse_args(argv)
    from .compare import METHODS

    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown methods {unknown}; choose from {', '.join(METHODS)}")
    attribute_model(args.model, methods=methods, cost=args.cost, screen=args.screen, evaluations=args.evaluations,
                    epsilon=args.epsilon, triangles=args.triangles)


if __name__ == "__main__":
    main()
