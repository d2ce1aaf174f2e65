# SPDX-License-Identifier: GPL-3.0-or-later
"""bridge.render: workbench renders of hand-made scenes against values computed here by hand."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge import mesh_io  # noqa: E402
from perceptual_uv.bridge.render import Camera, WorkbenchRenderer, camera_matrix  # noqa: E402

pytestmark = pytest.mark.bpy

# the unit square in the XY plane, UV = XY
SQUARE_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
SQUARE_UV = SQUARE_V[SQUARE_F][..., :2]
# looking down -Z at the square's centre, the square filling the 32 x 32 film exactly
TOP_VIEW = Camera(position=(0.5, 0.5, 5.0), look_at=(0.5, 0.5, 0.0), up=(0.0, 1.0, 0.0), ortho_scale=1.0)
FILM = 32


def _bytes_texture(seed, shape=(4, 4, 3)):
    values = np.random.default_rng(seed).integers(0, 256, size=shape)
    values[0, 0], values[0, 1] = 0, 255  # a black/white step: linear-light and stored-value blends differ
    return values / 255.0


def _bilinear_by_hand(texture, u, v):
    """Stored-value bilinear lookup, texel centres at (i + 0.5) / size, REPEAT."""
    h, w = texture.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    at = lambda yy, xx: texture[yy % h, xx % w]  # noqa: E731
    return ((1 - fx) * (1 - fy) * at(y0, x0) + fx * (1 - fy) * at(y0, x0 + 1)
            + (1 - fx) * fy * at(y0 + 1, x0) + fx * fy * at(y0 + 1, x0 + 1))


def _film_uv():
    """UV seen by each pixel centre of TOP_VIEW (row 0 = bottom): the square maps onto the film."""
    centres = (np.arange(FILM) + 0.5) / FILM
    return np.meshgrid(centres, centres)  # u varies along columns, v along rows


def test_camera_matrix_is_a_right_handed_look_at():
    matrix = camera_matrix(TOP_VIEW)
    np.testing.assert_allclose(matrix[:3, 0], [1, 0, 0])  # right
    np.testing.assert_allclose(matrix[:3, 1], [0, 1, 0])  # up
    np.testing.assert_allclose(matrix[:3, 2], [0, 0, 1])  # backward: the camera looks down -Z
    np.testing.assert_allclose(matrix[:3, 3], [0.5, 0.5, 5.0])
    with pytest.raises(ValueError, match="parallel"):
        Camera(position=(0, 0, 1), look_at=(0, 0, 0), up=(0, 0, 1))


def test_stored_values_reach_the_screen_bilinearly(empty_scene):
    texture = _bytes_texture(0)
    u, v = _film_uv()
    expected = _bilinear_by_hand(texture, u, v)
    with WorkbenchRenderer(width=FILM) as renderer:
        renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, texture)
        rendered = renderer.render(TOP_VIEW)
    assert rendered.shape == (FILM, FILM, 4) and rendered.dtype == np.float32
    np.testing.assert_array_equal(rendered[..., 3], 1.0)
    # half-float texture and 16-bit PNG: well under a byte
    assert np.abs(rendered[..., :3] - expected).max() < 0.5 / 255
    # the comparison can tell orientation: the film flipped either way is far off
    assert np.abs(rendered[::-1, :, :3] - expected).mean() > 20 / 255
    assert np.abs(rendered[:, ::-1, :3] - expected).mean() > 20 / 255


def test_srgb_mode_blends_in_linear_light_and_keeps_flat_colours(empty_scene):
    def to_linear(c):
        return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)

    def to_srgb(c):
        return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)

    texture = _bytes_texture(1)
    flat = np.full((2, 2, 3), [200 / 255, 30 / 255, 97 / 255])
    u, v = _film_uv()
    with WorkbenchRenderer(width=FILM, texture_values="srgb") as renderer:
        proxy = renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, texture)
        blended = renderer.render(TOP_VIEW)[..., :3]
        proxy.hide_render = True
        renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, flat)
        constant = renderer.render(TOP_VIEW)[..., :3]
    assert np.abs(blended - to_srgb(_bilinear_by_hand(to_linear(texture), u, v))).max() < 0.5 / 255
    assert np.abs(constant - flat[0, 0]).max() < 0.5 / 255  # 'Standard' view: a byte comes out unchanged


def test_add_object_uses_the_asked_uv_map_and_leaves_the_object_alone(empty_scene):
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.5, 0.5, 0.0))
    plane = bpy.context.active_object
    arrays = mesh_io.read_mesh(plane)
    # the primitive's UVs equal XY + 0.5 - location; make a second map that shows the texture mirrored in u
    mirrored = arrays.uv.copy()
    mirrored[..., 0] = 1.0 - mirrored[..., 0]
    mesh_io.write_uv_layer(plane, "Mirrored", mirrored, arrays.tri_loops)
    texture = _bytes_texture(2)
    image = bpy.data.images.new("user_image", 4, 4, alpha=True)
    image.pixels.foreach_set(np.concatenate([texture, np.ones((4, 4, 1))], axis=2).astype(np.float32).ravel())
    before = mesh_io.read_image(image).copy()
    names_before = {collection: set(getattr(bpy.data, collection).keys())
                    for collection in ("objects", "meshes", "materials", "images", "scenes", "cameras")}
    u, v = _film_uv()
    with WorkbenchRenderer(width=FILM) as renderer:
        renderer.add_object(plane, uv_name="Mirrored", image=image)
        rendered = renderer.render(TOP_VIEW)[..., :3]
    assert np.abs(rendered - _bilinear_by_hand(texture, 1.0 - u, v)).max() < 0.5 / 255
    assert np.array_equal(mesh_io.read_image(image), before)
    assert plane.data.uv_layers.active.name == "UVMap"
    for collection, names in names_before.items():
        assert set(getattr(bpy.data, collection).keys()) == names, collection


def test_invalid_arguments_raise_value_errors(empty_scene):
    with pytest.raises(ValueError, match="width"):
        WorkbenchRenderer(width=0)
    with pytest.raises(ValueError, match="texture_values"):
        WorkbenchRenderer(width=8, texture_values="linear")
    with WorkbenchRenderer(width=8) as renderer:
        with pytest.raises(ValueError, match="uv must have shape"):
            renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV[:1], np.zeros((2, 2)))
        with pytest.raises(ValueError, match="texture must have shape"):
            renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, np.zeros((2, 2, 2)))


def test_float_and_packed_images_show_the_values_blender_holds(empty_scene, tmp_path):
    """A float image goes through its pixels (as read_image gives them to core), a packed PNG too."""
    texture = _bytes_texture(3)
    u, v = _film_uv()
    expected = _bilinear_by_hand(texture, u, v)
    rgba = np.concatenate([texture, np.ones((4, 4, 1))], axis=2).astype(np.float32).ravel()
    float_image = bpy.data.images.new("float_user", 4, 4, alpha=True, float_buffer=True)
    float_image.pixels.foreach_set(rgba)
    byte_image = bpy.data.images.new("byte_user", 4, 4, alpha=True)
    byte_image.pixels.foreach_set(rgba)
    byte_image.filepath_raw = str(tmp_path / "texture.png")
    byte_image.file_format = "PNG"
    byte_image.save()
    packed = bpy.data.images.load(str(tmp_path / "texture.png"))
    packed.pack()
    with WorkbenchRenderer(width=FILM) as renderer:
        for image in (float_image, packed):
            proxy = renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, image)
            rendered = renderer.render(TOP_VIEW)[..., :3]
            proxy.hide_render = True
            assert np.abs(rendered - expected).max() < 0.5 / 255, image.name
    assert float_image.colorspace_settings.name == "Linear Rec.709" and packed.colorspace_settings.name == "sRGB"


def test_perspective_and_wide_film_follow_the_documented_geometry(empty_scene):
    texture = _bytes_texture(4)
    u, v = _film_uv()
    # a pinhole 5 units above the square with the square exactly filling the field of view: a plane seen
    # head-on is a scaled copy, so the picture equals the orthographic one
    fov = np.degrees(2 * np.arctan(0.5 / 5.0))
    pinhole = Camera(position=(0.5, 0.5, 5.0), look_at=(0.5, 0.5, 0.0), up=(0.0, 1.0, 0.0), fov_degrees=fov)
    with WorkbenchRenderer(width=FILM) as renderer:
        renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, texture)
        perspective = renderer.render(pinhole)
    assert np.abs(perspective[..., :3] - _bilinear_by_hand(texture, u, v)).max() < 1.0 / 255
    # a 2:1 film: the larger side (width) spans ortho_scale = 2 units, so the unit square covers the middle
    # half of the columns and every row
    wide = Camera(position=(0.5, 0.5, 5.0), look_at=(0.5, 0.5, 0.0), up=(0.0, 1.0, 0.0), ortho_scale=2.0)
    with WorkbenchRenderer(width=2 * FILM, height=FILM) as renderer:
        renderer.add_arrays(SQUARE_V, SQUARE_F, SQUARE_UV, texture)
        rendered = renderer.render(wide)
    assert rendered.shape == (FILM, 2 * FILM, 4)
    covered = rendered[..., 3] > 0.5
    assert covered[:, FILM // 2:3 * FILM // 2].all() and not covered[:, :FILM // 2].any()
    assert not covered[:, 3 * FILM // 2:].any()
    np.testing.assert_allclose(rendered[:, FILM // 2:3 * FILM // 2, :3], _bilinear_by_hand(texture, u, v),
                               atol=0.5 / 255)
