"""The loss over a stack of maps: scalar planes built from a material's maps, and E as their largest GMSD.

A material is several images (DESIGN.md, decision 6): base colour, tangent-space normal, packed data
(metallic-roughness, ORM), emissive, ... each at its own resolution. The triangle-wise loss of Sec. 4.1.1
compares grey screens (Eq. 3, 5), so every map becomes one or more scalar planes in [0, 1]
(:func:`loss_planes`):

* colour maps (base colour, emissive): Rec. 601 luma (:func:`texture_luma`), as the single-map loss;
  an alpha channel that is not constant is a plane of its own;
* data maps: one plane per used channel (``channels``), values as stored;
* tangent-space normal maps: the Lambert shading ``max(0, n . l)`` they produce under each of
  :data:`NORMAL_LIGHTS` (three lights at 30 degrees elevation, azimuths 0, 120 and 240 degrees), ``n`` the
  decoded unit normal ``normalize(2 rgb - 1)`` of each texel (:func:`normal_shading`). The lights span the
  three components of ``n`` (unclamped, ``n . l`` is linear in ``n``); they are symmetric about the
  tangent axis, so a map in DirectX convention (green flipped) gives the same loss as its OpenGL twin; at
  30 degrees elevation the shading of normals tilted up to 60 degrees from the surface stays unclamped, and
  the tangential part of the shading, which carries the detail, scales with the cosine of the elevation: low
  lights see it best (against the largest E over 48 lights, ``bench/joint_loss.py``; figures in
  docs/DECISIONS.md).
  Shading is taken per texel and then interpolated (the loss's screen operator stays linear in the texel
  values, Eq. 8-9); a renderer interpolates and normalizes the normal first, a second-order difference
  within one texel.

Planes that are constant over the whole image (an unused channel) are left out: they can never make E
positive.

A triangle's E over the stack is the largest of its planes' E, each plane rendered and re-baked through
the same screen operator (Eq. 8-11) on its own texel grid: ``E <= epsilon`` then holds for every map, and
Eq. 17's weights and the mesh-wise stage take that E unchanged. The deformation's parameters
``(alpha, lambda1, lambda2, beta)`` act in the texel frame of the first plane; a plane of another aspect
ratio sees the same UV-space map, ``A_i = D A D^-1`` with ``D = diag(w_i / w_0, h_i / h_0)``
(:func:`conjugate_params`); a plane of the same aspect ratio (any resolution) sees ``A`` itself. Each plane
keeps its own fixed point (the texel centre nearest the UV barycentre on its grid): the offset is free
(Eq. 14). A plane whose texels under a triangle's view are all equal (its ``is_constant``) is not rendered
and contributes 0 (:attr:`StackProblem.active_planes`).

References
----------
Sun et al. 2022, Sec. 4.1.1, Eq. 3, 5, 8-11, 13-14, 17.
"""
import functools
import math
from dataclasses import dataclass

import numpy as np

from .gmsd import GMSD_C
from .gmsd import luma as _to_luma
from .progress import run_generator

__all__ = ["MAP_ROLES", "NORMAL_LIGHTS", "NORMAL_LIGHT_ELEVATION", "PlaneStack", "texture_luma", "texture_planes",
           "normal_shading", "loss_planes", "iter_loss_planes", "conjugate_params", "StackProblem", "StackBatch"]

# :func:`iter_loss_planes` hands control back after each band of at most this many texels of a map (its float64
# copy, check and planes: a few hundredths of a second).
_TEXELS_PER_BAND = 1 << 19

#: Roles of the maps :func:`loss_planes` takes.
MAP_ROLES = ("color", "data", "normal")

#: Elevation of the lights a tangent-space normal map is shaded with (radians above the surface).
NORMAL_LIGHT_ELEVATION = math.pi / 6


def _lights(elevation, azimuths):
    c, s = math.cos(elevation), math.sin(elevation)
    return np.array([[c * math.cos(a), c * math.sin(a), s] for a in azimuths])


#: (3, 3) unit light directions in the tangent frame (tangent, bitangent, normal): 30 degrees elevation,
#: azimuths 0, 120, 240 degrees (measured choice, see the module notes).
NORMAL_LIGHTS = _lights(NORMAL_LIGHT_ELEVATION, (0.0, 2 * math.pi / 3, 4 * math.pi / 3))
NORMAL_LIGHTS.setflags(write=False)


class PlaneStack(tuple):
    """A tuple of (h_i, w_i) float64 planes with a name per plane (``names``), from :func:`loss_planes`."""

    def __new__(cls, planes, names=None):
        self = super().__new__(cls, planes)
        self.names = tuple(names) if names is not None else tuple(f"plane{i}" for i in range(len(self)))
        return self

    def __reduce__(self):
        return PlaneStack, (tuple(self), self.names)


def texture_luma(texture):
    """Luma of a texture for the loss: (h, w) passes through, (h, w, c) -> Rec. 601 luma.

    Parameters
    ----------
    texture : (h, w) or (h, w, c) array_like in [0, 1], row 0 = bottom (v = 0)

    Returns
    -------
    (h, w) ndarray of float64, C-contiguous
    """
    texture = np.asarray(texture, dtype=np.float64)
    if texture.ndim not in (2, 3):
        raise ValueError(f"texture must have shape (h, w) or (h, w, c), got {texture.shape}")
    if texture.shape[0] < 1 or texture.shape[1] < 1:
        raise ValueError(f"texture is empty: {texture.shape}")
    return np.ascontiguousarray(_to_luma(texture, channel_axis=-1 if texture.ndim == 3 else None))


def texture_planes(texture):
    """The stack of scalar planes the loss sees: one texture, or a sequence of planes.

    Parameters
    ----------
    texture : (h, w) or (h, w, c) array_like, or sequence of ndarrays
        One texture (reduced to luma, :func:`texture_luma`: the single-map loss), or a list/tuple of arrays,
        each an ``(h_i, w_i)`` plane (or an ``(h_i, w_i, c)`` colour image, reduced to luma) at its own
        resolution, e.g. from :func:`loss_planes`. Row 0 = bottom.

    Returns
    -------
    tuple of (h_i, w_i) ndarray of float64
        At least one plane; a :class:`PlaneStack` keeps its names.
    """
    if isinstance(texture, (list, tuple)) and texture and all(isinstance(p, np.ndarray) for p in texture):
        planes = tuple(texture_luma(p) for p in texture)
        if isinstance(texture, PlaneStack) and all(p is q for p, q in zip(planes, texture)):
            return texture
        return planes
    if isinstance(texture, (list, tuple)) and not texture:
        raise ValueError("the stack of planes is empty")
    return (texture_luma(texture),)


def normal_shading(normal_map, *, lights=NORMAL_LIGHTS):
    """Lambert shading ``max(0, n . l)`` of a tangent-space normal map under fixed lights.

    Parameters
    ----------
    normal_map : (h, w, c) array_like, c >= 3
        RGB in [0, 1] encoding the unit normal in the tangent frame (``n = 2 rgb - 1``, renormalized; a
        zero vector reads as the surface normal ``(0, 0, 1)``).
    lights : (L, 3) array_like, optional
        Unit light directions in the tangent frame (default :data:`NORMAL_LIGHTS`).

    Returns
    -------
    (L, h, w) ndarray of float64 in [0, 1]
        One plane per light. A flat map (0.5, 0.5, 1) gives ``sin(elevation)`` everywhere.
    """
    normal_map = np.asarray(normal_map, dtype=np.float64)
    if normal_map.ndim != 3 or normal_map.shape[2] < 3:
        raise ValueError(f"a normal map must have shape (h, w, c) with c >= 3, got {normal_map.shape}")
    lights = np.asarray(lights, dtype=np.float64).reshape(-1, 3)
    n = 2.0 * normal_map[..., :3] - 1.0
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    flat = norm[..., 0] < 1e-12
    n = np.where(flat[..., None], np.array([0.0, 0.0, 1.0]), n / np.where(flat[..., None], 1.0, norm))
    return np.clip(np.einsum("hwc,lc->lhw", n, lights), 0.0, 1.0)


def _map_entry(entry):
    if isinstance(entry, dict):
        return entry.get("role"), entry.get("pixels"), entry.get("channels"), entry.get("name")
    if isinstance(entry, (list, tuple)) and 2 <= len(entry) <= 3:
        return entry[0], entry[1], (entry[2] if len(entry) == 3 else None), None
    raise ValueError(f"a map is (role, pixels[, channels]) or a dict with 'role' and 'pixels', got {entry!r}")


def loss_planes(maps, *, lights=NORMAL_LIGHTS, drop_constant=True):
    """Scalar planes in [0, 1] the triangle-wise loss sees for a material's maps.

    :func:`iter_loss_planes` is the same computation as a generator that hands control back while it runs.

    Parameters
    ----------
    maps : sequence
        Each map ``(role, pixels)``, ``(role, pixels, channels)`` or a dict with keys ``role``, ``pixels`` and
        optionally ``channels`` and ``name``. ``pixels`` is (h, w) or (h, w, c) in [0, 1], row 0 = bottom, at
        the map's own resolution. Roles (:data:`MAP_ROLES`): ``"color"`` -> luma, plus alpha as a plane when
        ``c == 4`` and alpha varies; ``"data"`` -> one plane per channel of ``channels`` (all by default,
        e.g. ``(1, 2)`` for glTF's roughness and metallic); ``"normal"`` -> one shading plane per light
        (:func:`normal_shading`).
    lights : (L, 3) array_like, optional
        Light directions for normal maps.
    drop_constant : bool, optional
        Leave out planes with a single value over the whole image (they cannot raise E); the first plane is
        kept when every plane is constant, so the stack is never empty.

    Returns
    -------
    PlaneStack
        Tuple of (h_i, w_i) float64 C-contiguous planes, ``names`` e.g. ``("color.luma", "normal.light0")``.
        The first plane sets the texel frame of the deformation's parameters (see the module notes): put the
        base colour first.

    References
    ----------
    Sun et al. 2022, Eq. 3, 5 (GMSD of grey screens).
    """
    return run_generator(iter_loss_planes(maps, lights=lights, drop_constant=drop_constant))


def iter_loss_planes(maps, *, lights=NORMAL_LIGHTS, drop_constant=True, clip=False):
    """Generator form of :func:`loss_planes`: yields ``(done, total)`` maps and returns the :class:`PlaneStack`.

    Each map is converted a band of rows at a time (at most ``_TEXELS_PER_BAND`` texels), with a yield of
    ``(index, len(maps))`` after each band of map ``index`` and ``(len(maps), len(maps))`` at the end; every
    operation is per texel, so the planes are bit for bit those of one pass. ``clip=True`` clips every map to
    [0, 1] first (float images may exceed 1). Use ``stack = yield from iter_loss_planes(...)`` in a pipeline
    generator.
    """
    maps = list(maps)
    planes, names = [], []
    for index, entry in enumerate(maps):
        role, pixels, channels, name = _map_entry(entry)
        name = name or f"{role}{index}"
        if role not in MAP_ROLES:
            raise ValueError(f"map role must be one of {MAP_ROLES}, got {role!r}")
        pixels = np.asarray(pixels)
        if pixels.ndim not in (2, 3) or pixels.shape[0] < 1 or pixels.shape[1] < 1:
            raise ValueError(f"map {name!r} must have shape (h, w) or (h, w, c), got {pixels.shape}")
        h, w = pixels.shape[:2]
        c = 1 if pixels.ndim == 2 else pixels.shape[2]
        # The map's plane names, and what a band of its rows (float64) gives each of them.
        if role == "color":
            if c not in (1, 3, 4):
                raise ValueError(f"expected 1, 3 or 4 channels, got {c}")
            map_names = [f"{name}.luma"] + ([f"{name}.alpha"] if c == 4 else [])

            def convert(band, c=c):
                luma = _to_luma(band, channel_axis=-1 if band.ndim == 3 else None)
                return [luma, band[..., 3]] if c == 4 else [luma]
        elif role == "data":
            chosen = [int(channel) for channel in (range(c) if channels is None else channels)]
            for channel in chosen:
                if not 0 <= channel < c:
                    raise ValueError(f"map {name!r} has {c} channels, channel {channel} asked for")
            map_names = [f"{name}.{channel}" for channel in chosen]

            def convert(band, chosen=chosen):
                stack = band[..., None] if band.ndim == 2 else band
                return [stack[..., channel] for channel in chosen]
        else:
            if pixels.ndim != 3 or c < 3:
                raise ValueError(f"a normal map must have shape (h, w, c) with c >= 3, got {pixels.shape}")
            map_names = [f"{name}.light{light}"
                         for light in range(np.asarray(lights, dtype=np.float64).reshape(-1, 3).shape[0])]

            def convert(band):
                return normal_shading(band, lights=lights)
        map_planes = [np.empty((h, w)) for _ in map_names]
        rows_per_band = max(1, _TEXELS_PER_BAND // w)
        for start in range(0, h, rows_per_band):
            rows = slice(start, start + rows_per_band)
            band = np.asarray(pixels[rows], dtype=np.float64)
            if clip:
                band = np.clip(band, 0.0, 1.0)
            if not np.isfinite(band).all():
                raise ValueError(f"map {name!r} must be finite")
            for plane, values in zip(map_planes, convert(band)):
                plane[rows] = values
            yield index, len(maps)
        planes += map_planes
        names += map_names
    yield len(maps), len(maps)
    if not planes:
        raise ValueError("no maps given")
    if drop_constant:
        keep = [i for i, p in enumerate(planes) if p.min() != p.max()] or [0]
        planes, names = [planes[i] for i in keep], [names[i] for i in keep]
    return PlaneStack(planes, names)


def conjugate_params(params, ratio):
    """Parameters of ``D A D^-1``, ``D = diag(ratio, 1)``: a deformation in another plane's texel frame.

    Parameters
    ----------
    params : (k, 4) ndarray
        ``(alpha, lambda1, lambda2, beta)`` of ``A = R(alpha) S(lambda1, lambda2, beta)`` (Eq. 13-14).
    ratio : float
        ``(w_i / w_0) / (h_i / h_0)``: plane ``i``'s aspect ratio over the first plane's.

    Returns
    -------
    (k, 4) ndarray
        Rows of ``A_i = D A D^-1`` in the same form (polar decomposition, ``lambda1 >= lambda2``); rows whose
        ``A`` has no positive determinant are returned unchanged.
    """
    params = np.asarray(params, dtype=np.float64)
    alpha, l1, l2, beta = params.T
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    s00 = l1 * cb * cb + l2 * sb * sb
    s11 = l1 * sb * sb + l2 * cb * cb
    s01 = (l1 - l2) * cb * sb
    A = np.empty((len(params), 2, 2))
    A[:, 0, 0] = ca * s00 - sa * s01
    A[:, 0, 1] = (ca * s01 - sa * s11) * ratio
    A[:, 1, 0] = (sa * s00 + ca * s01) / ratio
    A[:, 1, 1] = sa * s01 + ca * s11
    out = params.copy()
    valid = np.linalg.det(A) > 0
    if valid.any():
        U, sigma, Wt = np.linalg.svd(A[valid])
        R = U @ Wt
        S = np.swapaxes(Wt, -1, -2) @ (sigma[..., :, None] * Wt)
        eigenvalues, vectors = np.linalg.eigh(S)
        out[valid] = np.column_stack([np.arctan2(R[:, 1, 0], R[:, 0, 0]), eigenvalues[:, 1], eigenvalues[:, 0],
                                      np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1])])
    return out


def _aspect_ratio(shape, first):
    """``(w / w_0) / (h / h_0)``, exactly 1.0 for the same aspect ratio."""
    (h, w), (h0, w0) = shape, first
    return 1.0 if w * h0 == h * w0 else (w / w0) / (h / h0)


@functools.lru_cache(maxsize=1)
def _kernel_modules():
    """:mod:`.loss` and :mod:`.loss_stack`, imported on first use (:mod:`.loss` imports this module)."""
    from . import loss, loss_stack

    return loss, loss_stack


@dataclass(frozen=True)
class StackProblem:
    """E of one triangle over a stack of planes: the largest of its planes' E (see the module notes).

    Attributes
    ----------
    planes : tuple of TriangleProblem
        One per plane, the same face, view and covered pixels, each on its own texel grid; ``planes[0]``
        sets the texel frame of the parameters (:attr:`texture_shape`, :attr:`uv_area`, :attr:`centre`).
    """

    planes: tuple

    @property
    def face(self):
        return self.planes[0].face

    @property
    def screen_pixels(self):
        return self.planes[0].screen_pixels

    @property
    def texture_shape(self):
        return self.planes[0].texture_shape

    @property
    def centre(self):
        return self.planes[0].centre

    @property
    def uv_area(self):
        """Area of the triangle in texels of the first plane (the barrier's area term, Eq. 14)."""
        return self.planes[0].uv_area

    @property
    def is_constant(self):
        """True when every plane is constant under the view: ``E == 0`` for every deformation of the box."""
        return all(p.is_constant for p in self.planes)

    @property
    def active_planes(self):
        """Indices of the planes :meth:`evaluate` renders for deformations with ``lambda1, lambda2 <= 1``: those
        whose texels under the view are not all equal; the others cost nothing."""
        return tuple(i for i, p in enumerate(self.planes) if not p.is_constant)

    def __post_init__(self):
        groups = {}
        for j, plane in enumerate(self.planes):
            groups.setdefault(tuple(plane.texture_shape), []).append(j)
        object.__setattr__(self, "_groups", tuple(tuple(g) for g in groups.values()))
        object.__setattr__(self, "_stacked", {})
        object.__setattr__(self, "_calls", {})

    def _stacked_arrays(self, rows):
        """References (P, count) and reference gradients (P, m, m) of planes ``rows`` (one shape), cached."""
        if rows not in self._stacked:
            self._stacked[rows] = (np.stack([self.planes[j].reference for j in rows]),
                                   np.stack([self.planes[j].reference_gradient for j in rows]))
        return self._stacked[rows]

    def _planned_calls(self, within):
        """The kernel calls :meth:`evaluate_planes` makes, per group of one shape: ``(rows, lead, ratio, stacked)``
        with ``stacked`` the group's references and gradients (None for a plane alone), made once per ``within``
        (whether every row of the call lies in the box, where constant planes cost nothing)."""
        if within not in self._calls:
            calls = []
            first_shape = self.planes[0].texture_shape
            for group in self._groups:
                rows = tuple(j for j in group if not (self.planes[j].is_constant and within))
                if rows:
                    lead = self.planes[rows[0]]
                    stacked = self._stacked_arrays(rows) if len(rows) > 1 else None
                    calls.append((rows, lead, _aspect_ratio(lead.texture_shape, first_shape), stacked))
            self._calls[within] = tuple(calls)
        return self._calls[within]

    def evaluate_planes(self, params):
        """E of every plane for deformations of this triangle.

        Planes of one shape share the screen operator's assembly and the re-bake's factorization
        (:mod:`.loss_stack`); a plane alone in its shape is evaluated as a single map.

        Parameters
        ----------
        params : (k, 4) or (4,) array_like
            Rows ``(alpha, lambda1, lambda2, beta)`` (Eq. 13-14) in the first plane's texel frame.

        Returns
        -------
        (k, P) ndarray of float64
            ``E`` of plane ``j`` in column ``j``; exactly 0 for a plane that is not rendered (constant under the
            view and every row within the box, :attr:`active_planes`).
        """
        loss, loss_stack = _kernel_modules()
        params = loss._check_params(params)
        lambdas = np.abs(params[:, 1:3])
        calls = self._planned_calls(bool((lambdas <= 1.0).all()))
        out = np.zeros((len(params), len(self.planes)))
        for rows, lead, ratio, stacked in calls:
            own = params if ratio == 1.0 else conjugate_params(params, ratio)
            if stacked is None:
                out[:, rows[0]] = lead.evaluate(own)
                continue
            references, gradients = stacked
            values = loss_stack._evaluate_planes_kernel(
                own, lead.points, lead.pooled_index, lead.box, references, gradients, lead.centre, lead.ridge,
                GMSD_C, True, loss_stack.DISSECTION_COST, loss_stack.PEEL_MIN_CELLS)
            if len(rows) == len(self.planes):  # every plane in this one call (the common case): its columns
                return values
            out[:, list(rows)] = values
        return out

    def evaluate(self, params):
        """E of the stack: the largest plane's E per row, NaN when any plane's is (k,) -> (k,).

        References
        ----------
        Sun et al. 2022, Eq. 3, 5, 8-11 (per plane).
        """
        return self.evaluate_planes(params).max(axis=1)


@dataclass(frozen=True)
class StackBatch:
    """Problems of many triangles over a stack of planes: one :class:`.loss.TriangleBatch` per plane, the same
    faces and views in each. ``batch[i]`` is the :class:`StackProblem` of ``batch.faces[i]``."""

    planes: tuple

    @property
    def faces(self):
        return self.planes[0].faces

    @property
    def screen_pixels(self):
        return self.planes[0].screen_pixels

    @property
    def is_constant(self):
        return np.logical_and.reduce([b.is_constant for b in self.planes])

    def __len__(self):
        return len(self.planes[0])

    def __getitem__(self, i):
        return StackProblem(tuple(b[i] for b in self.planes))

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def evaluate(self, i, params):
        """E of problem ``i`` for parameter rows ``params`` (k, 4) -> (k,)."""
        return self[i].evaluate(params)
