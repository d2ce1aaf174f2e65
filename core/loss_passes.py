"""Loss passes: the triangle-wise loss E of given deformations or new UV maps, over many faces at once.

The mesh-wise stage, the report and the benchmarks measure E (Sec. 4.1.1) where the optimization did not put
the triangles: at the fit's targets, after each fit, for another method's UV map. A pass prepares each face's
views once (:func:`.loss.prepare_triangles`, the views the triangle-wise stage sees: App. A's window grown to
one pixel per texel up to :data:`.camera.MAX_SCREEN_PIXELS`) and evaluates every row asked of that face on
them, so ``r`` maps measured together cost one preparation, not ``r``. Faces run in chunks in worker processes
(:mod:`.worker_pool`) or on a Dask cluster, as the optimization's do; the state the workers share
(:func:`_iter_state`) and a chunk's preparation (:func:`_prepared`) are the optimization's too.

A new UV map's deformation of triangle ``i`` is the affine map from its input UVs to the new ones, in texels
of the loss's first plane, as Eq. 13's ``(alpha, lambda1, lambda2, beta)`` (:func:`deformation_params`; the
translation ignored as in Eq. 14).

References
----------
Sun et al. 2022, Sec. 4.1.1 (Eq. 8-11), Eq. 13-14, App. A.
"""
import contextlib

import numpy as np

from .camera import MAX_SCREEN_PIXELS, texel_matched_pixels
from .deformation import inverse_2x2
from .loss import _check_view_faces, prepare_triangles
from .loss_planes import texture_planes
from .one_ring import one_ring_faces
from .progress import report_while_waiting, run_generator
from .worker_pool import run_chunks

__all__ = ["deformation_params", "iter_losses_at", "losses_at", "iter_losses_of", "losses_of", "iter_fit_losses"]


def _prepared(state, faces):
    """The problems of ``faces`` in that order, each with its own view size (``state["view_pixels"]``) and the
    faces ``state["view_faces"]`` says to draw."""
    sizes = state["view_pixels"][faces]
    problems = [None] * len(faces)
    for size in np.unique(sizes):
        rows = np.flatnonzero(sizes == size)
        batch = prepare_triangles(state["V"], state["F"], state["uv"], state["luma"], np.asarray(faces)[rows],
                                  screen_pixels=int(size), adjacency=state["adjacency"],
                                  view_faces=state["view_faces"])
        for row, problem in zip(rows, batch):
            problems[row] = problem
    return problems


def _iter_state(V, F, uv, luma, faces, screen_pixels, max_screen_pixels, options, view_faces="window"):
    """Generator: what the workers share, yielding None between its whole-mesh parts (each a few hundredths of a
    second on 40,000 faces): the mesh, the texture (a tuple of planes), the one-rings, every face's view size
    (one pixel per texel of the densest plane, :func:`.camera.texel_matched_pixels`) and which faces the views
    draw (:data:`.loss.VIEW_FACES`)."""
    view_pixels = np.zeros(len(F), dtype=np.int64)
    planes = texture_planes(luma)
    view_pixels[faces] = texel_matched_pixels(V, F, uv, planes[0].shape, faces, minimum=screen_pixels,
                                              maximum=max_screen_pixels)
    for plane in planes[1:]:  # a stack: one pixel per texel of its densest plane
        yield
        view_pixels[faces] = np.maximum(view_pixels[faces], texel_matched_pixels(
            V, F, uv, plane.shape, faces, minimum=screen_pixels, maximum=max_screen_pixels))
    yield
    return {"V": V, "F": F, "uv": uv, "luma": luma, "adjacency": one_ring_faces(F, V=V),
            "view_pixels": view_pixels, "view_faces": _check_view_faces(view_faces), "options": options}


def _check_mesh(V, F, uv, luma, faces):
    from .raster import check_mesh

    V, F = check_mesh(V, F)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    if uv.shape != (len(F), 3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2) = {(len(F), 3, 2)}, got {uv.shape}")
    luma = texture_planes(luma)
    faces = np.arange(len(F), dtype=np.int64) if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1)
    if faces.size and (faces.min() < 0 or faces.max() >= len(F)):
        raise ValueError(f"faces must be indices in 0..{len(F) - 1}")
    return V, F, uv, luma, faces


def _losses_chunk(state, faces):
    """Worker body for :func:`losses_at`: E of each face's deformation rows ``params[face]`` (r, 4), every row
    from the one preparation of the face's views; ``inf`` for a row that is not finite."""
    params = state["options"]["params"]
    out = np.full((len(faces), params.shape[1]), np.inf)
    for row, (face, problem) in enumerate(zip(faces, _prepared(state, faces))):
        finite = np.flatnonzero(np.all(np.isfinite(params[face]), axis=1))
        if not finite.size:
            continue
        try:
            out[row, finite] = problem.evaluate(params[face][finite])
        except (ArithmeticError, np.linalg.LinAlgError):
            for r in finite:  # the rows that can be evaluated keep their E
                with contextlib.suppress(ArithmeticError, np.linalg.LinAlgError):
                    out[row, r] = problem.evaluate(params[face][r:r + 1])[0]
    return np.asarray(faces), out


def _params_from_jacobians(J):
    """``(alpha, lambda1, lambda2, beta)`` with ``J = R(alpha) S(lambda1, lambda2, beta)`` (polar + eigen)."""
    U, sigma, Wt = np.linalg.svd(J)
    R = U @ Wt
    S = np.swapaxes(Wt, -1, -2) @ (sigma[..., :, None] * Wt)
    alpha = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    eigenvalues, vectors = np.linalg.eigh(S)
    beta = np.arctan2(vectors[..., 1, 1], vectors[..., 0, 1])
    return np.column_stack([alpha, eigenvalues[:, 1], eigenvalues[:, 0], beta])


def deformation_params(uv, new_uv, texel_scale):
    """Each triangle's deformation from ``uv`` to ``new_uv`` as Eq. 13's ``(alpha, lambda1, lambda2, beta)``.

    Parameters
    ----------
    uv, new_uv : (m, 3, 2) array_like of float64
        Input and new per-corner UVs in the input's UV units.
    texel_scale : (2,) array_like of float
        Texels per UV unit ``(w, h)`` of the texture the parameters act on (the first plane's for a stack).

    Returns
    -------
    (m, 4) float64 ndarray
        The affine map's Jacobian in texels as rotation and stretch (the translation ignored, as in Eq. 14);
        ``inf`` rows where the new triangle is flipped or degenerate, or the input one degenerate.
    """
    uv = np.asarray(uv, dtype=np.float64)
    new_uv = np.asarray(new_uv, dtype=np.float64)
    if new_uv.shape != uv.shape:
        raise ValueError(f"new_uv must have the shape of uv {uv.shape}, got {new_uv.shape}")
    scale = np.asarray(texel_scale, dtype=np.float64)
    old_edges = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=-1) * scale[:, None]
    new_edges = np.stack([new_uv[:, 1] - new_uv[:, 0], new_uv[:, 2] - new_uv[:, 0]], axis=-1) * scale[:, None]
    old_det = np.linalg.det(old_edges)
    valid = np.abs(old_det) > 1e-12 * np.maximum(np.abs(old_edges).max(axis=(1, 2)) ** 2, 1e-300)
    J = np.zeros_like(old_edges)
    J[valid] = new_edges[valid] @ inverse_2x2(old_edges[valid])
    valid &= np.linalg.det(J) > 0
    params = np.full((len(uv), 4), np.inf)
    if valid.any():
        params[valid] = _params_from_jacobians(J[valid])
    return params


def iter_losses_at(V, F, uv, luma, new_uv, *, screen_pixels=64, max_screen_pixels=MAX_SCREEN_PIXELS, faces=None,
                   workers=1, chunk_size=64, view_faces="window", scheduler=None):
    """Generator form of :func:`losses_at`: yields ``(done, total)`` faces (again every
    :data:`.worker_pool.WAIT_SECONDS` while workers compute), returns the losses."""
    V, F, uv, luma, faces = _check_mesh(V, F, uv, luma, faces)
    new_uv = np.asarray(new_uv, dtype=np.float64)
    if new_uv.shape[-3:] != uv.shape or new_uv.ndim not in (3, 4):
        raise ValueError(f"new_uv must have the shape of uv {uv.shape}, or that shape after a leading axis of r "
                         f"maps, got {new_uv.shape}")
    h, w = luma[0].shape  # the parameters' texel frame: the first plane's (:mod:`.loss_planes`)
    params = np.stack([deformation_params(uv, one, (w, h)) for one in new_uv.reshape((-1,) + uv.shape)], axis=1)
    losses = yield from _iter_losses(V, F, uv, luma, params, faces, screen_pixels, max_screen_pixels, workers,
                                     chunk_size, view_faces, scheduler)
    return losses.T if new_uv.ndim == 4 else losses[:, 0]


def losses_at(V, F, uv, luma, new_uv, *, screen_pixels=64, max_screen_pixels=MAX_SCREEN_PIXELS, faces=None,
              workers=1, chunk_size=64, view_faces="window"):
    """Triangle-wise loss E of a new UV map, each triangle measured with its own deformation.

    The deformation of triangle ``i`` is the affine map from its input UVs to ``new_uv`` (in texel units of
    the input texture, the first plane's for a stack; the translation ignored as in Eq. 14); E is the loss of
    Sec. 4.1.1 with that Jacobian (the largest plane's for a stack).

    Parameters
    ----------
    V, F, uv, luma
        As in :func:`.trianglewise.optimize_triangles` (``uv`` the input UVs the texture belongs to).
    new_uv : (m, 3, 2) or (r, m, 3, 2) array_like
        New UVs per corner in the input's UV units (e.g. the mesh-wise result before packing), or ``r`` such
        maps, measured in one pass: each triangle's views are prepared once for all of them.
    screen_pixels, max_screen_pixels : int, optional
        The views, as in :func:`.trianglewise.optimize_triangles`.
    faces : (k,) array_like of int, optional
    workers : int, optional
        As in :func:`.trianglewise.optimize_triangles` (default in this process).
    chunk_size : int, optional
    view_faces : {"window", "one_ring"}, optional
        Faces the views draw, as in :func:`.trianglewise.optimize_triangles`.

    Returns
    -------
    (k,) or (r, k) ndarray
        E per face (per map); ``inf`` where the new triangle is flipped or degenerate, or the input one
        degenerate.
    """
    return run_generator(iter_losses_at(V, F, uv, luma, new_uv, screen_pixels=screen_pixels,
                                        max_screen_pixels=max_screen_pixels, faces=faces, workers=workers,
                                        chunk_size=chunk_size, view_faces=view_faces))


def iter_losses_of(V, F, uv, luma, params, *, screen_pixels=64, max_screen_pixels=MAX_SCREEN_PIXELS, faces=None,
                   workers=1, chunk_size=64, view_faces="window", scheduler=None):
    """Generator form of :func:`losses_of`: yields ``(done, total)`` faces (again every
    :data:`.worker_pool.WAIT_SECONDS` while workers compute), returns the losses."""
    V, F, uv, luma, faces = _check_mesh(V, F, uv, luma, faces)
    params = np.asarray(params, dtype=np.float64)
    if params.shape[-2:] != (len(faces), 4) or params.ndim not in (2, 3):
        raise ValueError(f"params must have shape {(len(faces), 4)}, a row per face, or (r, {len(faces)}, 4) "
                         f"for r deformations of each, got {params.shape}")
    rows = params.reshape(-1, len(faces), 4)
    every = np.full((len(F), len(rows), 4), np.inf)
    every[faces] = rows.transpose(1, 0, 2)
    losses = yield from _iter_losses(V, F, uv, luma, every, faces, screen_pixels, max_screen_pixels, workers,
                                     chunk_size, view_faces, scheduler)
    return losses.T if params.ndim == 3 else losses[:, 0]


def losses_of(V, F, uv, luma, params, *, screen_pixels=64, max_screen_pixels=MAX_SCREEN_PIXELS, faces=None,
              workers=1, chunk_size=64, view_faces="window"):
    """Triangle-wise loss E of given deformations, e.g. the mesh-wise stage's targets.

    Parameters
    ----------
    V, F, uv, luma
        As in :func:`.trianglewise.optimize_triangles`.
    params : (k, 4) or (r, k, 4) array_like
        ``(alpha, lambda1, lambda2, beta)`` per face of ``faces`` (Eq. 13-14), or ``r`` deformations of each,
        measured in one pass (each triangle's views prepared once).
    screen_pixels, max_screen_pixels, faces, workers, chunk_size, view_faces
        As in :func:`losses_at`.

    Returns
    -------
    (k,) or (r, k) ndarray
        E per face (per deformation); ``inf`` where a row of ``params`` is not finite or E cannot be evaluated.
    """
    return run_generator(iter_losses_of(V, F, uv, luma, params, screen_pixels=screen_pixels,
                                        max_screen_pixels=max_screen_pixels, faces=faces, workers=workers,
                                        chunk_size=chunk_size, view_faces=view_faces))


def _iter_losses(V, F, uv, luma, params, faces, screen_pixels, max_screen_pixels, workers, chunk_size,
                 view_faces="window", scheduler=None):
    """E of ``params`` (m, r, 4), ``r`` rows per face of the mesh, at ``faces``, in worker processes; yields
    ``(done, total)`` faces and returns the (k, r) losses."""
    done = 0
    yield done, len(faces)
    state = yield from report_while_waiting(_iter_state(V, F, uv, luma, faces, screen_pixels, max_screen_pixels,
                                                        {"params": params}, view_faces), (done, len(faces)))
    out = np.empty((len(faces), params.shape[1]))
    row_of = {int(face): row for row, face in enumerate(faces)}
    with contextlib.closing(run_chunks(_losses_chunk, state, faces, workers=int(workers),
                                       chunk_size=int(chunk_size), scheduler=scheduler)) as chunks:
        for item in chunks:
            if item is not None:
                chunk, values = item
                for face, value in zip(chunk, values):
                    out[row_of[int(face)]] = value
                done += len(chunk)
            yield done, len(faces)
    return out


def iter_fit_losses(V, F, uv, luma, targets, new_uvs, *, faces=None, screen_pixels=64,
                    max_screen_pixels=MAX_SCREEN_PIXELS, workers=1, chunk_size=64, view_faces="window",
                    scheduler=None):
    """Generator: E at the mesh-wise fit's targets and under each of its new UV maps, in one loss pass.

    What the mesh-wise stage measures (:func:`.chartfit.iter_fit_charts`' ``measure``, the report's bound):
    each face's views are prepared once for its target and every new map. Yields ``(done, total)`` faces, as
    :func:`iter_losses_of`.

    Parameters
    ----------
    V, F, uv, luma
        As in :func:`.trianglewise.optimize_triangles` (``uv`` the input UVs the texture belongs to).
    targets : (k, 4) array_like of float64
        The fit's targets ``(alpha, lambda1, lambda2, beta)`` per face of ``faces`` (Eq. 13-14).
    new_uvs : sequence of r (m, 3, 2) array_like
        New UVs per corner in the input's UV units (the fits before packing).
    faces : (k,) array_like of int, optional
        The faces to measure (default all).
    screen_pixels, max_screen_pixels, workers, chunk_size, view_faces, scheduler
        As in :func:`losses_at` and :func:`.trianglewise.optimize_triangles`.

    Returns
    -------
    target_losses : (k,) ndarray
        E at each face's target.
    fit_losses : (r, m) ndarray
        E of every face of the mesh under each new map; 0 for faces not in ``faces``, ``inf`` where the new
        triangle is flipped or degenerate, or the input one degenerate.
    """
    faces = np.arange(len(F), dtype=np.int64) if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1)
    planes = texture_planes(luma)
    h, w = planes[0].shape  # the parameters' texel frame: the first plane's (:mod:`.loss_planes`)
    uv = np.asarray(uv, dtype=np.float64)
    deformations = [deformation_params(uv, np.asarray(one, dtype=np.float64), (w, h))[faces] for one in new_uvs]
    measured = yield from iter_losses_of(V, F, uv, planes, np.stack([np.asarray(targets, dtype=np.float64),
                                                                        *deformations]),
                                         screen_pixels=screen_pixels, max_screen_pixels=max_screen_pixels,
                                         faces=faces, workers=workers, chunk_size=chunk_size,
                                         view_faces=view_faces, scheduler=scheduler)
    fit_losses = np.zeros((len(measured) - 1, len(F)))
    fit_losses[:, faces] = measured[1:]
    return measured[0], fit_losses
