# SPDX-License-Identifier: GPL-3.0-or-later
"""The triangle-wise stage's result, and the targets and weights it gives the mesh-wise fit (Eq. 19).

:func:`.trianglewise.optimize_triangles` returns one row per face: the optimum ``(alpha, lambda1, lambda2,
beta)`` of Eq. 7, its loss and the sensitivity weights of Eq. 17. What the mesh-wise stage fits is not that
row as it is:

* targets (:meth:`TrianglewiseResult.fit_targets`): a floor in texels on each stretch of a textured triangle
  (``MIN_TEXELS``), because App. A's 64 px view magnifies a triangle a few texels wide until its texture looks
  smooth and the box floor would leave it a fraction of a texel; and each textured triangle's area drawn
  towards the area signal stretch gives it (``SIGNAL_WEIGHT``), a second estimate of the texels it needs;
* weights (:meth:`TrianglewiseResult.fit_weights`): a floor on every stretch weight (``STRETCH_WEIGHT_FLOOR``),
  so that a triangle whose loss does not react still pulls towards its smallest-area stretch.

Each of the three constants was measured on the ten shared models and kept under the tuning/validation split
(docs/DECISIONS.md).

References
----------
Sun et al. 2022, Eq. 7, 13-14, 17, 19; App. A; Sec. 5.2.2 (SSP's targets in the mesh-wise stage).
Sander et al. 2002 (signal stretch).
"""
import dataclasses

import numpy as np

from .charts import texel_areas
from .loss_planes import texture_planes
from .progress import run_generator
from .textured import iter_textured_triangles

__all__ = ["MIN_TEXELS", "SIGNAL_WEIGHT", "STRETCH_WEIGHT_FLOOR", "TrianglewiseResult"]

#: Added to every stretch weight of the fit: a tenth of the mesh-wise stage's ``w_rs = 1e-5``.
STRETCH_WEIGHT_FLOOR = 1e-6
#: Texel area a textured triangle keeps when both of its stretches sit at the box floor.
MIN_TEXELS = 2.0
#: Weight of signal stretch's area in a textured triangle's target area (geometric blend).
SIGNAL_WEIGHT = 0.5


@dataclasses.dataclass(frozen=True)
class TrianglewiseResult:
    """Output of :func:`.trianglewise.optimize_triangles`, one row per optimized face.

    Attributes
    ----------
    faces : (k,) int64 ndarray
        Face indices (all faces ``0..m-1`` by default).
    params : (k, 4) float64 ndarray
        ``(alpha, lambda1, lambda2, beta)`` per face (Eq. 13-14).
    loss : (k,) float64 ndarray
        E at ``params``.
    w_R, w_S : (k,) float64 ndarray
        Sensitivity weights (Eq. 17), non-negative.
    evaluations : (k,) int64 ndarray
        Loss evaluations used per face (0 for constant views).
    feasible : (k,) bool ndarray
        ``loss <= epsilon``.
    is_constant : (k,) bool ndarray
        Faces skipped because the texture their view reads is constant.
    epsilon, lambda_min : float
    formulation, backend : str
    unevaluated : (k,) bool ndarray, optional
        Faces whose loss could not be evaluated (:class:`.trianglewise.LossNotEvaluableError`); their ``params``
        are the identity, their loss NaN and their weights 0, so the mesh-wise stage keeps their input shape and
        size. All False by default.

    See Also
    --------
    TrianglewiseResult.fit_targets : the targets the mesh-wise stage should use.
    TrianglewiseResult.fit_weights : the weights the mesh-wise stage should use.
    """

    faces: np.ndarray
    params: np.ndarray
    loss: np.ndarray
    w_R: np.ndarray
    w_S: np.ndarray
    evaluations: np.ndarray
    feasible: np.ndarray
    is_constant: np.ndarray
    epsilon: float
    lambda_min: float
    formulation: str
    backend: str
    unevaluated: np.ndarray = None

    def __post_init__(self):
        if self.unevaluated is None:
            object.__setattr__(self, "unevaluated", np.zeros(len(self.faces), dtype=bool))

    def fit_targets(self, uv, luma, *, min_texels=MIN_TEXELS, signal_targets=None, signal_weight=SIGNAL_WEIGHT,
                    textured=None):
        """Targets for the mesh-wise fit (:meth:`iter_fit_targets` run to its end; see it for the parameters).

        Returns
        -------
        (k, 4) float64 ndarray
        """
        return run_generator(self.iter_fit_targets(uv, luma, min_texels=min_texels, signal_targets=signal_targets,
                                                   signal_weight=signal_weight, textured=textured))

    def iter_fit_targets(self, uv, luma, *, min_texels=MIN_TEXELS, signal_targets=None,
                         signal_weight=SIGNAL_WEIGHT, textured=None):
        """Generator: targets for the mesh-wise fit: :attr:`params` with no stretch of a textured triangle below
        the texel floor ``lambda >= sqrt(min_texels / A)``, ``A`` its input area in texels (at most 1), and, given
        signal stretch's targets, each textured triangle's target area drawn towards the area signal stretch
        gives it. Yields ``(done, total)`` after each slice of faces whose texels it tested
        (:func:`.textured.iter_textured_triangles`), then after each plane's texel areas; returns the targets.

        Parameters
        ----------
        uv : (m, 3, 2) array_like of float64
            The input per-corner UVs the stage ran on (rows :attr:`faces` are used).
        luma : (h, w) or (h, w, c) array_like, or sequence of (h_i, w_i) ndarrays
            Its texture or stack of planes, as given to :func:`.trianglewise.optimize_triangles`.
        min_texels : float, optional
            Texel area a textured triangle keeps when both stretches sit at the floor (0: no floor). With a
            stack, the texels are those of the densest plane in which the triangle is textured.
        signal_targets : (m, 4) array_like of float64, optional
            Signal stretch's targets of every face of the mesh (rows as ``uv``), as
            :func:`.ssp.ssp_targets` gives them. ``None``: the stage's own areas only.
        signal_weight : float, optional
            In [0, 1]. A textured triangle's target area becomes ``a^(1 - w) (s b)^w``: ``a`` its own (after the
            floor), ``b`` the signal-stretch area, ``s`` the median of ``a / b`` over the textured triangles (SSP
            fixes areas only up to a common factor). Each triangle keeps its own stretch ratio and orientation,
            and no stretch exceeds 1 (Eq. 14). 0 leaves the areas alone.
        textured : (p, k) array_like of bool, optional
            ``textured_triangles(uv[faces], luma, per_plane=True)`` (:func:`.textured.textured_triangles`) when the
            caller has it already; nothing is tested then.

        Returns
        -------
        (k, 4) float64 ndarray
            ``(alpha, lambda1, lambda2, beta)`` per face of :attr:`faces`; only the lambdas change, and only on
            triangles whose own texels vary (:func:`.textured.textured_triangles`), that have UV area and whose
            loss could be evaluated (:attr:`unevaluated` faces keep the identity).

        Notes
        -----
        App. A's view is at least 64 px wide whatever the triangle's size in texels, so a triangle a few texels
        wide is seen magnified, where bilinear lookups make its texture smooth and the optimum can sit at the box
        floor with a fraction of a texel; the floor, stated in texels and applied to textured triangles only,
        gives them texels of their own. It is not what takes targets past epsilon: the blend is.

        The blend with signal stretch: App. A's optimum is one noisy estimate of the texels a triangle needs (100
        evaluations of Bayesian optimization), made at the magnification of a 64 px view rather than at the
        density the whole model is seen at; SSP's expected stretch (Sander et al. 2002) is another, from the
        texture's gradients over the surface alone, and their geometric mean ranks the triangles better. Both
        constants were measured on the ten shared models and kept under the tuning/validation split: the figures
        are in docs/DECISIONS.md and docs/research.

        References
        ----------
        Sun et al. 2022, Eq. 13-14 (the stretches), App. A (the view), Sec. 5.2.2 (SSP's targets in the mesh-wise
        stage). Sander et al. 2002 (signal stretch).
        """
        if not (np.isfinite(min_texels) and min_texels >= 0):
            raise ValueError(f"min_texels must be a non-negative number, got {min_texels}")
        if not 0 <= signal_weight <= 1:
            raise ValueError(f"signal_weight must be in [0, 1], got {signal_weight}")
        planes = texture_planes(luma)
        uv = np.asarray(uv, dtype=np.float64)
        if uv.ndim != 3 or uv.shape[1:] != (3, 2) or (len(self.faces) and self.faces.max() >= len(uv)):
            raise ValueError(f"uv must have shape (m, 3, 2) with a row for every face of the result, got "
                             f"{uv.shape}")
        blend = signal_targets is not None and signal_weight > 0
        if blend:
            signal_targets = np.asarray(signal_targets, dtype=np.float64)
            if signal_targets.shape != (len(uv), 4):
                raise ValueError(f"signal_targets must have shape ({len(uv)}, 4), a row per face like uv, got "
                                 f"{signal_targets.shape}")
        params = np.array(self.params, dtype=np.float64)
        if min_texels == 0 and not blend:
            return params
        uv = uv[self.faces]
        if textured is None:
            textured = yield from iter_textured_triangles(uv, planes, per_plane=True)
        own = np.asarray(textured, dtype=bool)
        if own.shape != (len(planes), len(uv)):
            raise ValueError(f"textured must have shape ({len(planes)}, {len(uv)}), a row per plane and a column per "
                             f"face of the result, got {own.shape}")
        # A stack: the floor counts texels of the densest plane in which the triangle is textured.
        area = texel_areas(uv, planes[0].shape[1], planes[0].shape[0])
        textured = own[0].copy()
        yield 1, len(planes) + 1  # a plane's texel areas at a time: a few hundredths of a second on 40,000 faces
        for number, plane in enumerate(planes[1:], start=1):
            own_area = texel_areas(uv, plane.shape[1], plane.shape[0])
            area = np.where(own[number] & (~textured | (own_area > area)), own_area, area)
            textured |= own[number]
            yield number + 1, len(planes) + 1
        textured &= ~self.unevaluated
        if min_texels > 0:
            with np.errstate(divide="ignore"):
                floor = np.minimum(1.0, np.sqrt(min_texels / area))
            params[textured, 1:3] = np.maximum(params[textured, 1:3], floor[textured, None])
        if blend:
            _blend_areas(params, signal_targets[self.faces], textured & (area > 0), signal_weight)
        return params

    def fit_weights(self, *, floor=STRETCH_WEIGHT_FLOOR, rotation_scale=1.0):
        """Weights for the mesh-wise fit (Eq. 19): ``rotation_scale * w_R`` and ``w_S + floor``.

        Parameters
        ----------
        floor : float, optional
            Added to every stretch weight; the default is a tenth of the mesh-wise stage's ``w_rs = 1e-5``
            (0 gives Eq. 17's variances unchanged).
        rotation_scale : float, optional
            Multiplies Eq. 17's rotation weight: 1 is Eq. 16 as written, 0 leaves each triangle's rotation to
            the conforming map and fits the stretch targets alone.

        Returns
        -------
        w_R, w_S : (k,) float64 ndarray

        Notes
        -----
        Eq. 17 measures how the loss reacts; the cost of Eq. 7 (texel area) appears in the mesh-wise stage only
        through the target stretch ``S_bar``. Where the loss does not react at all (constant views, 47 % of
        the bundled spot's faces) or barely (smooth texture, a median ``w_S`` of 5e-6 there), Eq. 19 leaves
        the triangle free: it keeps the input's size while the detailed triangles shrink to their targets, so
        the texels go to the triangles that need them least. The floor makes every optimized triangle pull
        towards its smallest-area stretch. Rotation gets no floor: it changes neither the loss of such a
        triangle nor its area. What decides whether a triangle is free is its weight next to ``w_rs``, the
        weight that ties ``R S`` to the conforming Jacobian, so the floor is a fixed fraction of ``w_rs`` and
        does not follow epsilon.

        In one fit, the rotation targets mostly cost more than they give: a chart cannot take each triangle's
        own best rotation, so the weighted rotation terms bend it, and the bending stretches triangles away
        from their targets. That is why the pipeline fits with and without them (``rotation_scale`` 0 and 1)
        and lets every chart keep the better fit (:func:`.chartfit.fit_charts`). The measurements behind both
        are in docs/DECISIONS.md.
        """
        if not (np.isfinite(floor) and floor >= 0):
            raise ValueError(f"floor must be a non-negative number, got {floor}")
        if not (np.isfinite(rotation_scale) and rotation_scale >= 0):
            raise ValueError(f"rotation_scale must be a non-negative number, got {rotation_scale}")
        return rotation_scale * self.w_R, self.w_S + floor


def _blend_areas(params, other, rows, weight):
    """In place: the areas ``lambda1 lambda2`` of ``params[rows]`` towards those of ``other[rows]``, geometrically
    with ``weight``, after scaling ``other`` by the median ratio; shapes kept, stretches at most 1."""
    own = params[rows, 1] * params[rows, 2]
    theirs = other[rows, 1] * other[rows, 2]
    if not own.size:
        return
    if not np.all(np.isfinite(theirs) & (theirs > 0)):
        raise ValueError("signal_targets must have positive, finite stretches")
    log_ratio = np.log(own) - np.log(theirs)
    params[rows, 1:3] *= np.exp(-0.5 * weight * (log_ratio - np.median(log_ratio)))[:, None]
    np.minimum(params[:, 1:3], 1.0, out=params[:, 1:3])
