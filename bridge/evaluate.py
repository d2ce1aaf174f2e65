"""Whole-mesh evaluation of a UV map (paper Sec. 5.1): q_r at target relative costs, and E_iso.

For each target relative cost ``c_r`` the integer resolution ``r`` closest to it (Eq. 20-21) is chosen (an image
of the shape the candidate was packed for, when that is not a square: :func:`.core.cost.size_for_cost`; the
input UV map itself in the input texture's shape), the
ORIGINAL texture is baked through the reference UV map into an ``r x r`` image on the candidate UV map
(Blender's Cycles bake), and 20 workbench views from the vertices of a regular dodecahedron (flat light,
texture colour, linear interpolation, stored texture values) of the candidate are compared with the same views
of the reference (reference UV map + original image) by mean GMSD (Eq. 22-23). The symmetric Dirichlet energy
E_iso (Eq. 24) is computed with the UV map scaled to the surface area. Every q is reported with the screen size.

References
----------
Sun et al. 2022, Sec. 5.1, Eq. 20-24.
"""

import time

import bpy
import numpy as np

from ..core.cost import relative_cost, size_for_cost
from ..core.evaluation import dodecahedron_cameras, perceptual_loss_of_views, symmetric_dirichlet
from ..core.mesh import concatenate_meshes
from .material import base_color_image_node
from .mesh_io import read_mesh
from .render import Camera, WorkbenchRenderer
from .bake import bake_base_color

__all__ = ["reference_resolution", "image_aspect", "mesh_arrays", "render_views", "face_id_views", "evaluate_uv_map",
           "checked_inputs"]


def reference_resolution(objects):
    """``(width, height)`` of the base-colour image of ``objects`` with the most pixels: the input texture's
    resolution ``r_input``, whose texels Eq. 20-21 count (a non-square input counts ``width * height``).

    Raises
    ------
    ValueError
        When no object has a base-colour image.
    """
    sizes = []
    for obj in objects:
        for slot in obj.material_slots:
            node = base_color_image_node(slot.material)
            if node is not None and node.image is not None:
                sizes.append((int(node.image.size[0]), int(node.image.size[1])))
    largest = _largest_size(sizes)
    if largest[0] * largest[1] == 0:
        raise ValueError("no base-colour image on the objects: the flat evaluation sees the base colour alone; "
                         "--shaded measures every map of the material")
    return largest


def _largest_size(sizes):
    """The ``(width, height)`` of ``sizes`` with the most pixels (the larger pair of equals); ``(0, 0)`` for none."""
    return max(sizes, key=lambda size: (size[0] * size[1], size), default=(0, 0))


def image_aspect(aspect, uv_name, reference_uv, r_input):
    """The width-to-height ratio of the images a UV map is measured in: ``aspect`` when given; else the input
    texture's ``r_input`` for the input UV map itself (its layout fills that shape: at ``c_r = 1`` it is re-baked
    at the input's own size) and a square for any other map."""
    if aspect is not None:
        return float(aspect)
    return r_input[0] / r_input[1] if uv_name == reference_uv else 1.0


def mesh_arrays(objects, uv_name):
    """World-space triangles and per-corner UVs of several objects, concatenated.

    Returns
    -------
    V : (n, 3) float64 ndarray
    F : (m, 3) int64 ndarray
    uv : (m, 3, 2) float64 ndarray
    """
    mesh = concatenate_meshes([read_mesh(obj, uv_name=uv_name) for obj in objects])
    return mesh.V, mesh.F, mesh.uv


def _dodecahedron_views(V):
    """The 20 evaluation cameras around vertices ``V`` (Eq. 22), as Blender cameras."""
    cams = dodecahedron_cameras(V)
    return [Camera(position=tuple(cams.positions[i]), look_at=tuple(cams.look_at), up=tuple(cams.up[i]),
                   fov_degrees=cams.fov_degrees, clip_start=cams.clip_start, clip_end=cams.clip_end)
            for i in range(len(cams))]


def render_views(objects, *, uv_name, image=None, screen_pixels=512):
    """Render the 20 dodecahedron views of ``objects`` textured through ``uv_name``.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
    uv_name : str
        UV map to texture with.
    image : bpy.types.Image, optional
        Texture for every face; by default each slot's own base-colour image.
    screen_pixels : int, optional
        Width and height of each view.

    Returns
    -------
    list of 20 (screen_pixels, screen_pixels, 4) float32 ndarrays
    """
    objects = list(objects)
    V, _, _ = mesh_arrays(objects, uv_name)
    cameras = _dodecahedron_views(V)
    with WorkbenchRenderer(width=int(screen_pixels), texture_values="stored") as renderer:
        for obj in objects:
            renderer.add_object(obj, uv_name=uv_name, image=image)
        return [renderer.render(camera) for camera in cameras]


_ID_TEXTURE_WIDTH = 1024


def face_id_views(objects, *, screen_pixels=512):
    """Which triangle each pixel of the 20 views of :func:`render_views` shows.

    Every triangle is drawn in one flat colour that encodes its index: all three corners sample the centre of
    its own texel of an id texture (exact under linear interpolation), and the render stores values unchanged.
    The objects are not modified (the renderer draws copies made from arrays).

    Parameters
    ----------
    objects : sequence of bpy.types.Object
    screen_pixels : int, optional

    Returns
    -------
    list of 20 (screen_pixels, screen_pixels) int64 ndarrays
        Index into :func:`mesh_arrays`' triangles, -1 where nothing is drawn; row 0 at the bottom.
    """
    objects = list(objects)
    V, F, _ = mesh_arrays(objects, None)
    m = len(F)
    if m >= 256 ** 3 - 1:
        raise ValueError(f"{m} triangles: more than 24-bit face ids can tell apart")
    width = _ID_TEXTURE_WIDTH
    height = -(-m // width)
    ids = np.arange(width * height)
    texture = np.stack([(ids // 256 ** k) % 256 for k in range(3)], axis=-1).reshape(height, width, 3) / 255.0
    face = np.arange(m)
    texel_centre = np.column_stack([(face % width + 0.5) / width, (face // width + 0.5) / height])
    uv = np.repeat(texel_centre[:, None, :], 3, axis=1)
    cameras = _dodecahedron_views(V)
    with WorkbenchRenderer(width=int(screen_pixels), texture_values="stored") as renderer:
        renderer.add_arrays(V, F, uv, texture)
        views = [renderer.render(camera) for camera in cameras]
    out = []
    for view in views:
        digits = np.rint(view[..., :3] * 255.0).astype(np.int64)
        index = digits[..., 0] + 256 * digits[..., 1] + 256 ** 2 * digits[..., 2]
        out.append(np.where(view[..., 3] > 0.5, index, -1))
    return out


def checked_inputs(objects, costs, screen_pixels, uv_names):
    """``(objects, costs)`` as lists after the checks every evaluation makes: objects given, costs positive and
    finite, views of at least 16 px, and each object a mesh with every UV map in ``uv_names``.

    Raises
    ------
    ValueError
        With the first problem found.
    """
    objects = list(objects)
    if not objects:
        raise ValueError("no objects to evaluate")
    costs = [float(c) for c in costs]
    if not costs or any(not np.isfinite(c) or c <= 0 for c in costs):
        raise ValueError(f"costs must be positive numbers, got {costs}")
    if int(screen_pixels) < 16:
        raise ValueError(f"screen_pixels must be >= 16, got {screen_pixels}")
    for obj in objects:
        for name in uv_names:
            if obj.type != "MESH" or name not in obj.data.uv_layers:
                raise ValueError(f"'{obj.name}' has no UV map '{name}'")
    return objects, costs


def _side(width, height):
    """The side of the square with an image's pixel count, rounded down (the side itself for a square)."""
    return int(np.sqrt(width * height))


def _reported_size(width, height):
    """An image's size as the results give it: the side of a square, ``[width, height]`` otherwise."""
    return int(width) if width == height else [int(width), int(height)]


def _size_label(width, height):
    """An image's size in a name: ``"W"`` for a square, ``"WxH"`` otherwise."""
    return f"{width}" if width == height else f"{width}x{height}"


def evaluate_uv_map(objects, uv_name, *, reference_uv, costs=(0.1, 0.2, 0.3, 0.5), screen_pixels=512,
                    margin=None, reference_views=None, keep_images=False, keep_views=False, aspect=None):
    """q_r at each target relative cost and E_iso of UV map ``uv_name`` (paper Sec. 5.1).

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects sharing one texture atlas; not modified (the baked images are removed afterwards unless
        ``keep_images``).
    uv_name : str
        The candidate UV map.
    reference_uv : str
        The input UV map, through which the original texture is read (it defines ``c_r = 1``).
    costs : sequence of float, optional
        Target relative costs ``c_r`` (> 0).
    screen_pixels : int, optional
        Width and height of each of the 20 views; q depends on it and is reported with it.
    margin : int, optional
        Bake margin in pixels; by default ``max(2, r // 128)``.
    reference_views : list of ndarray, optional
        Views from :func:`render_views` of the reference, to reuse across candidates.
    keep_images : bool, optional
        Keep the baked images (returned under ``images``).
    keep_views : bool, optional
        Return each cost's 20 renders under ``rendered`` in its point.
    aspect : float, optional
        Width over height of the image ``uv_name`` was packed for (an ``optimize`` result's image may be a
        rectangle, ``core.packing``): each cost's image has that shape (:func:`.core.cost.size_for_cost`), so
        its texels are square on the surface as the packing laid them out. By default :func:`image_aspect`'s:
        the input texture's shape for the input UV map, a square for another.

    Returns
    -------
    dict
        ``uv_map``, ``reference_uv``, ``screen_pixels``, ``views`` (20), ``reference_resolution`` (the input
        texture's side, ``[width, height]`` when it is not square), ``e_iso``
        (Eq. 24, normalised), ``aspect``, ``points``: one dict per cost with ``target_cost``, ``resolution`` r
        (``[width, height]`` for an image that is not square),
        ``relative_cost`` (the realised c_r), ``q`` (mean GMSD, Eq. 22), ``q_views`` (20 floats), ``time_s``.

    Raises
    ------
    ValueError
        Empty objects, missing UV maps, no base-colour image, non-positive costs or screen size.
    """
    objects, costs = checked_inputs(objects, costs, screen_pixels, (uv_name, reference_uv))
    r_input = reference_resolution(objects)
    aspect = image_aspect(aspect, uv_name, reference_uv, r_input)
    V, F, uv = mesh_arrays(objects, uv_name)
    _, _, uv_ref = mesh_arrays(objects, reference_uv)
    if reference_views is None:
        reference_views = render_views(objects, uv_name=reference_uv, screen_pixels=screen_pixels)
    e_iso = float(symmetric_dirichlet(V, F, uv))
    points, images = [], []
    for target in costs:
        start = time.perf_counter()
        width, height = size_for_cost(uv, target, reference_uv=uv_ref, reference_resolution=r_input, aspect=aspect)
        c = float(relative_cost(uv, (width, height), reference_uv=uv_ref, reference_resolution=r_input))
        r = _reported_size(width, height)
        image = bake_base_color(objects, source_uv=reference_uv, target_uv=uv_name, resolution=(width, height),
                                margin=max(2, _side(width, height) // 128) if margin is None else int(margin),
                                image_name=f"PUV_eval_{uv_name}_{_size_label(width, height)}")
        try:
            views = render_views(objects, uv_name=uv_name, image=image, screen_pixels=screen_pixels)
        finally:
            if keep_images:
                images.append(image)
            else:
                bpy.data.images.remove(image)
        q, per_view = perceptual_loss_of_views(reference_views, views, full=True)
        points.append(dict(target_cost=target, resolution=r, relative_cost=c, q=float(q),
                           q_views=[float(x) for x in per_view], time_s=time.perf_counter() - start))
        if keep_views:
            points[-1]["rendered"] = views
    result = dict(uv_map=uv_name, reference_uv=reference_uv, screen_pixels=int(screen_pixels),
                  views=len(reference_views), reference_resolution=_reported_size(*r_input), e_iso=e_iso, aspect=aspect,
                  points=points)
    if keep_images:
        result["images"] = images
    return result
