"""Benchmark of the triangle-wise loss E (core.loss): ms per evaluation and per preparation on a real model.

Usage::

    .venv/bin/python bench/loss.py [--model ../shared/models/spot] [--faces 200] [--evals 100] [--seed 0]
    .venv/bin/python bench/loss.py --solvers --model ../shared/models/Avocado --faces 24 --evals 10
    .venv/bin/python bench/loss.py --views --model ../shared/models/sofa_03 --sample 400 --faces 4

Prints ms per triangle preparation, ms per evaluation (fused numba kernel) at identity, at random
deformations from the box of Eq. 14 and at shrinks lambda <= 0.5 (where the optimizer spends its samples on
textured triangles), in batches and in calls of one row, and the plain numpy/scipy reference on a few
triangles with the ratio of the two. Timings on a shared machine are noisy: compare the ratios printed by
one run.

``--views`` measures how far the views' drawn faces reach in UV instead: per ``view_faces`` setting
(``window``, ``one_ring``), the share of textured faces whose drawn faces' texel box is more than 2 and 4 times
the view's side (faces across a seam, on other islands of the atlas) and of those whose box diagonal reaches
the texture's side minus 4 (a deformed footprint can then be wider than the texture), and, for the
``--faces`` faces with the widest boxes among the largest views, ms per evaluation at the identity, at (0, 1,
0.5, 0.5) and turned near-isometrically by 66 degrees.

``--solvers`` compares the re-bake's solvers instead (:data:`core.loss_stack.DISSECTION_COST`): views sized
as the triangle-wise stage sizes them (one pixel per texel, 64-256 px), every evaluation run once with the
band/envelope Cholesky only and once with the default choice (nested dissection for wide footprints), at the
identity, near it (lambda >= 0.7) and at shrinks lambda <= 0.5; prints ms per evaluation of each, their
ratio and the largest difference of E. Models other than OBJ are read through Blender's importers
(``bench/trianglewise.py``).
"""
import argparse
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))


def load_model(directory):
    from skimage.io import imread

    from perceptual_uv.core.mesh import read_obj

    directory = pathlib.Path(directory)
    obj = sorted(directory.glob("*.obj"))[0]
    V, F, uv = read_obj(obj)
    pngs = sorted(p for p in directory.glob("*.png") if "normal" not in p.name)
    texture = imread(pngs[0]).astype(np.float64) / 255.0
    return V, F, uv, np.ascontiguousarray(texture[::-1])


def load_any_model(directory):
    """``(V, F, uv, texture)``: OBJ and PNG as :func:`load_model`, other formats through Blender's importers."""
    directory = pathlib.Path(directory)
    if any(directory.glob("*.obj")):
        return load_model(directory)
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    from trianglewise import load_model as load_with_blender

    return load_with_blender(directory)[:4]


def _sampled_views(model, count, seed):
    """``(V, F, uv, texture, luma, faces, sizes, rng)``: ``count`` faces of ``model`` drawn at random (sorted) and
    their view sizes as the triangle-wise stage sets them (one pixel per texel, 64-256 px)."""
    from perceptual_uv.core import loss
    from perceptual_uv.core.camera import MAX_SCREEN_PIXELS, texel_matched_pixels

    V, F, uv, texture = load_any_model(model)
    luma = loss.texture_luma(texture)
    rng = np.random.default_rng(seed)
    faces = np.sort(rng.choice(len(F), size=min(count, len(F)), replace=False))
    sizes = texel_matched_pixels(V, F, uv, luma.shape, faces, minimum=64, maximum=MAX_SCREEN_PIXELS)
    return V, F, uv, texture, luma, faces, sizes, rng


def compare_solvers(args):
    """Time the fused kernel with the band/envelope solve only against the default solver choice."""
    from perceptual_uv.core import loss, loss_stack
    from perceptual_uv.core.gmsd import GMSD_C

    V, F, uv, texture, luma, faces, sizes, rng = _sampled_views(args.model, args.faces, args.seed)
    problems = []
    for size in np.unique(sizes):
        batch = loss.prepare_triangles(V, F, uv, luma, faces[sizes == size], screen_pixels=int(size))
        problems += [problem for problem in batch if not problem.is_constant]
    print(f"model {args.model}: {len(F)} faces, texture {texture.shape}, {len(problems)} textured of "
          f"{len(faces)} sampled, views {sizes.min()}-{sizes.max()} px (median {np.median(sizes):.0f})")
    near = np.column_stack([rng.uniform(0, np.pi / 2, args.evals), rng.uniform(0.7, 1.0, (args.evals, 2)),
                            rng.uniform(0, np.pi / 2, args.evals)])
    small = np.column_stack([rng.uniform(0, np.pi / 2, args.evals), rng.uniform(0.05, 0.5, (args.evals, 2)),
                             rng.uniform(0, np.pi / 2, args.evals)])
    solvers = (("band/envelope", np.inf), ("default", float(loss_stack.DISSECTION_COST)))

    def kernel_args(problem, params):
        return (params, problem.points, problem.pooled_index, problem.box, problem.reference[None],
                problem.reference_gradient[None], problem.centre, problem.ridge, GMSD_C, True)

    for _, cost in solvers:  # compile or load the cache
        loss_stack._evaluate_planes_kernel(*kernel_args(problems[0], small[:1]), cost,
                                            loss_stack.PEEL_MIN_CELLS)
    for name, params in (("identity", np.array([[0.0, 1.0, 1.0, 0.0]])), ("lambda >= 0.7", near),
                         ("lambda <= 0.5", small)):
        seconds = dict.fromkeys(dict(solvers), 0.0)
        worst_abs = worst_rel = 0.0
        for problem in problems:
            e = {}
            for label, cost in solvers:
                t0 = time.perf_counter()
                e[label] = loss_stack._evaluate_planes_kernel(*kernel_args(problem, params), cost,
                                                               loss_stack.PEEL_MIN_CELLS)
                seconds[label] += time.perf_counter() - t0
            difference = np.abs(e["default"] - e["band/envelope"])
            worst_abs = max(worst_abs, float(difference.max()))
            seen = e["band/envelope"] > 1e-6  # E near 0 (the identity): only the absolute difference means much
            if seen.any():
                worst_rel = max(worst_rel, float(np.max(difference[seen] / e["band/envelope"][seen])))
        per = {label: seconds[label] / (len(problems) * len(params)) * 1e3 for label in seconds}
        print(f"{name}: band/envelope {per['band/envelope']:.2f} ms per evaluation, default "
              f"{per['default']:.2f} ms, ratio {per['band/envelope'] / per['default']:.2f}x; E differs by at "
              f"most {worst_abs:.1e}, relative {worst_rel:.1e} where E > 1e-6")


def measure_views(args):
    """How far each view's drawn faces reach in UV, and what the widest cost per evaluation, per view setting."""
    from perceptual_uv.core import loss

    V, F, uv, texture, luma, faces, sizes, _ = _sampled_views(args.model, args.sample, args.seed)
    deformations = (("identity", [0.0, 1.0, 1.0, 0.0]), ("(0, 1, 0.5, 0.5)", [0.0, 1.0, 0.5, 0.5]),
                    ("(1.15, 0.9, 0.95, 1.53)", [1.146, 0.901, 0.948, 1.528]))
    print(f"model {args.model}: {len(F)} faces, texture {texture.shape}, {len(faces)} faces sampled")
    widest = None
    for view_faces in ("window", "one_ring"):
        problems, sides, views, wide = [], [], [], []
        for size in np.unique(sizes):
            for problem in loss.prepare_triangles(V, F, uv, luma, faces[sizes == size], screen_pixels=int(size),
                                                  view_faces=view_faces):
                if not problem.is_constant:
                    extent = problem.box[1::2] - problem.box[::2]  # (u, v) texels
                    problems.append(problem)
                    sides.append(extent.max())
                    views.append(size)
                    wide.append(np.hypot(*extent) >= min(problem.texture_shape) - 4)
        ratios = np.array(sides) / np.array(views)
        print(f"{view_faces}: {len(ratios)} textured faces; texel box over view side > 2: {np.mean(ratios > 2):.3f}, "
              f"> 4: {np.mean(ratios > 4):.3f}, median {np.median(ratios):.3f}; box diagonal >= texture side - 4: "
              f"{np.mean(wide):.3f}")
        if widest is None:  # the same faces for both settings: the widest boxes among the largest window views
            order = np.lexsort((np.array(sides), np.array(views)))[::-1]
            widest = [problems[i].face for i in order[:args.faces]]
        chosen = [problem for problem in problems if problem.face in widest]
        chosen[0].evaluate(np.array([[0.0, 0.5, 0.5, 0.0]]))  # compile or load the cache
        for name, params in deformations:
            times = []
            for problem in chosen:
                t0 = time.perf_counter()
                problem.evaluate(np.array([params]))
                times.append(time.perf_counter() - t0)
            print(f"  faces {sorted(widest)} at {name}: {np.mean(times) * 1e3:.1f} ms per evaluation "
                  f"(max {np.max(times) * 1e3:.1f})")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = pathlib.Path(__file__).resolve().parents[1]
    parser.add_argument("--model", default=str(here.parent / "shared" / "models" / "spot"))
    parser.add_argument("--faces", type=int, default=200)
    parser.add_argument("--evals", type=int, default=100)
    parser.add_argument("--reference-faces", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--solvers", action="store_true",
                        help="compare the re-bake's solvers at the triangle-wise stage's view sizes instead")
    parser.add_argument("--views", action="store_true",
                        help="measure how far the views' drawn faces reach in UV, and what the widest cost")
    parser.add_argument("--sample", type=int, default=400, help="faces sampled by --views")
    args = parser.parse_args(argv)
    if args.solvers:
        return compare_solvers(args)
    if args.views:
        return measure_views(args)

    from perceptual_uv.core import loss
    from perceptual_uv.core.one_ring import one_ring_faces

    V, F, uv, texture = load_model(args.model)
    rng = np.random.default_rng(args.seed)
    luma = loss.texture_luma(texture)
    t0 = time.perf_counter()
    adjacency = one_ring_faces(F, V=V)
    t_mesh = time.perf_counter() - t0
    faces = rng.choice(len(F), size=min(args.faces, len(F)), replace=False)
    loss.prepare_triangles(V, F, uv, luma, faces[:2], adjacency=adjacency)  # compile / load the cache
    t0 = time.perf_counter()
    batch = loss.prepare_triangles(V, F, uv, luma, faces, adjacency=adjacency)
    t_prep = time.perf_counter() - t0
    print(f"model {args.model}: {len(V)} vertices, {len(F)} faces, texture {texture.shape}")
    print(f"one-ring adjacency for the mesh: {t_mesh * 1e3:.1f} ms")
    print(f"preparation: {t_prep / len(faces) * 1e3:.3f} ms per triangle ({len(faces)} triangles), "
          f"constant: {batch.is_constant.mean():.2f}, median covered pixels: "
          f"{np.median(np.diff(batch.offsets)):.0f}")

    work = [i for i in range(len(batch)) if not batch.is_constant[i]]
    per_face_bytes = sum(a.nbytes for a in (batch.pixel, batch.points, batch.reference, batch.pooled_index,
                                            batch.reference_gradient)) / len(batch)
    print(f"cached arrays: {per_face_bytes / 1024:.0f} KB per triangle")
    box_lo = np.array([0.0, 0.05, 0.05, 0.0])
    box_hi = np.array([np.pi / 2, 1.0, 1.0, np.pi / 2])
    random_box = box_lo + (box_hi - box_lo) * rng.random((args.evals, 4))
    small = random_box.copy()
    small[:, 1:3] = 0.05 + 0.45 * rng.random((args.evals, 2))  # lambda in [0.05, 0.5]: where optima live
    identity = np.tile([0.0, 1.0, 1.0, 0.0], (args.evals, 1))
    batch[work[0]].evaluate(random_box[:2])  # compile or load the cache
    for name, p in (("identity", identity), ("random box", random_box), ("lambda <= 0.5", small)):
        per_triangle = []
        for i in work:
            t0 = time.perf_counter()
            batch[i].evaluate(p)
            per_triangle.append((time.perf_counter() - t0) / len(p))
        t_batched = sum(per_triangle) * len(p)
        q50, q90, q100 = np.quantile(per_triangle, [0.5, 0.9, 1.0]) * 1e3
        t0 = time.perf_counter()
        for i in work:
            problem = batch[i]
            for row in p:
                problem.evaluate(row)
        t_single = time.perf_counter() - t0
        print(f"evaluate ({name}): {t_batched / (len(work) * len(p)) * 1e3:.4f} ms per evaluation in batches of "
              f"{len(p)}, {t_single / (len(work) * len(p)) * 1e3:.4f} ms in calls of one "
              f"({len(work)} non-constant triangles); per triangle median {q50:.3f}, 90% {q90:.3f}, "
              f"max {q100:.3f} ms")

    nref = min(args.reference_faces, len(work))
    sub = random_box[:20]
    t0 = time.perf_counter()
    for i in work[:nref]:
        loss._evaluate_reference(batch[i], sub)
    t_ref = (time.perf_counter() - t0) / (nref * len(sub))
    t0 = time.perf_counter()
    for i in work[:nref]:
        batch[i].evaluate(sub)
    t_fast = (time.perf_counter() - t0) / (nref * len(sub))
    print(f"numpy/scipy reference: {t_ref * 1e3:.3f} ms per evaluation; fused kernel {t_fast * 1e3:.4f} ms "
          f"(same samples, same run): ratio {t_ref / t_fast:.1f}x")


if __name__ == "__main__":
    main()
