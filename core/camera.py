"""The per-triangle orthographic camera of App. A (Algorithm 1), vectorized over triangles.

For triangle ``(a, b, c)`` the camera sits at ``C + 500 N`` (``C`` the barycentre, ``N`` the unit normal) and
looks along ``-N`` with up vector ``U``, as in Algorithm 1. Its right axis ``R`` runs along the triangle's
longest edge and ``U = N x R`` (Algorithm 1 turns ``R`` towards the first corner ``a``); the view is the
triangle's bounding box in the ``(R, U)`` frame, the smallest rectangle around a triangle, which has a side on
its longest edge. The screen is App. A's square on that box (``n x n`` pixels, the box centred in it, its
side the longest edge), but only the pixels whose centres lie in the drawn box are drawn: the triangle's box
with a band of its surroundings :data:`BOX_MARGIN` of the longest edge wide above and below it, within the
square. App. A's square spends most of a sliver's view, and much of any other, on what lies beside the
triangle; the band keeps the texture next to the triangle in view (a view without it judged spot's painted
edges too leniently).

Screen convention used by every module of the package: pixel ``(i, j)`` (row ``i``, column ``j``) of an
``n x n`` screen has its centre at ``(left + (j + 0.5) s / n, bottom + (i + 0.5) s / n)`` in the ``(R, U)``
frame, ``s = right - left = top - bottom`` the square's side: row 0 is the BOTTOM of the view (like Blender's
render result and ``image.pixels``), and pixels are sampled at their centres (as Blender's workbench does with
one sample).

The window is centred on the bounding box, which need not be centred on ``C``; ``view_centre`` gives the
world point at the window's centre (put a Blender orthographic camera there, ``ortho_scale = size``).
"""
from dataclasses import dataclass

import numpy as np

from .charts import texel_areas
from .mesh import check_mesh

__all__ = ["EYE_DISTANCE", "CLIP_NEAR", "CLIP_FAR", "MAX_SCREEN_PIXELS", "BOX_MARGIN", "WINDOWS", "TriangleCameras",
           "triangle_cameras", "texel_matched_pixels"]

#: Distance of the eye from the barycentre along ``N`` (Algorithm 1, line 7).
EYE_DISTANCE = 500.0
#: Near and far clip distances from the eye (Algorithm 1, line 8).
CLIP_NEAR = 0.1
CLIP_FAR = 1000.0
#: Largest side a view grows to for one pixel per texel (:func:`texel_matched_pixels`); a triangle spanning
#: more texels across its window is seen minified.
MAX_SCREEN_PIXELS = 256
#: Band of the surroundings drawn above and below the triangle's box, as a fraction of its longest edge (the
#: box's width); the drawn box stays within the square screen.
BOX_MARGIN = 0.125


@dataclass(frozen=True)
class TriangleCameras:
    """Cameras of ``k`` triangles (Algorithm 1); row ``i`` is the camera of ``faces[i]``.

    Attributes
    ----------
    faces : (k,) ndarray of int64
        Face index each camera belongs to.
    origin : (k, 3) ndarray
        Barycentre ``C`` (the point the camera looks at).
    right, up, normal : (k, 3) ndarray
        Orthonormal frame ``R``, ``U``, ``N`` (right-handed: ``R x U = N``); the camera looks along ``-N``.
    bounds : (k, 4) ndarray
        ``(left, right, bottom, top)`` of the square window in the ``(R, U)`` frame relative to ``origin``.
    screen_pixels : int
        The screen is ``screen_pixels x screen_pixels``.
    valid : (k,) ndarray of bool
        False for degenerate triangles (zero area); their other fields are NaN.
    box : (k, 4) ndarray
        ``(left, right, bottom, top)`` of the drawn part of the window: the triangle's bounding box, as wide as
        the window, with a band :data:`BOX_MARGIN` of its width above and below (within the window).
    """

    faces: np.ndarray
    origin: np.ndarray
    right: np.ndarray
    up: np.ndarray
    normal: np.ndarray
    bounds: np.ndarray
    screen_pixels: int
    valid: np.ndarray
    box: np.ndarray

    def __len__(self):
        return len(self.faces)

    def __getitem__(self, index):
        """Cameras of the selected rows (an int keeps a length-1 batch)."""
        index = np.atleast_1d(np.asarray(index))
        return TriangleCameras(self.faces[index], self.origin[index], self.right[index], self.up[index],
                               self.normal[index], self.bounds[index], self.screen_pixels, self.valid[index],
                               self.box[index])

    @property
    def size(self):
        """(k,) side length ``s`` of the square window, in world units."""
        return self.bounds[:, 1] - self.bounds[:, 0]

    @property
    def half_extent(self):
        """(k,) half the side length (Blender: ``ortho_scale = 2 * half_extent``)."""
        return 0.5 * self.size

    @property
    def pixel_size(self):
        """(k,) side length of one screen pixel, in world units."""
        return self.size / self.screen_pixels

    @property
    def view_centre(self):
        """(k, 3) world point at the centre of the window."""
        cx = 0.5 * (self.bounds[:, 0] + self.bounds[:, 1])
        cy = 0.5 * (self.bounds[:, 2] + self.bounds[:, 3])
        return self.origin + cx[:, None] * self.right + cy[:, None] * self.up

    @property
    def eye(self):
        """(k, 3) eye position ``C + 500 N`` of Algorithm 1 (the window is offset from it in-plane)."""
        return self.origin + EYE_DISTANCE * self.normal

    def pixel_centres(self, row=0):
        """World positions of the pixel centres of camera ``row`` on the plane through ``C``.

        Returns
        -------
        (n, n, 3) ndarray
            Entry ``[i, j]`` is the centre of pixel row ``i`` (0 = bottom), column ``j``.
        """
        n = self.screen_pixels
        left, _, bottom, _ = self.bounds[row]
        step = self.size[row] / n
        x = left + (np.arange(n) + 0.5) * step
        y = bottom + (np.arange(n) + 0.5) * step
        return (self.origin[row] + x[None, :, None] * self.right[row] + y[:, None, None] * self.up[row])


#: What a view draws (:func:`triangle_cameras`): the triangle's box and a band (the default), or App. A's square.
WINDOWS = ("box", "square")


def triangle_cameras(V, F, faces=None, *, screen_pixels=64, window="box"):
    """App. A cameras for many triangles at once.

    Parameters
    ----------
    V : (n, 3) array_like of float64
        Vertex positions.
    F : (m, 3) array_like of int64
        Triangles.
    faces : (k,) array_like of int, optional
        Which triangles; all of them by default.
    screen_pixels : int, optional
        Screen width and height in pixels (the paper uses 64).
    window : {"box", "square"}, optional
        ``"box"`` (default): ``R`` along the longest edge, only the box and its band drawn (module docstring).
        ``"square"``: Algorithm 1 as written, ``R`` towards the first corner ``a`` and the whole square drawn
        (``box`` equals ``bounds``).

    Returns
    -------
    TriangleCameras

    Raises
    ------
    ValueError
        On malformed arrays, indices out of range, ``screen_pixels < 1`` or an unknown ``window``.

    References
    ----------
    Sun et al. 2022, App. A, Algorithm 1 (the eye, clip planes and window; ``R`` along the longest edge and the
    drawn box are this project's, see docs/DECISIONS.md).
    """
    V, F = check_mesh(V, F)
    if int(screen_pixels) != screen_pixels or screen_pixels < 1:
        raise ValueError(f"screen_pixels must be a positive integer, got {screen_pixels}")
    if window not in WINDOWS:
        raise ValueError(f"window must be one of {WINDOWS}, got {window!r}")
    faces = np.arange(len(F)) if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1)
    if faces.size and (faces.min() < 0 or faces.max() >= len(F)):
        raise ValueError("faces refers to triangles outside F")

    a, b, c = (V[F[faces, k]] for k in range(3))
    centre = (a + b + c) / 3.0
    corners = np.stack([a, b, c], axis=1) - centre[:, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = np.cross(b - a, c - a)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        if window == "square":  # Algorithm 1: R points from the barycentre to the first corner
            right = corners[:, 0] / np.linalg.norm(corners[:, 0], axis=1, keepdims=True)
        else:  # R along the longest edge: a triangle's smallest enclosing rectangle has a side on it
            edges = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 1],
                              corners[:, 0] - corners[:, 2]], axis=1)
            lengths = np.linalg.norm(edges, axis=2)
            longest = np.argmax(lengths, axis=1)
            right = edges[np.arange(len(faces)), longest] / lengths[np.arange(len(faces)), longest][:, None]
        up = np.cross(normal, right)
        up /= np.linalg.norm(up, axis=1, keepdims=True)
    valid = np.isfinite(normal).all(1) & np.isfinite(right).all(1) & np.isfinite(up).all(1)

    x = np.einsum("kvd,kd->kv", corners, right)
    y = np.einsum("kvd,kd->kv", corners, up)
    left, rgt = x.min(1), x.max(1)
    bottom, top = y.min(1), y.max(1)
    width, height = rgt - left, top - bottom
    # The square grows the box along its shorter side (along R the longest edge makes the box at least as wide as
    # high); the drawn box grows by BOX_MARGIN of its width on each side, at most to the square.
    grow_x = np.maximum(height - width, 0.0) / 2.0
    grow_y = np.maximum(width - height, 0.0) / 2.0
    bounds = np.stack([left - grow_x, rgt + grow_x, bottom - grow_y, top + grow_y], axis=1)
    if window == "square":
        box = bounds.copy()
    else:
        band = np.minimum(BOX_MARGIN * width, grow_y)
        box = np.stack([left, rgt, bottom - band, top + band], axis=1)

    for field in (centre, normal, right, up, bounds, box):
        field[~valid] = np.nan
    return TriangleCameras(faces, centre, right, up, normal, bounds, int(screen_pixels), valid, box)


def texel_matched_pixels(V, F, uv, texture_shape, faces=None, *, minimum=64, maximum=MAX_SCREEN_PIXELS):
    """Side of each triangle's view: App. A's ``minimum``, grown to one pixel per input texel across the view.

    App. A's 64 px window spans the triangle's bounding box whatever its size in texels. A triangle that spans
    more texels than that is minified, and bilinear lookups (Eq. 9) skip texels: shrinking it until it spans
    about 64 texels changes nothing on such a screen, so the loss cannot see its detail go.

    Parameters
    ----------
    V : (n, 3) array_like of float64
    F : (m, 3) array_like of int64
    uv : (m, 3, 2) array_like of float64
        Input per-corner UVs.
    texture_shape : tuple
        ``(h, w)`` or ``(h, w, c)`` of the input texture.
    faces : (k,) array_like of int, optional
        Which triangles; all of them by default.
    minimum, maximum : int, optional
        Bounds of the side; ``maximum <= minimum`` gives App. A's fixed ``minimum``.

    Returns
    -------
    (k,) ndarray of int64
        ``clip(2 ceil(t / 2), minimum, max(minimum, maximum))`` with ``t`` the input texels across the window:
        the window side times the triangle's texel density ``sqrt(texel area / surface area)``. Even, so that
        GMSD's 2x2 pooling needs no padding; ``minimum`` for triangles without surface or UV area.

    References
    ----------
    Sun et al. 2022, App. A (Algorithm 1), Eq. 9.
    """
    if int(minimum) != minimum or minimum < 1:
        raise ValueError(f"minimum must be a positive integer, got {minimum}")
    cameras = triangle_cameras(V, F, faces)
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (len(np.asarray(F)), 3, 2):
        raise ValueError(f"uv must have shape (m, 3, 2) = {(len(np.asarray(F)), 3, 2)}, got {uv.shape}")
    h, w = texture_shape[:2]
    texel_area = texel_areas(uv[cameras.faces], w, h)
    a, b, c = (np.asarray(V, dtype=np.float64)[np.asarray(F)[cameras.faces, k]] for k in range(3))
    surface_area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        across = cameras.size * np.sqrt(texel_area / surface_area)
    across = np.where(np.isfinite(across), across, 0.0)
    even = 2 * np.ceil(across / 2)
    return np.clip(even, int(minimum), max(int(minimum), int(maximum))).astype(np.int64)
