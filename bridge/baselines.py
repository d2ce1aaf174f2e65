"""Baseline UV maps for the comparisons of paper Sec. 5.2, each a new UV map on the same objects with the input cuts.

Every function adds one UV map (the input UV map, image, materials and mesh stay as they were; Blender's unwrap runs
on temporary copies of the objects) and packs it with 90-degree rotations only (:func:`bridge.pack.pack_uv_layer`,
DESIGN decision 7). Before packing, every method's charts get the same post-processing
(:func:`core.chartfit.finish_charts`: folded charts keep their input layout, charts that share texels in the input
stay stacked (:mod:`core.stacks`) and pack as one island, every chart is turned rigidly to its rotation targets), so
that a comparison measures the methods and not whether they were given the fallbacks. The triangle-wise and
mesh-wise stages of ours see what a run of the product sees: every map of the material (:func:`loss_planes`,
:mod:`.material_copy`), not the base colour alone.

References
----------
Sun et al. 2022, Sec. 5.2 (baselines), Fig. 17 (weight ablations), Fig. 18 (epsilon); Sander et al. 2002 (SSP).
"""

import dataclasses
import hashlib
import os
import pathlib
import time
import zipfile

import bpy
import numpy as np

from ..core.chartfit import finish_charts, fit_charts
from ..core.charts import uv_topology
from ..core.loss_passes import iter_fit_losses
from ..core.loss_planes import PlaneStack
from ..core.meshwise import solve_meshwise
from ..core.overlap import FOLD_TOLERANCE
from ..core.progress import run_generator
from ..core.result_cache import dataclass_from, save_arrays
from ..core.ssp import solve_ssp, ssp_targets
from ..core.stacks import stacked_charts, stacked_faces
from ..core.textured import above_bound
from ..core.trianglewise import optimize_triangles
from ..core.trianglewise_result import MIN_TEXELS, SIGNAL_WEIGHT, STRETCH_WEIGHT_FLOOR, TrianglewiseResult
from .mesh_io import read_image, read_mesh, write_uv_layer
from .pack import pack_uv_layer, uv_operator_on_copies
from .evaluate import _side, mesh_arrays, reference_resolution
from .read_objects import source_image
from .material_copy import loss_planes_of, read_maps

__all__ = ["BLENDER_METHODS", "LOSS_MAPS", "repacked_input", "blender_unwrap", "ssp_uv", "sspop_uv",
           "loss_planes", "perceptual_uv", "triangle_targets"]

BLENDER_METHODS = ("ANGLE_BASED", "CONFORMAL", "MINIMUM_STRETCH")

LOSS_MAPS = ("material", "luma")
"""What the loss of ours sees (:func:`loss_planes`): every map of the material, as the product, or the base
colour's luma alone (the single-texture loss of the paper)."""

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


def _pack(objects, name, face_stack=None):
    """Pack UV map ``name`` as the product packs: into the shape of ``IMAGE_ASPECTS`` that holds its islands
    densest at the input's pixel count; returns ``{"aspect": width / height}`` for the method's report (its
    evaluation bakes images of that shape)."""
    from ..core.packing import IMAGE_ASPECTS

    packing = pack_uv_layer(objects, name, margin=PACK_MARGIN_PIXELS, resolution=_side(*reference_resolution(objects)),
                            face_stack=face_stack, aspects=IMAGE_ASPECTS)
    return {"aspect": packing.width / packing.height}


def _stacks(F, uv_in, keep_stacks=True):
    """The input's charts (``uv_topology``) and their stacks (:func:`core.stacks.stacked_charts`; None when not
    kept)."""
    topology = uv_topology(F, uv_in)
    return topology, (stacked_charts(uv_in, topology.face_chart) if keep_stacks else None)


def _face_stack(face_chart, stacks):
    return None if stacks is None else stacked_faces(face_chart, stacks)


def _write(objects, name, uv_all):
    """Write concatenated per-corner UVs (in :func:`read_mesh` order over ``objects``) as new UV maps."""
    start = 0
    for obj in objects:
        arrays = read_mesh(obj)
        m = len(arrays.F)
        write_uv_layer(obj, name, uv_all[start:start + m], arrays.tri_loops)
        start += m


def _finished(objects, name, uv_in, F, uv_new, texture, start):
    """Post-process ``uv_new`` (:func:`finish_charts`), write it as UV map ``name`` and pack it; returns timings
    (s) and what the post-processing did."""
    topology, stacks = _stacks(F, uv_in)
    face_chart = topology.face_chart
    uv, restored, angles = finish_charts(uv_in, uv_new, face_chart, texel_scale=texture.shape[1::-1], stacks=stacks)
    _write(objects, name, uv)
    shape = _pack(objects, name, _face_stack(face_chart, stacks))
    return {"total": time.perf_counter() - start, **_post_counts(restored, angles), **shape}


def _post_counts(restored, angles):
    return {"restored_charts": int(len(restored)), "turned_charts": int(np.count_nonzero(angles))}


def _texture(objects):
    return read_image(source_image(objects))


def loss_planes(objects, *, source_uv, maps="material"):
    """The planes the triangle-wise and mesh-wise stages of ours see, built as the product builds them.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
    source_uv : str
        The UV map the materials' images are read through.
    maps : {"material", "luma"}, optional
        ``"material"``: every map the materials read through ``source_uv``
        (:func:`.material_copy.read_maps`), each as the planes :func:`.material_copy.loss_planes_of` gives it
        (base colour as luma first, tangent-space normals as their shading, data maps per used channel), so
        that a comparison measures what a run of the product does. ``"luma"``: the first of those planes alone,
        the base colour's luma (the paper's single-texture loss).

    Returns
    -------
    core.loss_planes.PlaneStack
        With its plane names. ``"luma"`` of a material whose stack is its luma alone is that same stack.

    Raises
    ------
    ValueError
        When a map cannot be re-baked or the base colour is not read through ``source_uv``
        (:func:`.material_copy.read_maps`): the product refuses such an input too.
    """
    if maps not in LOSS_MAPS:
        raise ValueError(f"maps must be one of {LOSS_MAPS}, got {maps!r}")
    image = source_image(objects)
    records, _ = read_maps(objects, source_uv, image)
    planes = loss_planes_of(records, read_image(image))
    if maps == "luma" and len(planes) > 1:
        return PlaneStack(planes[:1], planes.names[:1])
    return planes


def repacked_input(objects, *, source_uv, name="InputRepacked"):
    """The input UV map copied to ``name`` and re-packed with 90-degree rotations. Returns timings (s)."""
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    _, F, uv = mesh_arrays(objects, source_uv)
    _write(objects, name, uv)
    topology, stacks = _stacks(F, uv)
    shape = _pack(objects, name, _face_stack(topology.face_chart, stacks))
    return {"total": time.perf_counter() - start, **shape}


def blender_unwrap(objects, *, source_uv, method, name=None):
    """Blender's unwrap (``method`` in :data:`BLENDER_METHODS`) with seams from the input islands, packed.

    The unwrap runs on temporary copies (seams marked there); the result, post-processed as every method's
    (:func:`finish_charts`, towards the input's texel grid), is copied to a new UV map ``name`` (default the
    method's name) on the original objects. Returns timings (s) and the restored and turned chart counts.
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
    V, F, uv = mesh_arrays(objects, source_uv)
    # per loop -> per triangle corner, in mesh_arrays' order
    unwrapped = np.concatenate([values[read_mesh(obj).tri_loops] for obj, values in zip(objects, uvs)])
    return _finished(objects, name, uv, F, unwrapped, _texture(objects), start)


def ssp_uv(objects, *, source_uv, name="SSP", **options):
    """SSP (Sander et al. 2002) from the input UV map and texture, post-processed (:func:`finish_charts`, towards
    the input's texel grid) and packed. Returns timings (s) and the restored and turned chart counts."""
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    V, F, uv = mesh_arrays(objects, source_uv)
    texture = _texture(objects)
    result = solve_ssp(V, F, uv, texture, **options)
    return _finished(objects, name, uv, F, result.uv, texture, start)


def sspop_uv(objects, *, source_uv, name="SSPOP"):
    """SSP's expected stretch as targets of our mesh-wise solver with w_R = 0 (paper Sec. 5.2.2), post-processed
    (:func:`finish_charts`, towards the input's texel grid: SSP's targets carry no rotation) and packed.
    Returns timings (s) and the restored and turned chart counts."""
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    V, F, uv = mesh_arrays(objects, source_uv)
    texture = _texture(objects)
    params, w_R, w_S = ssp_targets(V, F, uv, texture)
    result = solve_meshwise(F, uv, params, w_R, w_S)
    return _finished(objects, name, uv, F, result.uv, texture, start)


def triangle_targets(objects, *, source_uv, epsilon, evaluations, screen_pixels=64, workers=1, seed=0, cache=None,
                     planes=None, **options):
    """The triangle-wise stage (Sec. 4.1) on the objects: its result and its time (s), reusable across ablations.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
    source_uv : str
    epsilon, evaluations, screen_pixels, workers, seed
        Of :func:`core.trianglewise.optimize_triangles`.
    cache : path, optional
        An ``.npz`` file that keeps the result between runs, so that a change to the later stages is measured
        without the triangle-wise stage again: it is read when it was written for the same vertices, faces, UVs,
        planes (every array and its name) and settings (the time returned is then that of the run that wrote
        it), and written otherwise. The code is not part of the key: a change to the triangle-wise stage needs a
        new cache. While the stage runs, the faces done so far are kept next to it (``<cache>.partial.npz``,
        about every half minute): a run cut off resumes from them, and its time adds up every run's.
    planes : core.loss_planes.PlaneStack, optional
        What the loss sees; default :func:`loss_planes` of the objects (every map of the material, as the
        product's run).
    **options
        To :func:`core.trianglewise.optimize_triangles` (e.g. the paper's ``formulation="barrier"``,
        ``max_screen_pixels=64`` and ``view_faces="one_ring"``) and into the cache key.

    Returns
    -------
    result : core.trianglewise_result.TrianglewiseResult
    seconds : float
    """
    V, F, uv = mesh_arrays(objects, source_uv)
    if planes is None:
        planes = loss_planes(objects, source_uv=source_uv)
    settings = dict(epsilon=epsilon, evaluations=evaluations, screen_pixels=screen_pixels, seed=seed, **options)
    key = _triangle_cache_key(V, F, uv, planes, **settings)
    stored = _read_triangle_cache(cache, key)
    if stored is not None:
        return stored
    partial = None if cache is None else pathlib.Path(cache).with_suffix(".partial.npz")
    known, earlier = _read_triangle_cache(partial, key) or (None, 0.0)
    start = time.perf_counter()

    def keep(result):
        _write_triangle_cache(partial, key, result, earlier + time.perf_counter() - start)

    result = optimize_triangles(V, F, uv, planes, workers=workers, known=known,
                                checkpoint=None if cache is None else keep, **settings)
    seconds = earlier + time.perf_counter() - start
    if cache is not None:
        _write_triangle_cache(cache, key, result, seconds)
        partial.unlink(missing_ok=True)
    return result, seconds


def _read_triangle_cache(path, key):
    """``(result, seconds)`` kept in ``path`` under ``key``, or None (no file, another key, or unreadable)."""
    if path is None or not os.path.exists(path):
        return None
    try:
        with np.load(path) as stored:
            if str(stored["key"]) != key:
                return None
            return dataclass_from(TrianglewiseResult, stored), float(stored["seconds"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):  # a file cut off or damaged: compute again
        return None


def _write_triangle_cache(path, key, result, seconds):
    """Keep ``result`` in ``path`` whole or not at all (:func:`core.result_cache.save_arrays`)."""
    save_arrays(path, key=key, seconds=seconds, **dataclasses.asdict(result))


def _triangle_cache_key(V, F, uv, planes, **settings):
    """What a cached triangle-wise result must match: a hash of the mesh's arrays, of every plane the loss sees
    (its name, dtype, shape and values) and of the settings."""
    if isinstance(planes, np.ndarray):
        planes = PlaneStack([planes])
    names = getattr(planes, "names", tuple(f"plane{i}" for i in range(len(planes))))
    digest = hashlib.sha256(repr(sorted(settings.items())).encode())
    digest.update(repr(("planes", tuple(names))).encode())
    for array in (V, F, uv, *planes):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def perceptual_uv(objects, *, source_uv, triangles, name, weights="perceptual", formulation="perceptual",
                  rotation_scale=None, workers=1, min_texels=MIN_TEXELS, signal_weight=SIGNAL_WEIGHT,
                  weight_floor=STRETCH_WEIGHT_FLOOR, fold_tolerance=FOLD_TOLERANCE, keep_stacks=True, planes=None):
    """Our mesh-wise stage on triangle-wise results ``triangles``, or one of the Fig. 17 ablations, packed.

    By default as in the pipeline (:func:`core.chartfit.fit_charts`): fits with and without Eq. 16's rotation
    terms, each post-processed as :func:`finish_charts` does, and every chart keeping the fit whose triangles'
    loss E is lower. An ablation (``weights``, ``formulation`` or ``rotation_scale`` given) is one fit of Eq. 19
    post-processed by :func:`finish_charts` with the rotation targets and weights ours turns its charts with
    (the triangle-wise ``alpha`` and Eq. 17's ``w_R``, whatever ``rotation_scale`` the fit used), so that it
    differs from ours only in what it ablates.

    Parameters
    ----------
    triangles : core.trianglewise_result.TrianglewiseResult
        Of every face; its ``fit_targets()`` and ``fit_weights()`` drive the fit, as in the pipeline.
    weights : {"perceptual", "identity"}
    formulation : {"perceptual", "common"}
    rotation_scale : float, optional
        Of :meth:`~core.trianglewise_result.TrianglewiseResult.fit_weights` for one fit; 1 fits Eq. 16's rotation
        targets, 0 leaves them out.
    workers : int, optional
        Processes measuring E (:func:`core.loss_passes.iter_fit_losses`; 0: one per core).
    min_texels, signal_weight : float, optional
        Of :meth:`~core.trianglewise_result.TrianglewiseResult.fit_targets` (the texel floor and the signal-stretch
        blend; 0 turns each off).
    weight_floor : float, optional
        ``floor`` of :meth:`~core.trianglewise_result.TrianglewiseResult.fit_weights`.
    fold_tolerance : float, optional
        Of :func:`core.overlap.restore_folded_charts`, for the default.
    keep_stacks : bool, optional
        Charts that share texels in the input stay stacked (:mod:`core.stacks`), as in the pipeline and for
        every baseline; False gives every chart texels of its own.
    planes : core.loss_planes.PlaneStack, optional
        What the loss sees in the fit's targets, the choice between the fits and ``above_bound``: those
        ``triangles`` were optimized on; default :func:`loss_planes` of the objects (every map of the material,
        as the product's run).

    Returns
    -------
    dict
        Times (s), the post-processing's counts, and ``above_bound``: the fractions of textured triangles whose
        E (the project's views, :func:`core.loss_passes.iter_fit_losses`) exceeds the triangle-wise epsilon at
        the fit's targets and after the fit (:func:`core.textured.above_bound`): for ours measured with the choice
        between the fits, in ``mesh`` as in the pipeline; for an ablation after ``mesh`` was timed.
    """
    objects = _check(objects, source_uv, name)
    start = time.perf_counter()
    V, F, uv = mesh_arrays(objects, source_uv)
    texture = _texture(objects)
    if planes is None:
        planes = loss_planes(objects, source_uv=source_uv)
    signal = ssp_targets(V, F, uv, texture)[0] if signal_weight > 0 else None
    params = triangles.fit_targets(uv, planes, min_texels=min_texels, signal_targets=signal,
                                   signal_weight=signal_weight)
    target_losses = fit_losses = None
    topology, stacks = _stacks(F, uv, keep_stacks)
    face_chart = topology.face_chart
    if (weights, formulation, rotation_scale) == ("perceptual", "perceptual", None):
        def measure(fits):  # the targets' losses and the two fits' in one pass, as the pipeline measures them
            nonlocal target_losses
            target_losses, losses = yield from iter_fit_losses(V, F, uv, planes, params, fits, workers=workers)
            return losses

        fit = fit_charts(F, uv, params, *triangles.fit_weights(floor=weight_floor), measure=measure,
                         texel_scale=texture.shape[1::-1], fold_tolerance=fold_tolerance, stacks=stacks,
                         topology=topology)
        uv_fit, post, fit_losses = fit.uv, _post_counts(fit.restored, fit.angles), fit.losses
    else:
        w_R, w_S = triangles.fit_weights(floor=weight_floor,
                                         rotation_scale=0.0 if rotation_scale is None else rotation_scale)
        result = solve_meshwise(F, uv, params, w_R, w_S, weights=weights, formulation=formulation,
                                texel_scale=texture.shape[1::-1], topology=topology)
        uv_fit, restored, angles = finish_charts(uv, result.uv, face_chart, alpha=params[:, 0],
                                                 w_R=triangles.fit_weights()[0], texel_scale=texture.shape[1::-1],
                                                 stacks=stacks)
        post = _post_counts(restored, angles)
    t_mesh = time.perf_counter() - start
    if fit_losses is None:
        target_losses, (fit_losses,) = run_generator(iter_fit_losses(V, F, uv, planes, params, [uv_fit],
                                                                     workers=workers))
    bound = above_bound(uv, planes, triangles.epsilon, targets=target_losses, fit=fit_losses)
    _write(objects, name, uv_fit)
    shape = _pack(objects, name, _face_stack(face_chart, stacks))
    return {"mesh": t_mesh, "total": time.perf_counter() - start, "above_bound": bound, **post, **shape}
