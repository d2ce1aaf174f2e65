"""Benchmark of the joint loss over a material's maps (core.loss_planes): cost per plane, and the normal map's lights.

Usage::

    .venv/bin/python bench/joint_loss.py [--model ../shared/models/WaterBottle] [--faces 60] [--evals 40]

Part 1 prints the ms per evaluation of a stack of k = 1..4 planes and its ratio to one plane, measured in
this run on the same triangles and deformations (random in the box of Eq. 14), for planes of one resolution
(which share the operator's assembly and factorization, :mod:`core.loss_stack`) and for a stack whose extra
planes are at half resolution (one operator per resolution), and on triangles where the extra planes are
constant (which cost nothing). Part 2 compares the tangent-space normal map's loss under the default three
lights (:data:`core.loss_planes.NORMAL_LIGHTS`) with other rings of lights and with a dense set of 48 (16
azimuths x elevations 30, 45, 60 degrees): how much of the dense set's E the few lights see, and how often they
decide ``E <= epsilon`` differently. Timings on a shared machine are noisy: compare the ratios of one run.
"""
import argparse
import json
import math
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))

_COMPONENT = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def load_gltf(path):
    """V, F, per-corner UV (v up, as Blender) and the first material's maps by glTF slot (row 0 = bottom)."""
    from skimage.io import imread

    path = pathlib.Path(path)
    doc = json.loads(path.read_text())
    buffers = [(path.parent / b["uri"]).read_bytes() for b in doc["buffers"]]

    def accessor(index):
        acc = doc["accessors"][index]
        view = doc["bufferViews"][acc["bufferView"]]
        dtype = np.dtype(_COMPONENT[acc["componentType"]])
        item = dtype.itemsize * _WIDTH[acc["type"]]
        stride = view.get("byteStride", item)
        offset = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        raw = np.frombuffer(buffers[view["buffer"]], dtype=np.uint8, count=stride * (acc["count"] - 1) + item,
                            offset=offset)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(acc["count"], item), strides=(stride, 1)).copy()
        return rows.view(dtype).reshape(acc["count"], _WIDTH[acc["type"]])

    primitive = doc["meshes"][0]["primitives"][0]
    V = accessor(primitive["attributes"]["POSITION"]).astype(np.float64)
    F = accessor(primitive["indices"]).reshape(-1, 3).astype(np.int64)
    texcoord = accessor(primitive["attributes"]["TEXCOORD_0"]).astype(np.float64)
    texcoord[:, 1] = 1.0 - texcoord[:, 1]
    material = doc["materials"][primitive.get("material", 0)]
    slots = {"baseColor": material.get("pbrMetallicRoughness", {}).get("baseColorTexture"),
             "metallicRoughness": material.get("pbrMetallicRoughness", {}).get("metallicRoughnessTexture"),
             "normal": material.get("normalTexture"), "emissive": material.get("emissiveTexture")}
    maps = {}
    for slot, ref in slots.items():
        if ref is not None:
            uri = doc["images"][doc["textures"][ref["index"]]["source"]]["uri"]
            image = imread(path.parent / uri).astype(np.float64) / 255.0
            maps[slot] = np.ascontiguousarray(image[::-1])
    return V, F, texcoord[F], maps


def _time_per_eval(problems, params, repeats=1):
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for problem in problems:
            problem.evaluate(params)
        best = min(best, time.perf_counter() - t0)
    return best / (len(problems) * len(params)) * 1e3


def part_cost(V, F, uv, planes, names, faces, params, adjacency, label, screen_pixels):
    from perceptual_uv.core import loss

    batches = [loss.prepare_triangles(V, F, uv, list(planes[:k]) if k > 1 else planes[0], faces,
                                      adjacency=adjacency, screen_pixels=screen_pixels) for k in range(1, 5)]
    for b in batches:
        b[0].evaluate(params[:2])  # compile / load the cache
    active = [np.array([len(b[i].active_planes) if k else int(not b[i].is_constant) for i in range(len(b))])
              for k, b in enumerate(batches)]
    base = None
    sizes = [f"{n} {p.shape[1]}x{p.shape[0]}" for n, p in zip(names, planes)]
    print(f"{label}, {screen_pixels} px views: planes {sizes}")
    for k, b in enumerate(batches, start=1):
        ms = _time_per_eval(list(b), params, repeats=2)
        base = base or ms
        print(f"  k = {k}: {ms:.3f} ms per evaluation, ratio to one plane {ms / base:.2f} "
              f"(mean active planes {active[k - 1].mean():.2f})")


def part_lights(V, F, uv, normal_map, faces, params, adjacency, epsilon):
    from perceptual_uv.core import loss
    from perceptual_uv.core.loss_planes import NORMAL_LIGHTS, _lights, normal_shading

    dense = np.vstack([_lights(math.radians(e), [2 * math.pi * i / 16 for i in range(16)]) for e in (30, 45, 60)])

    def ring(count, elevation):
        return _lights(math.radians(elevation), [2 * math.pi * i / count for i in range(count)])

    sets = {"3 lights at 30 deg (default)": NORMAL_LIGHTS, "6 lights at 30 deg": ring(6, 30),
            "3 lights at 45 deg": ring(3, 45), "4 lights at 45 deg": ring(4, 45), "3 lights at 60 deg": ring(3, 60),
            "48 lights": dense}
    losses = {}
    for name, lights in sets.items():
        planes = list(normal_shading(normal_map, lights=lights))
        batch = loss.prepare_triangles(V, F, uv, planes, faces, adjacency=adjacency)
        losses[name] = np.array([batch[i].evaluate(params) for i in range(len(batch))])
    reference = losses["48 lights"]
    textured = reference.max(axis=1) > 1e-6
    print(f"normal map lights on {int(textured.sum())} triangles with normal detail, {len(params)} deformations each:")
    for name in list(sets)[:-1]:
        ratio = losses[name][textured] / np.maximum(reference[textured], 1e-300)
        differ = (losses[name][textured] <= epsilon) != (reference[textured] <= epsilon)
        print(f"  {name}: E / E(48 lights) median {np.median(ratio):.3f}, 5th percentile "
              f"{np.percentile(ratio, 5):.3f}; decides E <= {epsilon} differently in {differ.mean():.3%}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = pathlib.Path(__file__).resolve().parents[1]
    parser.add_argument("--model", default=str(here.parent / "shared" / "models" / "WaterBottle"))
    parser.add_argument("--faces", type=int, default=60)
    parser.add_argument("--evals", type=int, default=40)
    parser.add_argument("--epsilon", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--screen-pixels", type=int, nargs="+", default=[64, 256],
                        help="view sides for the cost part (App. A's 64 and the largest texel-matched view)")
    parser.add_argument("--skip-lights", action="store_true")
    args = parser.parse_args(argv)

    from perceptual_uv.core.loss_planes import loss_planes
    from perceptual_uv.core.one_ring import one_ring_faces

    V, F, uv, maps = load_gltf(sorted(pathlib.Path(args.model).glob("*.gltf"))[0])
    print(f"model {args.model}: {len(F)} faces, maps {[f'{k} {v.shape}' for k, v in maps.items()]}")
    rng = np.random.default_rng(args.seed)
    adjacency = one_ring_faces(F, V=V)
    faces = rng.choice(len(F), size=min(args.faces, len(F)), replace=False)
    params = np.array([0.0, 0.1, 0.1, 0.0]) + np.array([math.pi / 2, 0.9, 0.9, math.pi / 2]) * rng.random(
        (args.evals, 4))
    stack = loss_planes([("color", maps["baseColor"]), ("normal", maps["normal"]),
                         ("data", maps["metallicRoughness"], (1, 2))])
    print(f"loss_planes: {list(stack.names)}")
    chosen = [0, 1, 2, 4] if len(stack) >= 5 else list(range(min(4, len(stack))))
    planes = [stack[i] for i in chosen]
    names = [stack.names[i] for i in chosen]
    # Triangles where the first plane varies, so that one plane has work to do.
    from perceptual_uv.core import loss

    probe = loss.prepare_triangles(V, F, uv, planes[0], faces, adjacency=adjacency)
    busy = faces[~probe.is_constant]
    half = [planes[0]] + [np.ascontiguousarray(0.25 * (p[0::2, 0::2] + p[1::2, 0::2] + p[0::2, 1::2] + p[1::2, 1::2]))
                          for p in planes[1:]]
    flat = [planes[0]] + [np.full_like(p, 0.5) for p in planes[1:]]
    for n in args.screen_pixels:
        part_cost(V, F, uv, planes, names, busy, params, adjacency, "one resolution", n)
        part_cost(V, F, uv, half, names, busy, params, adjacency, "extra planes at half resolution", n)
        part_cost(V, F, uv, flat, names, busy, params, adjacency, "extra planes constant", n)
    if "normal" in maps and not args.skip_lights:
        part_lights(V, F, uv, maps["normal"], faces[: max(10, args.faces // 2)], params[: max(8, args.evals // 2)],
                    adjacency, args.epsilon)


if __name__ == "__main__":
    main()
