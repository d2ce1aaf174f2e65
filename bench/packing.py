"""Benchmark of the packing: ``core.packing.pack_charts`` against Blender's ``uv.pack_islands``, same charts.

Usage::

    .venv/bin/python bench/packing.py --models ../shared/models/spot ../shared/models/bob [--resolution 1024] \
        [--margin 4] [--json OUT.json]

Each model's input UV map is packed both ways, in one process, into a ``--resolution`` px square with a
``--margin`` px gap: ours fills the image (an explicit resolution), Blender's packer runs as the project used
it before (CONCAVE shapes, CARDINAL rotation, margin as a fraction of the image). Printed per model: charts,
seconds and coverage (the fraction of the image the triangles cover) of both, and the ratios ours / Blender's;
then ours again at the same pixel count in the shape of ``core.packing.IMAGE_ASPECTS`` that holds the charts
densest, as the pipeline packs: its size, seconds and coverage, and its texels per unit and time over the
square's.
"""
import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from pipeline import model_file  # noqa: E402  (bench/pipeline.py, next to this file)


def blender_pack(objects, uv_name, *, resolution, margin):
    """Blender's packer on temporary copies, as ``bridge.pack`` ran it; the packed UV per object's loops."""
    import bpy

    from perceptual_uv.bridge.pack import uv_operator_on_copies

    def pack():
        bpy.ops.uv.pack_islands(udim_source="CLOSEST_UDIM", rotate=True, rotate_method="CARDINAL", scale=True,
                                merge_overlap=False, margin_method="FRACTION", margin=margin / resolution,
                                pin=False, shape_method="CONCAVE")

    return uv_operator_on_copies(objects, uv_name, pack)


def measure(path, *, resolution, margin):
    import bpy

    from perceptual_uv.bridge.batch import textured_objects
    from perceptual_uv.bridge.mesh_io import import_model, read_mesh
    from perceptual_uv.core.charts import uv_topology
    from perceptual_uv.core.cost import uv_area
    from perceptual_uv.core.packing import IMAGE_ASPECTS, pack_charts

    bpy.ops.wm.read_factory_settings(use_empty=True)
    import_model(path)
    objects = textured_objects()
    source = objects[0].data.uv_layers.active.name
    arrays = [read_mesh(obj, uv_name=source) for obj in objects]
    offsets = np.cumsum([0] + [len(a.V) for a in arrays])
    F = np.concatenate([a.F + offset for a, offset in zip(arrays, offsets)])
    uv = np.concatenate([a.uv for a in arrays])
    face_chart = uv_topology(F, uv).face_chart
    started = time.perf_counter()
    ours = pack_charts(uv, face_chart, margin=margin, resolution=resolution)
    ours_seconds = time.perf_counter() - started
    started = time.perf_counter()
    shaped = pack_charts(uv, face_chart, margin=margin, resolution=resolution, aspects=IMAGE_ASPECTS)
    shaped_seconds = time.perf_counter() - started
    started = time.perf_counter()
    packed = blender_pack(objects, source, resolution=resolution, margin=margin)
    blender_seconds = time.perf_counter() - started
    theirs = np.concatenate([loops[a.tri_loops] for loops, a in zip(packed, arrays)])
    return {"model": path.parent.name, "faces": int(len(F)), "charts": int(face_chart.max() + 1),
            "ours_s": ours_seconds, "ours_coverage": ours.coverage,
            "blender_s": blender_seconds, "blender_coverage": uv_area(theirs),
            "shaped_size": list(shaped.size), "shaped_s": shaped_seconds, "shaped_coverage": shaped.coverage,
            "shaped_density_ratio": shaped.texels_per_unit / ours.texels_per_unit}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", required=True, help="model folders or files")
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--margin", type=int, default=4)
    parser.add_argument("--json", type=pathlib.Path)
    args = parser.parse_args(argv)
    from perceptual_uv.core.packing import pack_charts

    square = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], dtype=float)
    pack_charts(square, np.zeros(2, dtype=np.int64), margin=1, resolution=16)  # compile the kernels first
    rows = []
    for path in args.models:
        if not pathlib.Path(path).exists():
            print(f"skipping {path}: not found", file=sys.stderr)
            continue
        row = measure(model_file(path), resolution=args.resolution, margin=args.margin)
        rows.append(row)
        print(f"{row['model']:<24} {row['faces']:>6} faces {row['charts']:>4} charts | ours {row['ours_s']:6.2f} s "
              f"coverage {row['ours_coverage']:.3f} | Blender {row['blender_s']:6.2f} s coverage "
              f"{row['blender_coverage']:.3f} | time ratio {row['ours_s'] / row['blender_s']:.2f}, coverage ratio "
              f"{row['ours_coverage'] / row['blender_coverage']:.2f}", flush=True)
        print(f"{'':<24} shaped {row['shaped_size'][0]} x {row['shaped_size'][1]}: {row['shaped_s']:6.2f} s coverage "
              f"{row['shaped_coverage']:.3f} | texels per unit over the square's {row['shaped_density_ratio']:.3f}, "
              f"time ratio {row['shaped_s'] / row['ours_s']:.2f}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
