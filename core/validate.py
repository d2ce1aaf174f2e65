# SPDX-License-Identifier: GPL-3.0-or-later
"""Check a mesh and its texture before the optimization stages, and say what will be done with them.

Real assets are messy (``../shared/models/README.md``): this module turns each problem into either a
documented treatment or a ``ValueError`` whose message says what is wrong and what to do about it.

Treatments (the input arrays are never changed; the result holds views and new arrays):

* Triangles with zero 3D area (repeated or collinear vertices) or zero UV area are *skipped* by the
  triangle-wise stage: they have no on-screen footprint or no texels, so Eq. 7 has no meaning for them. They
  stay in the mesh, move with their chart in the mesh-wise stage (which gives degenerate UV triangles weight 0)
  and get a UV in the output like every other triangle.
* Texture values outside [0, 1] (float or 16-bit images, HDR) are clipped for the perceptual loss, which is
  defined on [0, 1] (GMSD's constant ``c`` assumes it); the bake reads the image as stored.
* Mirrored and overlapping UV triangles, UVs outside [0, 1] (repeat) and non-square textures are valid input
  and pass unchanged.

* Triangles whose material does not show the texture (``shows_texture``) are skipped the same way.

Refusals: no triangles; NaN or infinite positions, UVs or pixels; a UV map whose triangles all have zero
area (collapsed to a point or a line); a texture smaller than 2 x 2 pixels (one colour, nothing to
optimize); no triangle left to optimize; a run whose memory estimate exceeds the budget.
"""
import dataclasses
import os

import numpy as np

from .mesh import MeshArrays

__all__ = ["ValidatedInput", "validate_inputs", "memory_estimate", "check_memory_budget"]

# Relative tolerance for "zero area": area <= tol * (longest edge)^2, the same criterion as the mesh-wise
# stage's ``degenerate_tol`` so both stages agree on which triangles are degenerate.
AREA_TOLERANCE = 1e-10
# Mesh-wise stage per triangle: 4.5 KB of numpy peak measured with tracemalloc on 3,200 and 20,000 triangle
# grids (core.meshwise.solve_meshwise, 5 iterations), doubled for the sparse factorization, which
# tracemalloc does not see.
_MESHWISE_BYTES_PER_TRIANGLE = 9_000
# Triangle-wise preparation: about screen_pixels^2 * 40 bytes per triangle (core.loss.prepare_triangles),
# a chunk of 16 triangles per worker at a time.
_PREPARE_BYTES_PER_PIXEL = 40
_CHUNK = 16


@dataclasses.dataclass(frozen=True, eq=False)
class ValidatedInput:
    """What :func:`validate_inputs` found and what the stages should use.

    Attributes
    ----------
    mesh : MeshArrays
        The input mesh, every triangle kept (the output is written for all of them).
    texture : (h, w, c) float32 ndarray
        The texture for the perceptual loss, values in [0, 1] (a clipped copy when the input left it).
    optimize : (m,) bool ndarray
        Triangles for the triangle-wise stage; the others are skipped (see the module notes).
    zero_area_3d : (m,) bool ndarray
        Triangles with (numerically) zero area in 3D.
    zero_area_uv : (m,) bool ndarray
        Triangles with (numerically) zero area in UV.
    mirrored_uv : (m,) bool ndarray
        Triangles whose UV corners run clockwise (mirrored texture halves), zero-area ones excluded; optimized
        like the others.
    outside_unit_square : bool
        Whether some UVs leave [0, 1] (the texture repeats there).
    notes : tuple of str
        Sentences for the user about what is done differently from the plain case.
    memory_bytes : int
        The estimate checked against the budget.
    """

    mesh: MeshArrays
    texture: np.ndarray
    optimize: np.ndarray
    zero_area_3d: np.ndarray
    zero_area_uv: np.ndarray
    mirrored_uv: np.ndarray
    outside_unit_square: bool
    notes: tuple
    memory_bytes: int

    @property
    def faces(self):
        """Indices of the triangles to optimize, ascending: ``faces=`` of the triangle-wise stage."""
        return np.flatnonzero(self.optimize)

    def targets(self, params, w_R, w_S):
        """Targets and weights of every triangle for the mesh-wise stage, from those of :attr:`faces`.

        Skipped triangles get the identity deformation and zero weights: they follow their chart without
        pulling on it (the mesh-wise stage still keeps them flip-free when their UV area is non-zero).

        Parameters
        ----------
        params : (k, 4) array_like
            ``(alpha, lambda1, lambda2, beta)`` of the optimized triangles, in the order of :attr:`faces`.
        w_R, w_S : (k,) array_like
            Their sensitivity weights (Eq. 17).

        Returns
        -------
        params : (m, 4) float64 ndarray
        w_R, w_S : (m,) float64 ndarray
        """
        faces = self.faces
        params = np.asarray(params, dtype=np.float64)
        if params.shape != (len(faces), 4):
            raise ValueError(f"params must have shape ({len(faces)}, 4), one row per optimized triangle, got "
                             f"{params.shape}")
        m = self.mesh.n_faces
        full = np.tile([0.0, 1.0, 1.0, 0.0], (m, 1))
        full[faces] = params
        weights = []
        for name, w in (("w_R", w_R), ("w_S", w_S)):
            w = np.asarray(w, dtype=np.float64)
            if w.shape != (len(faces),):
                raise ValueError(f"{name} must have shape ({len(faces)},), got {w.shape}")
            out = np.zeros(m)
            out[faces] = w
            weights.append(out)
        return full, weights[0], weights[1]


def _gib(count):
    if count >= 2**28:
        return f"{count / 2**30:.2f} GiB"
    return f"{count / 2**20:.0f} MiB" if count >= 2**20 else f"{count / 2**10:.0f} KiB"


def _physical_memory():
    """Total physical memory in bytes, or None where the platform does not say (then no default budget)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def memory_estimate(n_vertices, n_triangles, texture_shape, *, workers=1, screen_pixels=64):
    """Peak memory of one optimization run, in bytes, and the parts it is made of.

    Parameters
    ----------
    n_vertices, n_triangles : int
        Size of the (triangulated) mesh.
    texture_shape : tuple of int
        ``(h, w)`` or ``(h, w, c)`` of the input texture.
    workers : int, optional
        Worker processes of the triangle-wise stage (each holds the mesh and the texture's luma); 0 is one
        per core.
    screen_pixels : int, optional
        Largest side of a per-triangle view.

    Returns
    -------
    total : int
    parts : dict of str to int
        ``texture`` (the float32 pixels, the float64 luma, and the larger of the bake's float RGBA copy and
        signal stretch's float64 colour copy, which are never held together), ``workers``
        (copies of luma and mesh in the worker processes), ``triangle-wise`` (per-chunk preparation),
        ``mesh-wise`` (the sparse solve).
    """
    if len(texture_shape) not in (2, 3):
        raise ValueError(f"texture_shape must be (h, w) or (h, w, c), got {texture_shape}")
    h, w = int(texture_shape[0]), int(texture_shape[1])
    c = int(texture_shape[2]) if len(texture_shape) == 3 else 1
    workers = int(workers) if workers else (os.cpu_count() or 1)
    pixels = h * w
    mesh_bytes = n_vertices * 24 + n_triangles * (24 + 48 + 24 + 8 * 3)
    parts = {
        "texture": pixels * (4 * c + 8 + max(16, 8 * min(c, 3))),
        "workers": (workers if workers > 1 else 0) * (pixels * 8 + mesh_bytes),
        "triangle-wise": max(workers, 1) * _CHUNK * screen_pixels ** 2 * _PREPARE_BYTES_PER_PIXEL + mesh_bytes,
        "mesh-wise": n_triangles * _MESHWISE_BYTES_PER_TRIANGLE,
    }
    return int(sum(parts.values())), parts


def check_memory_budget(n_vertices, n_triangles, texture_shape, *, workers=1, screen_pixels=64,
                        memory_budget=None, what="the mesh"):
    """Refuse a run whose :func:`memory_estimate` exceeds the budget, before any large array is read.

    Parameters
    ----------
    n_vertices, n_triangles, texture_shape, workers, screen_pixels
        As in :func:`memory_estimate`.
    memory_budget : int, optional
        Bytes the run may use; default half of the physical memory (no check where it is unknown).
    what : str, optional
        What is optimized, for the message.

    Returns
    -------
    int
        The estimate in bytes.

    Raises
    ------
    ValueError
        With the estimate, its parts and the budget in the message.
    """
    budget = memory_budget
    if budget is None:
        physical = _physical_memory()
        budget = physical // 2 if physical else None
    estimate, parts = memory_estimate(n_vertices, n_triangles, texture_shape, workers=workers,
                                      screen_pixels=screen_pixels)
    if budget is not None and estimate > budget:
        h, w = texture_shape[:2]
        detail = ", ".join(f"{name} {_gib(size)}" for name, size in parts.items())
        processes = int(workers) or os.cpu_count() or 1
        raise ValueError(f"optimizing {what} ({n_triangles} triangles, {w} x {h} texture, {processes} worker "
                         f"processes) needs about {_gib(estimate)} ({detail}), more than the memory budget of "
                         f"{_gib(budget)}; use fewer workers, a smaller texture or fewer triangles")
    return estimate


def _triangle_areas(mesh):
    P = mesh.V[mesh.F]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area3 = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    longest3 = np.max(np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2), axis=1)
    uv = mesh.uv
    f1, f2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    signed_uv = 0.5 * (f1[:, 0] * f2[:, 1] - f1[:, 1] * f2[:, 0])
    longest_uv = np.max(np.linalg.norm(uv - np.roll(uv, 1, axis=1), axis=2), axis=1)
    return area3, longest3, signed_uv, longest_uv


def validate_inputs(mesh, texture, *, shows_texture=None, workers=1, screen_pixels=64, memory_budget=None,
                    uv_name=None, image_name=None):
    """Check a mesh and texture before the stages; return what to optimize, or raise a clear ValueError.

    Parameters
    ----------
    mesh : MeshArrays
        Triangulated mesh with per-corner UVs (``MeshArrays`` already refuses wrong shapes, bad indices and
        non-finite values when it is built; this function repeats the finiteness check for arrays built
        elsewhere).
    texture : (h, w) or (h, w, c) array_like
        The base-colour texture, row 0 at the bottom, ``c`` in 1..4.
    shows_texture : (m,) array_like of bool, optional
        Which triangles show the texture (their material's base colour is this image); the others (another
        material, a constant colour) are skipped like degenerate ones. Default: all.
    workers : int, optional
        Worker processes the run will use (0: one per core), for the memory estimate.
    screen_pixels : int, optional
        Largest per-triangle view size, for the memory estimate.
    memory_budget : int, optional
        Bytes the run may use; default half of the physical memory (no check where it is unknown).
    uv_name, image_name : str, optional
        Names used in messages; default ``mesh.uv_name`` and "the texture".

    Returns
    -------
    ValidatedInput

    Raises
    ------
    ValueError
        If the mesh has no triangles, holds NaN or infinite coordinates, its UV map is collapsed, every
        triangle is degenerate, the texture is smaller than 2 x 2 or holds NaN/infinite values, or the
        memory estimate exceeds ``memory_budget``; the message names the problem and a remedy.

    Examples
    --------
    >>> import numpy as np
    >>> from perceptual_uv.core.mesh import MeshArrays
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    >>> F = np.array([[0, 1, 2], [1, 3, 2]])
    >>> uv = V[F][:, :, :2].copy()
    >>> mesh = MeshArrays(V=V, F=F, uv=uv, tri_loops=np.arange(6).reshape(2, 3), tri_polygons=np.arange(2),
    ...                   material_index=np.zeros(2, np.int64), object_index=np.zeros(2, np.int64))
    >>> result = validate_inputs(mesh, np.random.default_rng(0).random((8, 8, 3)))
    >>> result.optimize.tolist(), result.notes
    ([True, True], ())
    """
    if not isinstance(mesh, MeshArrays):
        raise ValueError(f"mesh must be a MeshArrays, got {type(mesh).__name__}")
    uv_label = f"UV map '{uv_name or mesh.uv_name}'" if (uv_name or mesh.uv_name) else "the UV map"
    image_label = f"image '{image_name}'" if image_name else "the texture"
    objects = ", ".join(f"'{name}'" for name in mesh.object_names if name) or "the mesh"
    m = mesh.n_faces
    if m == 0:
        raise ValueError(f"{objects} has no faces: there is nothing to optimize")
    bad_v = ~np.isfinite(mesh.V).all(axis=1)
    if bad_v.any():
        raise ValueError(f"{objects} has {int(bad_v.sum())} vertices with NaN or infinite coordinates; fix or "
                         "delete them (e.g. Mesh > Clean Up) first")
    bad_uv = ~np.isfinite(mesh.uv).all(axis=(1, 2))
    if bad_uv.any():
        raise ValueError(f"{uv_label} of {objects} has NaN or infinite coordinates on {int(bad_uv.sum())} "
                         "triangles; re-unwrap them first")

    texture = np.asarray(texture)
    if texture.ndim == 2:
        texture = texture[:, :, None]
    if texture.ndim != 3 or not 1 <= texture.shape[2] <= 4:
        raise ValueError(f"{image_label} must have shape (h, w) or (h, w, c) with 1 to 4 channels, got "
                         f"{np.shape(texture)}")
    h, w, c = texture.shape
    if h < 2 or w < 2:
        raise ValueError(f"{image_label} is {w} x {h} pixels: a single row or column of colour has nothing to "
                         "optimize; use an image of at least 2 x 2 pixels")
    if not np.issubdtype(texture.dtype, np.number):
        raise ValueError(f"{image_label} must hold numbers, got dtype {texture.dtype}")

    estimate = check_memory_budget(mesh.n_vertices, m, texture.shape, workers=workers, screen_pixels=screen_pixels,
                                   memory_budget=memory_budget, what=objects)

    finite = np.isfinite(texture)
    if not finite.all():
        raise ValueError(f"{image_label} has {int((~finite).any(axis=2).sum())} pixels with NaN or infinite "
                         "values; fix the image first")
    notes = []
    texture = texture.astype(np.float32, copy=False)
    if texture.min() < 0.0 or texture.max() > 1.0:
        notes.append(f"{image_label} has values outside [0, 1] (float/HDR, range {float(texture.min()):.3g} to "
                     f"{float(texture.max()):.3g}); the perceptual loss sees them clipped to [0, 1] and the baked "
                     "8-bit image is clipped too")
        texture = np.clip(texture, 0.0, 1.0)

    area3, longest3, signed_uv, longest_uv = _triangle_areas(mesh)
    zero_3d = area3 <= AREA_TOLERANCE * np.maximum(longest3, np.finfo(float).tiny) ** 2
    zero_uv = np.abs(signed_uv) <= AREA_TOLERANCE * np.maximum(longest_uv, np.finfo(float).tiny) ** 2
    # A map collapsed to a point or a line has no area anywhere (its longest edge may still be long).
    if zero_uv.all():
        extent = np.ptp(mesh.uv.reshape(-1, 2), axis=0)
        shape = "a point" if np.all(extent == 0) else "a line or points"
        raise ValueError(f"{uv_label} of {objects} is collapsed to {shape} (every UV triangle has zero area); "
                         "unwrap the mesh first (UV > Unwrap) or pick another UV map")
    if shows_texture is None:
        shows_texture = np.ones(m, dtype=bool)
    shows_texture = np.asarray(shows_texture)
    if shows_texture.shape != (m,) or shows_texture.dtype != bool:
        raise ValueError(f"shows_texture must be a bool array of shape ({m},), got {shows_texture.dtype} "
                         f"{shows_texture.shape}")
    optimize = ~(zero_3d | zero_uv) & shows_texture
    if not optimize.any():
        raise ValueError(f"no triangle of {objects} both shows {image_label} and has a non-zero area in 3D and in "
                         f"{uv_label}; there is nothing to optimize")
    if zero_3d.any():
        notes.append(f"{int(zero_3d.sum())} of {m} triangles have zero area in 3D; they are not optimized (nothing "
                     "of them is visible) and follow their UV island")
    only_uv = zero_uv & ~zero_3d
    if only_uv.any():
        notes.append(f"{int(only_uv.sum())} of {m} triangles have zero area in {uv_label}; they are not optimized "
                     "(they show no texels) and follow their UV island")
    if not shows_texture.all():
        notes.append(f"{int((~shows_texture).sum())} of {m} triangles use a material without {image_label}; they "
                     "are not optimized, follow their UV island and get their material's colour in the new image")
    outside = bool(np.any(mesh.uv < 0.0) or np.any(mesh.uv > 1.0))
    return ValidatedInput(mesh=mesh, texture=texture, optimize=optimize, zero_area_3d=zero_3d, zero_area_uv=zero_uv,
                          mirrored_uv=(signed_uv < 0) & ~zero_uv, outside_unit_square=outside,
                          notes=tuple(notes), memory_bytes=estimate)
