# SPDX-License-Identifier: GPL-3.0-or-later
"""Render textured meshes with Blender's workbench engine into numpy arrays (evaluation and fidelity checks).

Everything is drawn in a temporary scene from temporary proxies: a copy of each mesh keeping only the UV map
to show, and a material whose only node is an Image Texture with linear interpolation and REPEAT extension.
The user's objects, meshes, materials, images and scenes are never changed; all temporaries are removed when
the :class:`WorkbenchRenderer` closes.

Colour: with ``texture_values="stored"`` (the default) the texture is read as Non-Color and the view
transform is 'Raw', so filtering happens on the stored values and a texel value comes out unchanged on
screen: this is what ``core`` computes. ``"srgb"`` reads the texture as sRGB and uses the 'Standard' view
transform, as Blender's viewport shows it: a single texel's value still comes out unchanged, but bilinear
blends happen in linear light, so they differ from the stored-value blend at sharp colour edges.

Screen convention of the returned arrays: ``(height, width, 4)`` float32 RGBA in [0, 1], row 0 is the
BOTTOM of the picture (like ``image.pixels`` and the project's textures). For an orthographic camera with
right vector ``R``, up vector ``U`` and scale ``s`` (the larger image side spans ``s`` world units), the
centre of pixel (row ``i``, column ``j``) sees the world point
``position + R * s * ((j + 0.5) / W - 0.5) * W / max(W, H) + U * s * ((i + 0.5) / H - 0.5) * H / max(W, H)``.
Alpha is 0 where no surface is visible (transparent film); texture alpha is ignored (opaque surfaces).
Anti-aliasing is off by default, so each pixel is one sample at its centre.
"""
import contextlib
import dataclasses
import os
import tempfile

import bpy
import numpy as np
from mathutils import Matrix

from .material import base_color_image_node
from .mesh_io import read_image

__all__ = ["Camera", "WorkbenchRenderer", "camera_matrix", "triangle_view"]

_TEXTURE_VALUES = ("stored", "srgb")
_ANTIALIASING = ("OFF", "FXAA", "5", "8", "11", "16", "32")


@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole or orthographic camera.

    Attributes
    ----------
    position : (3,) array_like
        Eye position in world space.
    look_at : (3,) array_like
        A point on the optical axis.
    up : (3,) array_like
        Approximate up direction (made orthogonal to the view direction).
    ortho_scale : float or None
        Orthographic when given: world-space extent of the larger image side. Perspective otherwise.
    fov_degrees : float
        Perspective only: field of view across the larger image side.
    clip_start, clip_end : float
        Near and far clipping distances from the eye.
    """

    position: tuple
    look_at: tuple
    up: tuple = (0.0, 0.0, 1.0)
    ortho_scale: float = None
    fov_degrees: float = 50.0
    clip_start: float = 0.1
    clip_end: float = 1000.0

    def __post_init__(self):
        for name in ("position", "look_at", "up"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise ValueError(f"camera {name} must be 3 finite numbers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(x) for x in value))
        if self.ortho_scale is not None and not (np.isfinite(self.ortho_scale) and self.ortho_scale > 0):
            raise ValueError(f"ortho_scale must be positive, got {self.ortho_scale}")
        if not 0 < self.fov_degrees < 180:
            raise ValueError(f"fov_degrees must be in (0, 180), got {self.fov_degrees}")
        if not 0 < self.clip_start < self.clip_end:
            raise ValueError(f"need 0 < clip_start < clip_end, got {self.clip_start}, {self.clip_end}")
        camera_matrix(self)  # degenerate directions fail here, at construction


def triangle_view(cameras, row=0):
    """The Blender camera equal to one App. A triangle camera of :mod:`..core.camera`.

    Parameters
    ----------
    cameras : core.camera.TriangleCameras
        A batch of Algorithm 1 cameras.
    row : int
        Which camera of the batch.

    Returns
    -------
    Camera
        Orthographic, centred on the square window (Algorithm 1's window need not be centred on the
        barycentre, so the eye moves in-plane with it), 500 units along the normal, up = ``U``, right = ``R``,
        ``ortho_scale`` = the window side, the same near and far planes. Rendered with a film of
        ``cameras.screen_pixels`` square, pixel (i, j) of :meth:`WorkbenchRenderer.render` is pixel (i, j) of
        ``cameras.pixel_centres(row)``.
    """
    from ..core.camera import CLIP_FAR, CLIP_NEAR, EYE_DISTANCE

    if not cameras.valid[row]:
        raise ValueError(f"camera {row} belongs to a degenerate triangle")
    centre = cameras.view_centre[row]
    return Camera(position=centre + EYE_DISTANCE * cameras.normal[row], look_at=centre, up=cameras.up[row],
                  ortho_scale=float(cameras.size[row]), clip_start=CLIP_NEAR, clip_end=CLIP_FAR)


def _srgb_to_linear(values):
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)


def camera_matrix(camera):
    """World matrix of a Blender camera object looking from ``position`` at ``look_at``.

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    (4, 4) float64 ndarray
        Columns: right, up, backward (Blender cameras look down their local -Z) and the position.

    Raises
    ------
    ValueError
        If ``look_at`` equals ``position`` or ``up`` is parallel to the view direction.
    """
    position = np.asarray(camera.position, dtype=np.float64)
    backward = position - np.asarray(camera.look_at, dtype=np.float64)
    if np.linalg.norm(backward) == 0:
        raise ValueError("camera position and look_at coincide")
    backward /= np.linalg.norm(backward)
    right = np.cross(np.asarray(camera.up, dtype=np.float64), backward)
    if np.linalg.norm(right) < 1e-12:
        raise ValueError("camera up is parallel to the view direction")
    right /= np.linalg.norm(right)
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = right, np.cross(backward, right), backward, position
    return matrix


class WorkbenchRenderer:
    """A temporary workbench scene: add textured proxies, render camera views to arrays, then close.

    Parameters
    ----------
    width : int
        Film width in pixels.
    height : int, optional
        Film height in pixels; ``width`` by default.
    texture_values : {"stored", "srgb"}
        How texture values reach the screen, see the module docstring.
    antialiasing : {"OFF", "FXAA", "5", "8", "11", "16", "32"}
        Workbench render anti-aliasing; "OFF" samples each pixel once at its centre.

    Examples
    --------
    >>> with WorkbenchRenderer(width=512) as renderer:          # doctest: +SKIP
    ...     renderer.add_object(obj, uv_name="PerceptualUV", image=baked)
    ...     rgba = renderer.render(Camera(position=(0, -5, 0), look_at=(0, 0, 0), ortho_scale=2.0))
    """

    def __init__(self, *, width, height=None, texture_values="stored", antialiasing="OFF"):
        height = width if height is None else height
        for name, value in (("width", width), ("height", height)):
            if int(value) != value or value <= 0:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if texture_values not in _TEXTURE_VALUES:
            raise ValueError(f"texture_values must be one of {_TEXTURE_VALUES}, got {texture_values!r}")
        if antialiasing not in _ANTIALIASING:
            raise ValueError(f"antialiasing must be one of {_ANTIALIASING}, got {antialiasing!r}")
        self.width, self.height = int(width), int(height)
        self.texture_values = texture_values
        self._created = []
        self._image_copies = {}
        self._had_render_result = "Render Result" in bpy.data.images
        self._folder = tempfile.TemporaryDirectory(prefix="perceptual_uv_render_")
        try:
            self.scene = self._new(bpy.data.scenes, "perceptual_uv_render")
            self._configure_scene(antialiasing)
            camera_data = self._new(bpy.data.cameras, "perceptual_uv_camera")
            self.camera_object = self._new(bpy.data.objects, "perceptual_uv_camera", camera_data)
            self.scene.collection.objects.link(self.camera_object)
            self.scene.camera = self.camera_object
        except Exception:
            self.close()
            raise

    # -- lifetime ---------------------------------------------------------------------------------------------
    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def close(self):
        """Remove every temporary data block and file; the renderer cannot be used afterwards."""
        collections = {bpy.types.Object: bpy.data.objects, bpy.types.Mesh: bpy.data.meshes,
                       bpy.types.Material: bpy.data.materials, bpy.types.Image: bpy.data.images,
                       bpy.types.Camera: bpy.data.cameras, bpy.types.Scene: bpy.data.scenes}
        for block in reversed(self._created):
            with contextlib.suppress(ReferenceError, KeyError):
                collections[type(block)].remove(block)
        self._created.clear()
        self._image_copies.clear()
        render_result = bpy.data.images.get("Render Result")
        if render_result is not None and not getattr(self, "_had_render_result", True):
            bpy.data.images.remove(render_result)
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None

    def _new(self, collection, name, *args, **kwargs):
        block = collection.new(name, *args, **kwargs)
        self._created.append(block)
        return block

    def _configure_scene(self, antialiasing):
        scene = self.scene
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.render.resolution_x, scene.render.resolution_y = self.width, self.height
        scene.render.resolution_percentage = 100
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
        scene.render.film_transparent = True
        scene.render.dither_intensity = 0.0  # dithering adds noise to every pixel
        scene.render.use_compositing = False
        scene.render.use_sequencer = False
        scene.render.image_settings.file_format = "PNG"
        scene.render.image_settings.color_mode = "RGBA"
        scene.render.image_settings.color_depth = "16"
        scene.render.image_settings.compression = 0
        scene.display.render_aa = antialiasing
        shading = scene.display.shading
        shading.light = "FLAT"
        shading.color_type = "TEXTURE"
        shading.show_cavity = shading.show_shadows = shading.show_object_outline = False
        shading.show_specular_highlight = shading.show_xray = shading.use_dof = False
        shading.show_backface_culling = False
        scene.display_settings.display_device = "sRGB"
        scene.view_settings.view_transform = "Raw" if self.texture_values == "stored" else "Standard"
        scene.view_settings.look = "None"
        scene.view_settings.exposure = 0.0
        scene.view_settings.gamma = 1.0
        scene.view_settings.use_curve_mapping = False

    # -- content ----------------------------------------------------------------------------------------------
    def _texture_image(self, image):
        """A private image showing ``image`` (a data block or an array) the way ``texture_values`` asks."""
        if isinstance(image, bpy.types.Image):
            key = image.name_full
            if key not in self._image_copies:
                if (image.source == "FILE" and not image.is_dirty and not image.is_float
                        and image.packed_file is None):
                    # a copy re-reads the 8-bit file: bytes stay bytes, no float buffer for a large atlas
                    copy = image.copy()
                    self._created.append(copy)
                    copy.colorspace_settings.name = "Non-Color" if self.texture_values == "stored" else "sRGB"
                    copy.alpha_mode = "NONE"
                else:
                    # generated, edited, packed or float images: copy() may regenerate or re-decode them, so
                    # go through the pixels Blender holds (what mesh_io.read_image gives core)
                    copy = self._texture_image(read_image(image))
                self._image_copies[key] = copy
            return self._image_copies[key]
        texture = np.asarray(image, dtype=np.float32)
        if texture.ndim == 2:
            texture = texture[..., None]
        if texture.ndim != 3 or texture.shape[2] not in (1, 3, 4) or min(texture.shape[:2]) == 0:
            raise ValueError(f"texture must have shape (h, w), (h, w, 1), (h, w, 3) or (h, w, 4), got "
                             f"{np.shape(image)}")
        if not np.isfinite(texture).all():
            raise ValueError("texture contains NaN or infinite values")
        height, width, channels = texture.shape
        rgba = np.ones((height, width, 4), dtype=np.float32)
        rgba[..., :3] = np.clip(texture[..., :3] if channels >= 3 else texture[..., :1], 0.0, 1.0)
        created = self._new(bpy.data.images, "perceptual_uv_texture", width, height, alpha=True,
                            float_buffer=True)
        if self.texture_values == "srgb":
            # float buffers hold linear light whatever their colour space says: decode sRGB here
            rgba[..., :3] = _srgb_to_linear(rgba[..., :3])
            created.colorspace_settings.name = "Linear Rec.709"
        else:
            created.colorspace_settings.name = "Non-Color"
        created.alpha_mode = "NONE"
        created.pixels.foreach_set(rgba.ravel())
        created.update()
        return created

    def _textured_material(self, image):
        material = self._new(bpy.data.materials, "perceptual_uv_render")
        if material.node_tree is None:  # Blender 4.x; from 5.0 every material has its node tree
            material.use_nodes = True
        tree = material.node_tree
        tree.nodes.clear()
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image, node.interpolation, node.extension = image, "Linear", "REPEAT"
        tree.nodes.active = node
        return material

    def _link_proxy(self, mesh, matrix_world):
        proxy = self._new(bpy.data.objects, "perceptual_uv_proxy", mesh)
        proxy.matrix_world = matrix_world.copy()
        self.scene.collection.objects.link(proxy)
        return proxy

    def add_object(self, obj, *, uv_name=None, image=None):
        """Show a copy of a mesh object, textured through one UV map.

        Parameters
        ----------
        obj : bpy.types.Object
            A mesh object; its original mesh (no modifiers) is drawn with its world transform.
        uv_name : str, optional
            UV map to texture with; the active one by default.
        image : bpy.types.Image or (h, w[, c]) array_like, optional
            Texture for every face. By default each material slot shows its own base-colour image
            (slots without one show their material's viewport colour).

        Returns
        -------
        bpy.types.Object
            The temporary proxy (removed on close).
        """
        if obj is None or obj.type != "MESH":
            raise ValueError(f"'{getattr(obj, 'name', obj)}' is not a mesh object")
        uv_layers = obj.data.uv_layers
        if uv_name is None:
            if uv_layers.active is None:
                raise ValueError(f"'{obj.name}' has no UV map")
            uv_name = uv_layers.active.name
        elif uv_name not in uv_layers:
            raise ValueError(f"'{obj.name}' has no UV map '{uv_name}'")
        mesh = self._new_mesh_copy(obj.data)
        # workbench textures through the active UV map; keeping only the one asked for removes any doubt
        for layer_name in [layer.name for layer in mesh.uv_layers if layer.name != uv_name]:
            mesh.uv_layers.remove(mesh.uv_layers[layer_name])
        mesh.uv_layers[uv_name].active = mesh.uv_layers[uv_name].active_render = True
        if image is not None:
            mesh.materials.clear()
            mesh.materials.append(self._textured_material(self._texture_image(image)))
        else:
            for index, slot in enumerate(obj.material_slots):
                node = base_color_image_node(slot.material)
                if node is not None:
                    mesh.materials[index] = self._textured_material(self._texture_image(node.image))
                else:
                    plain = self._new(bpy.data.materials, "perceptual_uv_plain")
                    if slot.material is not None:
                        plain.diffuse_color = slot.material.diffuse_color
                    mesh.materials[index] = plain
        return self._link_proxy(mesh, obj.matrix_world)

    def _new_mesh_copy(self, mesh):
        copy = mesh.copy()
        self._created.append(copy)
        return copy

    def add_arrays(self, V, F, uv, texture):
        """Show a triangle mesh given as arrays with one texture.

        Parameters
        ----------
        V : (n, 3) array_like of float
            World-space vertex positions.
        F : (m, 3) array_like of int
            Triangles.
        uv : (m, 3, 2) array_like of float
            Per-corner UVs.
        texture : bpy.types.Image or (h, w[, c]) array_like
            An image (copied, never modified) or texture values in [0, 1], row 0 at the bottom; one channel
            is grey, alpha is ignored.

        Returns
        -------
        bpy.types.Object
            The temporary proxy (removed on close).
        """
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F)
        uv = np.asarray(uv, dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3:
            raise ValueError(f"V must have shape (n, 3), got {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer) or len(F) == 0:
            raise ValueError(f"F must be a non-empty integer array of shape (m, 3), got {F.shape} {F.dtype}")
        if uv.shape != (len(F), 3, 2):
            raise ValueError(f"uv must have shape ({len(F)}, 3, 2), got {uv.shape}")
        if F.min() < 0 or F.max() >= len(V):
            raise ValueError(f"F indexes vertices outside [0, {len(V)})")
        if not (np.isfinite(V).all() and np.isfinite(uv).all()):
            raise ValueError("V or uv contains NaN or infinite values")
        mesh = self._new(bpy.data.meshes, "perceptual_uv_arrays")
        mesh.vertices.add(len(V))
        mesh.vertices.foreach_set("co", V.astype(np.float32).ravel())
        mesh.loops.add(3 * len(F))
        mesh.loops.foreach_set("vertex_index", F.astype(np.int32).ravel())
        mesh.polygons.add(len(F))
        mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(F), 3, dtype=np.int32))
        layer = mesh.uv_layers.new(name="UVMap")
        layer.uv.foreach_set("vector", uv.astype(np.float32).ravel())
        mesh.update(calc_edges=True)
        mesh.materials.append(self._textured_material(self._texture_image(texture)))
        return self._link_proxy(mesh, Matrix.Identity(4))

    # -- rendering --------------------------------------------------------------------------------------------
    def render(self, camera):
        """Render the proxies from one camera.

        Parameters
        ----------
        camera : Camera

        Returns
        -------
        (height, width, 4) float32 ndarray
            Display values in [0, 1], row 0 at the bottom; alpha 0 where nothing is drawn.
        """
        if self._folder is None:
            raise ValueError("the renderer is closed")
        if not isinstance(camera, Camera):
            raise ValueError(f"camera must be a Camera, got {type(camera).__name__}")
        data = self.camera_object.data
        if camera.ortho_scale is not None:
            data.type, data.ortho_scale = "ORTHO", float(camera.ortho_scale)
        else:
            data.type, data.sensor_fit = "PERSP", "AUTO"
            data.angle = np.radians(camera.fov_degrees)
        data.clip_start, data.clip_end = camera.clip_start, camera.clip_end
        data.shift_x = data.shift_y = 0.0
        self.camera_object.matrix_world = Matrix(camera_matrix(camera).tolist())
        path = os.path.join(self._folder.name, "view.png")
        self.scene.render.filepath = path
        with bpy.context.temp_override(scene=self.scene):
            bpy.ops.render.render(write_still=True, scene=self.scene.name)
        loaded = bpy.data.images.load(path, check_existing=False)
        try:
            loaded.colorspace_settings.name = "Non-Color"  # the file already holds display values
            pixels = read_image(loaded)
        finally:
            bpy.data.images.remove(loaded)
        return pixels.copy()
