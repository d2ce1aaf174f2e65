"""The triangle-wise perceptual loss-on-screen E (Sec. 4.1.1, Eq. 3, 5, 8-11), batched and fast.

For triangle ``i`` and a deformation ``(alpha, lambda1, lambda2, beta)`` (Eq. 13-14):

1. camera ``C_i`` of App. A (:mod:`.camera`), screen ``n x n`` (64 by default);
2. reference render (Eq. 1, 8-9): the one-ring of ``i`` (triangles sharing a vertex, welded by position) and
   the further faces connected to it that reach into the window (:func:`.one_ring.window_faces`), with
   their input UVs and the input texture at its own resolution, luma only (:mod:`.raster`).
   ``view_faces="one_ring"`` draws App. A's set instead, the triangle and its one-ring only
   (:func:`.one_ring.one_ring_faces`): the paper as written, for comparison;
3. deformed UVs: every drawn triangle's texel-space UVs mapped by ``x -> A (x - c) + c`` with
   ``A = R(alpha) S(lambda1, lambda2, beta)`` (:func:`.deformation.jacobian`), i.e. ``phi~`` of Eq. 6 applied
   to every drawn triangle. The paper sets the offset ``t_i = 0``; the offset does not change the area and
   is free, so we fix ``c``: the texel centre nearest to the UV barycentre of triangle ``i``. Fixing a
   point of the triangle keeps the texel phase under the triangle stable while ``A`` varies (with ``t = 0``
   a triangle far from the UV origin would slide across many texels for a small change of ``A``), and
   fixing it on a texel centre makes the 90-degree symmetry of Eq. 14 exact: a rotation by 90 degrees about
   a texel centre maps the texel lattice onto itself. ``A`` acts on texel units ``(u * w, v * h)`` so
   pixels are square for non-square textures too. Only UVs change: the surface point each pixel sees is
   cached, and only the bilinear weights are recomputed per evaluation.
4. re-bake (Eq. 11) of the texels the deformed triangles read, by least squares (:mod:`.bake_lsq`), at the
   same resolution, and render again (Eq. 2). A texel is its position on the deformed points' lattice, without
   REPEAT wrapping: a footprint wider than the texture gets texels of its own, as every chart does in the
   packed atlas (:func:`.loss_stack._rebake_render_cells`);
5. ``E = GMSD(reference, deformed)`` (Eq. 3, 5) over the covered part of the screen
   (:func:`.gmsd.covered_gmsd`): uncovered pooling cells continue the nearest covered one, so the edge of the
   drawn faces is no step in either render, and the deviation is taken over covered cells only.

Performance (``bench/loss.py``; 2 shared cores, so ranges over runs): one evaluation is one pass over the
covered pixels (deform, bilinear weights, pixels pooled per texel cell into the normal equations), an
envelope Cholesky over the touched texels, a render pass and GMSD, all in one numba kernel
(:func:`.loss_stack._evaluate_planes_kernel`, one plane; a stack's planes of one shape share it). On spot and bob
(64 px): ~0.1 ms per evaluation at shrinks lambda <= 0.5, ~0.15 ms over the whole box, ~0.3 ms at the
identity (median 300-500 touched texels); 30x faster than the numpy/scipy reference path. The solve costs
about ``T * W^2`` for ``T`` touched texels in a footprint ``W`` texels wide, so triangles whose texels are
about the size of a screen pixel (several thousand texels in view) cost 5-15 ms near the identity; wide
footprints are factorized in nested-dissection order instead (:data:`.loss_stack.DISSECTION_COST`,
:mod:`.multifrontal`; about ``T^{3/2}``). Preparation: 0.4-0.9 ms per triangle. The per-triangle cache holds
arrays only (picklable; the numba kernels are module functions), ~165 KB per triangle at 64 px. With the
window faces (step 2) a sliver's view holds the panel around it instead of a thin line, so it costs like a
well-shaped triangle's of the same window.

A material's maps: every function here that takes ``luma`` also takes a stack of scalar planes, each at its
own resolution (:func:`.loss_planes.loss_planes` builds them: colour through luma, data per channel,
tangent-space normals through their shading). Each plane is prepared on its own texel grid with the same views;
a triangle's E is the largest of its planes' (:class:`.loss_planes.StackProblem`); planes of one shape share
the operator's assembly and factorization (:mod:`.loss_stack`), a plane constant under a view is not rendered.
One plane (a 2-D array, or a list of one) is the single-map path above, bit for bit.

Which triangles show texture of their own at all (the fit's texel floor, the bound's fractions) is
:mod:`.textured`.
"""
import dataclasses
from dataclasses import dataclass

import numpy as np

from ._jit import njit
from .bake_lsq import DEFAULT_RIDGE
from .camera import triangle_cameras
from .charts import texel_areas
from .gmsd import GMSD_C, _covered_gradient_kernel, _pooled_index, covered_gmsd
from .loss_planes import StackBatch, StackProblem, texture_luma, texture_planes
from .loss_stack import DISSECTION_COST, PEEL_MIN_CELLS, _evaluate_planes_kernel
from .one_ring import WINDOW_FACE_LIMIT, _window_faces_kernel, one_ring_faces, window_faces
from .raster import _rasterize_kernel, check_mesh, rasterize, sample_bilinear, texel_coordinates

__all__ = ["VIEW_FACES", "TriangleProblem", "TriangleBatch", "StackProblem", "StackBatch", "texture_luma",
           "texture_planes", "triangle_problem", "prepare_triangles", "render_reference"]

#: Which faces a triangle's view draws: ``"window"`` (default) the one-ring and the faces connected to it that
#: reach into the window (:func:`.one_ring.window_faces`); ``"one_ring"`` the triangle and the faces sharing a
#: vertex with it (:func:`.one_ring.one_ring_faces`), as Sec. 4.1 (after Eq. 6) and App. A describe.
VIEW_FACES = ("window", "one_ring")
# The camera window each of them is drawn in (:func:`.camera.triangle_cameras`): App. A's view as written draws
# its whole square.
_CAMERA_WINDOW = {"window": "box", "one_ring": "square"}


def _check_inputs(V, F, uv):
    V, F = check_mesh(V, F)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    if uv.shape != (len(F), 3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2) = {(len(F), 3, 2)}, got {uv.shape}")
    if not (np.isfinite(V).all() and np.isfinite(uv).all()):
        raise ValueError("V and uv must be finite")
    return V, F, uv


def _check_params(params):
    params = np.asarray(params, dtype=np.float64)
    if params.ndim == 1:
        params = params[None, :]
    if params.ndim != 2 or params.shape[1] != 4:
        raise ValueError(f"params must have shape (k, 4) rows (alpha, lambda1, lambda2, beta), got {params.shape}")
    if not np.isfinite(params).all():
        raise ValueError("params must be finite")
    return np.ascontiguousarray(params)


# ---------------------------------------------------------------------------------------------------- kernels
@njit
def _sample_luma_kernel(luma, points):
    h, w = luma.shape
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        x = points[p, 0] - 0.5
        y = points[p, 1] - 0.5
        x0 = np.floor(x)
        y0 = np.floor(y)
        fx = x - x0
        fy = y - y0
        ix0 = int(x0) % w
        iy0 = int(y0) % h
        ix1 = (ix0 + 1) % w
        iy1 = (iy0 + 1) % h
        out[p] = ((1 - fx) * (1 - fy) * luma[iy0, ix0] + fx * (1 - fy) * luma[iy0, ix1]
                  + (1 - fx) * fy * luma[iy1, ix0] + fx * fy * luma[iy1, ix1])
    return out


@njit
def _constant_kernel(luma, points, centre):
    """True when every texel that a deformed point ``A (q - c) + c`` with ``||A|| <= 1`` can read has the same
    luma: such points stay in the disk of radius ``max |q - c|`` around ``c``; a continuous texel coordinate
    ``x`` reads texels ``floor(x)`` and ``floor(x) + 1``, i.e. texels ``t`` with ``|x - t|_inf < 1``."""
    h, w = luma.shape
    if points.shape[0] == 0:
        return True
    radius = 0.0
    for p in range(points.shape[0]):
        dx = points[p, 0] - centre[0]
        dy = points[p, 1] - centre[1]
        radius = max(radius, np.sqrt(dx * dx + dy * dy))
    radius = radius * (1.0 + 1e-12) + 1e-9  # round-off in the deformation must not escape the test
    cx = centre[0] - 0.5
    cy = centre[1] - 0.5
    value = luma[int(np.floor(cy)) % h, int(np.floor(cx)) % w]
    for iy in range(int(np.floor(cy - radius)) - 1, int(np.ceil(cy + radius)) + 2):
        ey = max(abs(iy - cy) - 1.0, 0.0)
        if ey > radius:
            continue
        # Texels of this row within Euclidean distance radius of the disk centre, after the square dilation.
        half = 1.0 + np.sqrt(radius * radius - ey * ey)
        ix0 = int(np.ceil(cx - half))
        ix1 = int(np.floor(cx + half))
        row = iy % h
        col = ix0 % w
        for _ in range(ix1 - ix0 + 1):
            if luma[row, col] != value:
                return False
            col += 1
            if col == w:
                col = 0
    return True


@njit
def _plane_kernel(uv, pixel, face, bary, n, luma, centre, gradient, points, reference, pooled_index):
    """Numba: texel points, reference luma and pooled indices (written into ``points``, ``reference``,
    ``pooled_index``, one row per pixel), point box and constancy of one triangle's view (``pixel, face, bary``
    from :func:`.raster._rasterize_kernel`) on one plane; returns ``(box, constant)``."""
    count = pixel.shape[0]
    h, w = luma.shape
    for p in range(count):
        f = face[p]
        points[p, 0] = (bary[p, 0] * uv[f, 0, 0] + bary[p, 1] * uv[f, 1, 0] + bary[p, 2] * uv[f, 2, 0]) * w
        points[p, 1] = (bary[p, 0] * uv[f, 0, 1] + bary[p, 1] * uv[f, 1, 1] + bary[p, 2] * uv[f, 2, 1]) * h
    reference[:] = _sample_luma_kernel(luma, points)
    m = n // 2
    sums = np.zeros((m + 2) * (m + 2))
    counts = np.zeros((m + 2) * (m + 2))
    box = np.zeros(4)
    if count:
        box[0] = box[1] = points[0, 0]
        box[2] = box[3] = points[0, 1]
    for p in range(count):
        i = pixel[p] // n
        j = pixel[p] - i * n
        pooled_index[p] = (i // 2 + 1) * (m + 2) + j // 2 + 1
        sums[pooled_index[p]] += reference[p]
        counts[pooled_index[p]] += 1.0
        box[0] = min(box[0], points[p, 0])
        box[1] = max(box[1], points[p, 0])
        box[2] = min(box[2], points[p, 1])
        box[3] = max(box[3], points[p, 1])
    _covered_gradient_kernel(sums, counts, m, gradient.reshape(m * m), np.empty((m + 2) * (m + 2)),
                             np.empty((m + 2) * (m + 2), np.int64))
    # Reference values that differ beyond round-off (equal texels v give v * (sum of weights), within a few
    # ulps of v) prove that different texels are readable: skip the disk scan.
    constant = True
    for p in range(1, count):
        if abs(reference[p] - reference[0]) > 1e-9 * (abs(reference[p]) + abs(reference[0])):
            constant = False
            break
    if constant:
        constant = _constant_kernel(luma, points, centre)
    return box, constant


def _points_box(points):
    if len(points) == 0:
        return np.zeros(4)
    return np.array([points[:, 0].min(), points[:, 0].max(), points[:, 1].min(), points[:, 1].max()])


def _evaluate_kernel(params, points, pooled_index, box, reference, reference_gradient, centre, ridge, c_gmsd,
                     use_cells):
    """E of one plane, (k, 4) params -> (k,): :func:`.loss_stack._evaluate_planes_kernel` with P = 1.

    Called from Python, not from another kernel: a numba caller would inline the kernel into a copy that ran
    ~6 % slower."""
    return _evaluate_planes_kernel(params, points, pooled_index, box, reference[None], reference_gradient[None],
                                   centre, ridge, c_gmsd, use_cells, DISSECTION_COST, PEEL_MIN_CELLS)[:, 0]


# ---------------------------------------------------------------------------------------------------- problems
@dataclass(frozen=True)
class TriangleProblem:
    """Everything needed to evaluate E for one triangle; arrays only, so it pickles cheaply.

    Attributes
    ----------
    face : int
    screen_pixels : int
        ``n`` (even); the screen is ``n x n``, row 0 at the bottom of the view.
    texture_shape : tuple of int
        ``(h, w)`` of the texture.
    centre : (2,) ndarray
        Fixed point ``c`` of the deformation in texel units (a texel centre).
    pixel : (p,) ndarray of int64
        Covered pixels (flat ``i * n + j``), ascending.
    points : (p, 2) ndarray
        Texel-space point ``(u * w, v * h)`` each covered pixel sees under the input UVs.
    reference : (p,) ndarray
        Reference render (luma) at the covered pixels.
    reference_gradient : (n/2, n/2) ndarray
        Gradient magnitude of the pooled reference screen over its covered cells, continued into the
        uncovered ones (:func:`.gmsd.covered_gmsd`; the fixed half of E).
    uv_area : float
        Area of the triangle in texel units, ``|triangle^t| * w * h``.
    is_constant : bool
        True when every texel the drawn faces can read under any deformation with ``lambda1, lambda2 <= 1`` has
        the same luma; then ``E == 0`` exactly for all such deformations (and :meth:`evaluate` returns 0).
    ridge : float
        Tikhonov weight of the re-bake.
    """

    face: int
    screen_pixels: int
    texture_shape: tuple
    centre: np.ndarray
    pixel: np.ndarray
    points: np.ndarray
    reference: np.ndarray
    reference_gradient: np.ndarray
    uv_area: float
    is_constant: bool
    ridge: float = DEFAULT_RIDGE
    pooled_index: np.ndarray = dataclasses.field(default=None, repr=False)
    box: np.ndarray = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        # Derived caches of the kernel (cheap; not needed in a pickle but harmless there).
        if self.pooled_index is None:
            object.__setattr__(self, "pooled_index", _pooled_index(self.pixel, self.screen_pixels))
        if self.box is None:
            object.__setattr__(self, "box", _points_box(self.points))

    def evaluate(self, params):
        """Perceptual loss E for deformations of this triangle.

        Parameters
        ----------
        params : (k, 4) or (4,) array_like
            Rows ``(alpha, lambda1, lambda2, beta)`` (Eq. 13-14).

        Returns
        -------
        (k,) ndarray of float64
            ``E = GMSD(reference render, re-baked deformed render)``.

        References
        ----------
        Sun et al. 2022, Eq. 3, 5, 8-11.
        """
        params = _check_params(params)
        if self.is_constant:
            within = (np.abs(params[:, 1]) <= 1.0) & (np.abs(params[:, 2]) <= 1.0)
            if within.all():
                return np.zeros(len(params))
        return _evaluate_kernel(params, self.points, self.pooled_index, self.box, self.reference,
                                self.reference_gradient, self.centre, self.ridge, GMSD_C, True)

    def reference_image(self):
        """(n, n) reference luma screen, row 0 = bottom of the view, 0 where nothing is hit."""
        n = self.screen_pixels
        image = np.zeros(n * n)
        image[self.pixel] = self.reference
        return image.reshape(n, n)

    def deformed_image(self, params):
        """(n, n) re-baked deformed luma screen for one parameter row (numpy reference path)."""
        from .bake_lsq import _rebake_reference
        from .deformation import jacobian
        from .raster import bilinear_weights, deform_points

        params = _check_params(params)
        if len(params) != 1:
            raise ValueError("deformed_image takes one parameter row")
        R, S = jacobian(params[0])
        points = deform_points(self.points, R @ S, self.centre)
        # Texels by position without REPEAT wrapping, as the kernels number them: moved by whole texels to
        # positive coordinates (the weights keep their fractions) on a lattice wider than the footprint.
        if len(points):
            low = np.floor(points.min(axis=0)) - 1.0
            span = np.ceil(points.max(axis=0) - low).astype(np.int64) + 2
            points = points - low
        else:
            span = np.ones(2, np.int64)
        texels, weights = bilinear_weights(points, (int(span[1]), int(span[0])))
        n = self.screen_pixels
        image = np.zeros(n * n)
        if len(texels):
            unique, values = _rebake_reference(texels, weights, self.reference, ridge=self.ridge)
            image[self.pixel] = np.einsum("pk,pk->p", weights, values[np.searchsorted(unique, texels)])
        return image.reshape(n, n)


def _evaluate_reference(problem, params):
    """Plain numpy/scipy E (sparse normal equations, numpy GMSD), for tests of the fused kernel."""
    params = _check_params(params)
    reference = problem.reference_image()
    covered = np.zeros(problem.screen_pixels ** 2, dtype=bool)
    covered[problem.pixel] = True
    covered = covered.reshape(reference.shape)
    return np.array([covered_gmsd(reference, problem.deformed_image(row), covered) for row in params])


@dataclass(frozen=True)
class TriangleBatch:
    """Problems of many triangles of one mesh in concatenated arrays (picklable, cheap to slice).

    ``batch[i]`` is the :class:`TriangleProblem` of ``batch.faces[i]``; ``batch.evaluate(i, params)`` is
    ``batch[i].evaluate(params)``.
    """

    faces: np.ndarray
    screen_pixels: int
    texture_shape: tuple
    offsets: np.ndarray
    centre: np.ndarray
    pixel: np.ndarray
    points: np.ndarray
    reference: np.ndarray
    reference_gradient: np.ndarray
    uv_area: np.ndarray
    is_constant: np.ndarray
    ridge: float = DEFAULT_RIDGE
    pooled_index: np.ndarray = dataclasses.field(default=None, repr=False)
    box: np.ndarray = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        if self.pooled_index is None:
            object.__setattr__(self, "pooled_index", _pooled_index(self.pixel, self.screen_pixels))
        if self.box is None:
            object.__setattr__(self, "box", np.array([_points_box(self.points[lo:hi]) for lo, hi in
                                                      zip(self.offsets[:-1], self.offsets[1:])]).reshape(-1, 4))

    def __len__(self):
        return len(self.faces)

    def __getitem__(self, i):
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(f"problem {i} out of range for a batch of {len(self)}")
        i %= len(self)
        lo, hi = self.offsets[i], self.offsets[i + 1]
        return TriangleProblem(int(self.faces[i]), self.screen_pixels, self.texture_shape, self.centre[i],
                               self.pixel[lo:hi], self.points[lo:hi], self.reference[lo:hi],
                               self.reference_gradient[i], float(self.uv_area[i]), bool(self.is_constant[i]),
                               self.ridge, self.pooled_index[lo:hi], self.box[i])

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def evaluate(self, i, params):
        """E of problem ``i`` for parameter rows ``params`` (k, 4) -> (k,)."""
        return self[i].evaluate(params)


def _check_view_faces(view_faces):
    """``view_faces`` as given, or ValueError when it is not one of :data:`VIEW_FACES`."""
    if not isinstance(view_faces, str) or view_faces not in VIEW_FACES:
        raise ValueError(f"view_faces must be one of {VIEW_FACES}, got {view_faces!r}")
    return view_faces


def _one_ring_draw(ring_offsets, ring, face):
    """The triangle then the rest of its one-ring (ascending): the faces App. A's view draws.

    Returns
    -------
    (k,) ndarray of int64
        ``face`` first, as :func:`.one_ring.window_faces` orders its result.
    """
    neighbours = ring[ring_offsets[face]:ring_offsets[face + 1]]
    return np.concatenate([np.array([face], np.int64), neighbours[neighbours != face]]).astype(np.int64)


def _centre_texels(uv_faces, w, h):
    """Texel centre nearest to the UV barycentre of each triangle (k, 3, 2) -> (k, 2), in texel units."""
    bary = uv_faces.mean(axis=1) * np.array([w, h], dtype=np.float64)
    return np.floor(bary) + 0.5


def prepare_triangles(V, F, uv, luma, faces=None, *, screen_pixels=64, adjacency=None, ridge=DEFAULT_RIDGE,
                      view_faces="window"):
    """Build the loss problems of many triangles of one mesh.

    Parameters
    ----------
    V : (n, 3) array_like of float64
    F : (m, 3) array_like of int64
    uv : (m, 3, 2) array_like of float64
        Input per-corner UVs (``psi^``).
    luma : (h, w) or (h, w, c) array_like, or sequence of (h_i, w_i) ndarrays
        Texture (row 0 = bottom) at its own resolution; colour is reduced to luma (:func:`texture_luma`). A
        sequence is a stack of planes, each at its own resolution (:func:`.loss_planes.texture_planes`,
        :func:`.loss_planes.loss_planes`): every plane is prepared on its own texel grid with the same views.
    faces : (k,) array_like of int, optional
        Triangles to prepare; all by default. Memory is about ``n^2 * 40`` bytes per triangle (165 KB at
        n = 64): prepare large meshes in chunks (e.g. per worker task).
    screen_pixels : int, optional
        Even screen size ``n`` (64 in the paper).
    adjacency : tuple, optional
        ``(offsets, neighbours)`` from :func:`.one_ring.one_ring_faces` with ``V`` (compute it once per mesh
        when preparing chunks).
    ridge : float, optional
        Tikhonov weight of the re-bake (:mod:`.bake_lsq`).
    view_faces : {"window", "one_ring"}, optional
        Faces drawn into each view (:data:`VIEW_FACES`). ``"window"`` (default): the one-ring plus the faces
        connected to it that reach into the window within half a window side of its plane
        (:func:`.one_ring.window_faces`, at most ``WINDOW_FACE_LIMIT``). ``"one_ring"``: the triangle and
        the faces sharing a vertex with it (welded by position), all of them whatever their distance to the
        plane, in App. A's whole square window turned towards the first corner (:func:`.camera.triangle_cameras`
        with ``window="square"``), as App. A draws them; one-ring faces outside the window simply cover no
        pixel. ``"window"`` draws the triangle's box and its band only (``window="box"``). Either way
        E is GMSD over the covered pixels only (:func:`.gmsd.covered_gmsd`, a project decision, see
        docs/DECISIONS.md), not over the whole screen: with ``"one_ring"`` a sliver's view is mostly
        uncovered, and those pixels do not count.

    Returns
    -------
    TriangleBatch or StackBatch
        A :class:`StackBatch` (E the largest of the planes', :class:`.loss_planes.StackProblem`) for two planes
        or more; one plane gives the single-map :class:`TriangleBatch`.

    References
    ----------
    Sun et al. 2022, Sec. 4.1.1 (text after Eq. 6), App. A.
    """
    V, F, uv = _check_inputs(V, F, uv)
    planes = texture_planes(luma)
    if int(screen_pixels) != screen_pixels or screen_pixels < 2 or screen_pixels % 2:
        raise ValueError(f"screen_pixels must be an even integer >= 2, got {screen_pixels}")
    if not ridge > 0:
        raise ValueError(f"ridge must be positive, got {ridge}")
    view_faces = _check_view_faces(view_faces)
    one_ring_only = view_faces == "one_ring"
    n = int(screen_pixels)
    faces = np.arange(len(F), dtype=np.int64) if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1)
    if faces.size and (faces.min() < 0 or faces.max() >= len(F)):
        raise ValueError("faces refers to triangles outside F")
    if adjacency is None:
        adjacency = one_ring_faces(F, V=V)
    ring_offsets, ring = adjacency
    cameras = triangle_cameras(V, F, faces, screen_pixels=n, window=_CAMERA_WINDOW[view_faces])
    frames = np.stack([cameras.origin, cameras.right, cameras.up, cameras.normal], axis=1)

    # Each view is rastered once; every plane samples its own texel grid at the view's pixels, into arrays of
    # the stack's final size (no per-view parts to join: their copies and the heap they fragment were the
    # preparation's peak).
    k = len(faces)
    offsets = np.zeros(k + 1, np.int64)
    empty_draw = np.zeros(0, np.int64)
    stamp = np.zeros(len(F), np.int64)
    views = []
    for row, f in enumerate(faces):
        draw = empty_draw
        if cameras.valid[row] and one_ring_only:
            draw = _one_ring_draw(ring_offsets, ring, int(f))
        elif cameras.valid[row]:
            draw = _window_faces_kernel(V, F, ring_offsets, ring, int(f), frames[row], cameras.bounds[row],
                                        WINDOW_FACE_LIMIT, stamp, row + 1)
        views.append(_rasterize_kernel(V, F, draw, cameras.origin[row], cameras.right[row], cameras.up[row],
                                       cameras.normal[row], cameras.bounds[row], cameras.box[row], n))
        offsets[row + 1] = offsets[row] + len(views[-1][0])
    pixel = np.concatenate([view[0] for view in views]).astype(np.int64) if k else np.zeros(0, np.int64)
    batches = []
    for plane in planes:
        h, w = plane.shape
        centres = _centre_texels(uv[faces], w, h)
        gradients = np.empty((k, n // 2, n // 2))
        constant = np.empty(k, dtype=bool)
        boxes = np.zeros((k, 4))
        points = np.empty((offsets[-1], 2))
        references = np.empty(offsets[-1])
        pooled = np.empty(offsets[-1], np.int64)
        for row, (view_pixel, view_face, view_bary) in enumerate(views):
            lo, hi = offsets[row], offsets[row + 1]
            boxes[row], constant[row] = _plane_kernel(uv, view_pixel, view_face, view_bary, n, plane, centres[row],
                                                      gradients[row], points[lo:hi], references[lo:hi],
                                                      pooled[lo:hi])
        batches.append(TriangleBatch(faces, n, (h, w), offsets, centres, pixel, points, references, gradients,
                                     texel_areas(uv[faces], w, h), constant, float(ridge), pooled, boxes))
    return StackBatch(tuple(batches)) if len(batches) > 1 else batches[0]


def triangle_problem(V, F, uv, luma, face, *, screen_pixels=64, adjacency=None, ridge=DEFAULT_RIDGE,
                     view_faces="window"):
    """The loss problem of one triangle (see :func:`prepare_triangles`, which documents the parameters).

    Returns
    -------
    TriangleProblem or StackProblem
        ``problem.evaluate(params)`` maps (k, 4) rows ``(alpha, lambda1, lambda2, beta)`` to (k,) E values.
    """
    return prepare_triangles(V, F, uv, luma, [face], screen_pixels=screen_pixels, adjacency=adjacency,
                             ridge=ridge, view_faces=view_faces)[0]


def render_reference(V, F, uv, texture, face, *, screen_pixels=64, adjacency=None, view_faces="window"):
    """Reference render of the faces drawn for one triangle (:func:`.one_ring.window_faces`, or its one-ring
    with ``view_faces="one_ring"``) with its App. A camera, all texture channels.

    Parameters
    ----------
    V : (n, 3) array_like of float64
    F : (m, 3) array_like of int64
    uv : (m, 3, 2) array_like of float64
    texture : (h, w) or (h, w, c) array_like
        Row 0 = bottom (``v = 0``), as Blender's ``image.pixels``.
    face : int
    screen_pixels : int, optional
    adjacency : tuple, optional
        Output of :func:`.one_ring.one_ring_faces` with ``V``.
    view_faces : {"window", "one_ring"}, optional
        Faces drawn, as in :func:`prepare_triangles`.

    Returns
    -------
    image : (n, n) or (n, n, c) ndarray of float64
        Row 0 is the BOTTOM of the view (Blender's render-result order); pixel ``(i, j)`` samples the surface
        at its centre ``(left + (j + 0.5) s / n, bottom + (i + 0.5) s / n)`` of the camera's ``(R, U)``
        window; bilinear texture lookup with REPEAT; uncovered pixels are 0.
    mask : (n, n) ndarray of bool
        Covered pixels.
    camera : TriangleCameras
        The camera (a batch of length 1): world frame, window bounds, ``view_centre``, ``half_extent``.
    """
    V, F, uv = _check_inputs(V, F, uv)
    texture = np.asarray(texture, dtype=np.float64)
    if texture.ndim not in (2, 3):
        raise ValueError(f"texture must have shape (h, w) or (h, w, c), got {texture.shape}")
    face = int(face)
    if not 0 <= face < len(F):
        raise ValueError(f"face {face} outside 0..{len(F) - 1}")
    view_faces = _check_view_faces(view_faces)
    one_ring_only = view_faces == "one_ring"
    offsets, ring = one_ring_faces(F, V=V) if adjacency is None else adjacency
    camera = triangle_cameras(V, F, [face], screen_pixels=screen_pixels, window=_CAMERA_WINDOW[view_faces])
    if one_ring_only:
        draw = _one_ring_draw(np.asarray(offsets, np.int64), np.asarray(ring, np.int64), face)
    else:
        draw = window_faces(V, F, (offsets, ring), face, origin=camera.origin[0], right=camera.right[0],
                            up=camera.up[0], normal=camera.normal[0], bounds=camera.bounds[0])
    raster = rasterize(V, F, draw, camera)
    values = sample_bilinear(texture, texel_coordinates(uv, raster.face, raster.bary, texture.shape))
    n = camera.screen_pixels
    image = np.zeros((n * n,) + texture.shape[2:])
    image[raster.pixel] = values
    mask = np.zeros(n * n, dtype=bool)
    mask[raster.pixel] = True
    return image.reshape((n, n) + texture.shape[2:]), mask.reshape(n, n), camera
