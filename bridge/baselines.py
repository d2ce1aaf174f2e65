"""Baseline UV maps for the comparisons of paper Sec. 5.2, each a new UV map on the same objects with the input cuts.

Every function adds one UV map (the input UV map, image, materials and mesh stay as they were; Blender's
unwrap runs on temporary copies of the objects) and packs it with 90-degree rotations only
(:func:`bridge.pack.pack_uv_layer`, DESIGN decision 7).

References
----------
Sun et al. 2022, Sec. 5.2 (baselines), Fig. 17 (weight ablations), Fig. 18 (epsilon); Sander et al. 2002 (SSP).
"""

import dataclasses
import hashlib
import os
import time

import bpy
import numpy as np

from ..core.chartfit import fit_charts
from ..core.loss import texture_luma
from ..core.meshwise import solve_meshwise
from ..core.overlap import restore_folded_charts
from ..core.ssp import solve_ssp, ssp_targets
from ..core.trianglewise import TrianglewiseResult, losses_at, optimize_triangles
from .mesh_io import read_image, read_mesh, write_uv_layer
from .pack import pack_uv_layer, uv_operator_on_copies
from .evaluate import mesh_arrays, reference_resolution
from .material import base_color_image_node

__all__ = ["BLENDER_METHODS", "repacked_input", "blender_unwrap", "ssp_uv", "sspop_uv", "perceptual_uv",
           "triangle_targets"]

BLENDER_METHODS = ("ANGLE_BASED", "CONFORMAL", "MINIMUM_STRETCH")

PACK_MARGIN_PIXELS = 4


def _check(objects, source_uv, name):
    objects = list(objects)
    if not objects:
        raise ValueError("no objects")
    for obj in objects:
        if obj.type != "MESH" or source_uv not in obj.data.uv_layers:
            raise ValueError(f"'{obj.name}' has no UV map '{source_uv}'")
        if name in obj.data.uv_layers:
            raise ValueError(f"'{obj.name}' already has a UV map '{name}'")
    return objects


def _pack(objects, name):
    pack_uv_layer(objects, name, margin_fraction=PACK_MARGIN_PIXELS / reference_resolution(objects))


def _write(objects, name, uv_all):
    """Write concatenated per-corner UVs (in :func:`read_mesh` order over ``objects``) as new UV maps."""
    start = 0
    for obj in objects:
        arrays = read_mesh(obj)
        m = len(arrays.F)
        write_uv_layer(obj, name, uv_all[start:start + m], arrays.tri_loops)
        start += m


def _texture(objects):
    for obj in objects:
        for slot in obj.material_slots:
            node = base_color_image_node(slot.material)
            if node is not None and node.image is not None:
                return read_image(node.image)
    raise ValueError("no base-colour image")


def repacked_input(objects, *, source_uv, name="InputRepacked"):
    """The input UV map copied to ``name`` and re-packed with 90-degree rotations. Returns timings (s)."""
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    _, _, uv = mesh_arrays(objects, source_uv)
    _write(objects, name, uv)
    _pack(objects, name)
    return {"total": time.perf_counter() - start}


def blender_unwrap(objects, *, source_uv, method, name=None):
    """Blender's unwrap (``method`` in :data:`BLENDER_METHODS`) with seams from the input islands, packed.

    The unwrap runs on temporary copies (seams marked there); the result is copied to a new UV map ``name``
    (default the method's name) on the original objects. Returns timings (s).
    """
    if method not in BLENDER_METHODS:
        raise ValueError(f"method must be one of {BLENDER_METHODS}, got {method!r}")
    name = name or method
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()

    def unwrap():
        bpy.ops.uv.seams_from_islands(mark_seams=True)
        bpy.ops.uv.unwrap(method=method, margin=0.0)

    uvs = uv_operator_on_copies(objects, source_uv, unwrap)
    for obj, values in zip(objects, uvs):
        layer = obj.data.uv_layers.new(name=name)
        layer.data.foreach_set("uv", values.ravel())
    _pack(objects, name)
    return {"total": time.perf_counter() - start}


def ssp_uv(objects, *, source_uv, name="SSP", **options):
    """SSP (Sander et al. 2002) from the input UV map and texture, packed. Returns timings (s)."""
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    V, F, uv = mesh_arrays(objects, source_uv)
    result = solve_ssp(V, F, uv, _texture(objects), **options)
    _write(objects, name, result.uv)
    _pack(objects, name)
    return {"total": time.perf_counter() - start}


def sspop_uv(objects, *, source_uv, name="SSPOP"):
    """SSP's expected stretch as targets of our mesh-wise solver with w_R = 0 (paper Sec. 5.2.2), packed."""
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    V, F, uv = mesh_arrays(objects, source_uv)
    params, w_R, w_S = ssp_targets(V, F, uv, _texture(objects))
    result = solve_meshwise(F, uv, params, w_R, w_S)
    _write(objects, name, result.uv)
    _pack(objects, name)
    return {"total": time.perf_counter() - start}


def triangle_targets(objects, *, source_uv, epsilon, evaluations, screen_pixels=64, workers=1, seed=0, cache=None):
    """The triangle-wise stage (Sec. 4.1) on the objects: its result and its time (s), reusable across ablations.

    ``cache`` (an ``.npz`` path) keeps the result between runs, so that a change to the later stages is measured
    without the triangle-wise stage again: it is read when it was written for the same vertices, faces, UVs,
    texture and settings (the time returned is then that of the run that wrote it), and written otherwise.
    The code is not part of the key: a change to the triangle-wise stage needs a new cache.
    """
    V, F, uv = mesh_arrays(objects, source_uv)
    luma = texture_luma(_texture(objects))
    settings = dict(epsilon=epsilon, evaluations=evaluations, screen_pixels=screen_pixels, seed=seed)
    key = _triangle_cache_key(V, F, uv, luma, **settings)
    if cache is not None and os.path.exists(cache):
        with np.load(cache) as stored:
            if str(stored["key"]) == key:
                fields = {f.name: stored[f.name] for f in dataclasses.fields(TrianglewiseResult)}
                for name in ("epsilon", "lambda_min"):
                    fields[name] = float(fields[name])
                for name in ("formulation", "backend"):
                    fields[name] = str(fields[name])
                return TrianglewiseResult(**fields), float(stored["seconds"])
    start = time.perf_counter()
    result = optimize_triangles(V, F, uv, luma, workers=workers, **settings)
    seconds = time.perf_counter() - start
    if cache is not None:
        np.savez(cache, key=key, seconds=seconds, **dataclasses.asdict(result))
    return result, seconds


def _triangle_cache_key(V, F, uv, luma, **settings):
    """What a cached triangle-wise result must match: a hash of the arrays and the settings."""
    digest = hashlib.sha256(repr(sorted(settings.items())).encode())
    for array in (V, F, uv, luma):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def perceptual_uv(objects, *, source_uv, triangles, name, weights="perceptual", formulation="perceptual",
                  rotation_scale=None, workers=1):
    """Our mesh-wise stage on triangle-wise results ``triangles``, or one of the Fig. 17 ablations, packed.

    By default as in the pipeline (:func:`core.chartfit.fit_charts`): fits with and without Eq. 16's rotation
    terms, every chart turned to its best angle and keeping the fit whose triangles' loss E is lower. An
    ablation (``weights``, ``formulation`` or ``rotation_scale`` given) is one fit of Eq. 19 whose folded charts
    keep their input layout (:func:`core.overlap.restore_folded_charts`).

    Parameters
    ----------
    triangles : core.trianglewise.TrianglewiseResult
        Of every face; its ``fit_targets()`` and ``fit_weights()`` drive the fit, as in the pipeline.
    weights : {"perceptual", "identity"}
    formulation : {"perceptual", "common"}
    rotation_scale : float, optional
        Of :meth:`~core.trianglewise.TrianglewiseResult.fit_weights` for one fit; 1 fits Eq. 16's rotation
        targets, 0 leaves them out.
    workers : int, optional
        Processes measuring E for the default (``core.trianglewise.losses_at``; 0: one per core).
    """
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    V, F, uv = mesh_arrays(objects, source_uv)
    texture = _texture(objects)
    luma = texture_luma(texture)
    signal, _, _ = ssp_targets(V, F, uv, texture)
    params = triangles.fit_targets(uv, luma, signal_targets=signal)
    if (weights, formulation, rotation_scale) == ("perceptual", "perceptual", None):
        uv_fit = fit_charts(F, uv, params, *triangles.fit_weights(),
                            measure=lambda new_uv: losses_at(V, F, uv, luma, new_uv, workers=workers),
                            texel_scale=texture.shape[1::-1]).uv
    else:
        w_R, w_S = triangles.fit_weights(rotation_scale=0.0 if rotation_scale is None else rotation_scale)
        result = solve_meshwise(F, uv, params, w_R, w_S, weights=weights, formulation=formulation)
        uv_fit, _ = restore_folded_charts(uv, result.uv, result.topology.face_chart)
    t_mesh = time.perf_counter() - start
    _write(objects, name, uv_fit)
    _pack(objects, name)
    return {"mesh": t_mesh, "total": time.perf_counter() - start}
