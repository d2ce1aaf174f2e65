"""Packing with cardinal rotations only, and the Cycles bake between UV maps, on hand-made meshes and spot."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge.bake import bake_base_color  # noqa: E402
from perceptual_uv.bridge.cycles_bake import touched_tiles  # noqa: E402
from perceptual_uv.bridge.pack import pack_uv_layer  # noqa: E402

pytestmark = pytest.mark.bpy
ONE_STEP = 1 / 255 + 1e-6


def textured_quads(quads_uv, texture):
    """One object with a quad per entry of ``quads_uv`` ((4, 2) corner UVs each), textured by ``texture``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    verts, faces = [], []
    for index in range(len(quads_uv)):
        x = 2.0 * index
        base = len(verts)
        verts += [(x, 0, 0), (x + 1, 0, 0), (x + 1, 1, 0), (x, 1, 0)]
        faces.append((base, base + 1, base + 2, base + 3))
    mesh = bpy.data.meshes.new("quads")
    mesh.from_pydata(verts, [], faces)
    layer = mesh.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", np.concatenate(quads_uv).ravel())
    height, width = texture.shape[:2]
    image = bpy.data.images.new("source", width, height, alpha=True)
    image.pixels.foreach_set(texture.astype(np.float32).ravel())
    material = bpy.data.materials.new("textured")
    tree = material.node_tree
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    tree.links.new(node.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    mesh.materials.append(material)
    obj = bpy.data.objects.new("quads", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def read_uv(obj, name):
    uv = np.empty(2 * len(obj.data.loops))
    obj.data.uv_layers[name].uv.foreach_get("vector", uv)
    return uv.reshape(-1, 4, 2)


def checker_texture(size):
    rng = np.random.default_rng(7)
    rgba = np.ones((size, size, 4))
    rgba[..., :3] = rng.integers(0, 256, (size, size, 3)) / 255.0
    return rgba


def test_pack_uses_one_scale_and_quarter_turns_only():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    rotated = 0.1 * square @ np.array([[np.cos(0.3), np.sin(0.3)], [-np.sin(0.3), np.cos(0.3)]])
    obj = textured_quads([0.2 * square, rotated + 0.5, 0.05 * square * [4, 1] + 0.7], checker_texture(4))
    obj.data.uv_layers.new(name="Packed", do_init=True)
    before = read_uv(obj, "Packed")
    original = read_uv(obj, "UVMap")
    objects, meshes, scenes = len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.scenes)

    pack_uv_layer([obj], "Packed", margin=1, resolution=100)

    after = read_uv(obj, "Packed")
    assert after.min() >= 0.0 and after.max() <= 1.0 + 1e-6
    scales = []
    for old, new in zip(before, after):
        # The linear part maps old edge vectors to new ones: it must be s * R(k pi/2), the same s for all islands.
        linear, *_ = np.linalg.lstsq(old[1:] - old[0], new[1:] - new[0], rcond=None)
        s = np.sqrt(abs(np.linalg.det(linear)))
        quarter_turns = [np.array([[1, 0], [0, 1]]), np.array([[0, 1], [-1, 0]]), -np.eye(2),
                         np.array([[0, -1], [1, 0]])]
        assert min(np.abs(linear / s - turn).max() for turn in quarter_turns) < 1e-4
        scales.append(s)
    np.testing.assert_allclose(scales, scales[0], rtol=1e-4)
    np.testing.assert_array_equal(read_uv(obj, "UVMap"), original)
    assert obj.data.uv_layers.active.name == "UVMap"
    assert (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.scenes)) == (objects, meshes, scenes)


def test_bake_copies_texels_exactly_on_the_same_layout():
    texture = checker_texture(8)
    obj = textured_quads([np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)], texture)
    obj.data.uv_layers.new(name="Same", do_init=True)
    image = bake_base_color([obj], source_uv="UVMap", target_uv="Same", resolution=8, margin=2, image_name="baked")
    baked = np.empty(8 * 8 * 4, dtype=np.float32)
    image.pixels.foreach_get(baked)
    # Texel centres of the target sit on texel centres of the source: bilinear sampling returns the byte values,
    # up to one 8-bit step (Cycles' lookup position is off by ~1e-3 texel, which can round either way).
    np.testing.assert_allclose(baked.reshape(8, 8, 4)[..., :3], texture[..., :3], atol=ONE_STEP)
    assert image.colorspace_settings.name == "sRGB" and tuple(image.size) == (8, 8)


def test_bake_into_a_rectangle_copies_a_rectangular_source_on_the_same_layout():
    rng = np.random.default_rng(3)
    texture = np.ones((4, 8, 4))  # 8 columns, 4 rows
    texture[..., :3] = rng.integers(0, 256, (4, 8, 3)) / 255.0
    obj = textured_quads([np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)], texture)
    obj.data.uv_layers.new(name="Same", do_init=True)
    image = bake_base_color([obj], source_uv="UVMap", target_uv="Same", resolution=(8, 4), margin=2,
                            image_name="wide")
    assert tuple(image.size) == (8, 4)
    baked = np.empty(8 * 4 * 4, dtype=np.float32)
    image.pixels.foreach_get(baked)
    np.testing.assert_allclose(baked.reshape(4, 8, 4)[..., :3], texture[..., :3], atol=ONE_STEP)


def test_the_margin_of_a_rectangle_wraps_each_axis_at_its_own_length():
    from perceptual_uv.bridge.cycles_bake import extend_margin

    covered = np.zeros((3, 5), dtype=bool)  # 3 rows, 5 columns
    covered[0, 0] = True
    pixels = np.zeros((3, 5, 4), dtype=np.float32)
    pixels[0, 0] = 1.0
    extend_margin(pixels, covered, 1)
    # within one texel of (0, 0): its row neighbours (0, 1) and (0, 4) across the right edge, its column
    # neighbours (1, 0) and (2, 0) across the top; diagonals are sqrt(2) away
    filled = {(int(r), int(c)) for r, c in zip(*np.nonzero(pixels[..., 0]))}
    assert filled == {(0, 0), (0, 1), (0, 4), (1, 0), (2, 0)}


def test_objects_sharing_a_material_bake_from_one_copy_of_its_image(monkeypatch):
    from perceptual_uv.bridge import bake

    texture = checker_texture(9)
    strips = [np.array([[k / 3, 0], [(k + 1) / 3, 0], [(k + 1) / 3, 1], [k / 3, 1]]) for k in range(3)]
    first = textured_quads(strips[:1], texture)
    objects = [first]
    for k, strip in enumerate(strips[1:], start=1):  # two more objects with the first one's material
        mesh = bpy.data.meshes.new(f"strip{k}")
        mesh.from_pydata([(2.0 * k, 0, 0), (2.0 * k + 1, 0, 0), (2.0 * k + 1, 1, 0), (2.0 * k, 1, 0)], [],
                         [(0, 1, 2, 3)])
        mesh.uv_layers.new(name="UVMap").uv.foreach_set("vector", strip.ravel())
        mesh.materials.append(first.data.materials[0])
        obj = bpy.data.objects.new(f"strip{k}", mesh)
        bpy.context.scene.collection.objects.link(obj)
        objects.append(obj)
    for obj in objects:
        obj.data.uv_layers.new(name="Same", do_init=True)
    copies = []
    monkeypatch.setattr(bake, "_raw_copy", lambda image, _copy=bake._raw_copy: copies.append(image) or _copy(image))
    image = bake_base_color(objects, source_uv="UVMap", target_uv="Same", resolution=9, margin=2, image_name="b")
    assert len(copies) == 1  # one float copy of the shared image, not one per object
    baked = np.empty(9 * 9 * 4, dtype=np.float32)
    image.pixels.foreach_get(baked)
    # each strip is three texel columns wide: the three objects together cover every texel of the layout
    np.testing.assert_allclose(baked.reshape(9, 9, 4)[..., :3], texture[..., :3], atol=ONE_STEP)
    assert not [block for block in bpy.data.images if block.name.startswith("perceptual_uv_bake")]


def test_a_float_source_beyond_one_bakes_clipped_to_one():
    texture = np.ones((8, 8, 4))
    texture[..., :3] = [1.7, 0.25, 2.0]  # linear values beyond 1, as an EXR holds
    obj = textured_quads([np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)], texture)
    source = bpy.data.images.new("bright", 8, 8, alpha=True, float_buffer=True)
    source.pixels.foreach_set(texture.astype(np.float32).ravel())
    obj.data.materials[0].node_tree.nodes["Image Texture"].image = source
    obj.data.uv_layers.new(name="Same", do_init=True)
    image = bake_base_color([obj], source_uv="UVMap", target_uv="Same", resolution=8, margin=2, image_name="c")
    baked = np.empty(8 * 8 * 4, dtype=np.float32)
    image.pixels.foreach_get(baked)
    assert image.is_float
    np.testing.assert_allclose(baked.reshape(-1, 4)[:, :3], np.tile([1.0, 0.25, 1.0], (64, 1)), atol=1e-6)


def test_bake_through_a_quarter_turn_rotates_the_image():
    texture = checker_texture(8)
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    obj = textured_quads([square], texture)
    layer = obj.data.uv_layers.new(name="Turned")
    # Target (u, v) = (1 - v, u): a quarter turn counter-clockwise about the centre of the unit square.
    layer.uv.foreach_set("vector", np.stack([1 - square[:, 1], square[:, 0]], axis=1).ravel())
    image = bake_base_color([obj], source_uv="UVMap", target_uv="Turned", resolution=8, margin=2, image_name="t")
    baked = np.empty(8 * 8 * 4, dtype=np.float32)
    image.pixels.foreach_get(baked)
    baked = baked.reshape(8, 8, 4)[..., :3]
    # Target texel (row y, column x) shows source point (u, v) = (y', 1 - x') -> source row 7 - x, column y.
    expected = np.transpose(texture[::-1, :, :3], (1, 0, 2))
    np.testing.assert_allclose(baked, expected, atol=ONE_STEP)


def test_bake_leaves_scene_and_data_untouched():
    obj = textured_quads([np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)], checker_texture(4))
    obj.data.uv_layers.new(name="Copy", do_init=True)
    engine = bpy.context.scene.render.engine
    counts = {name: len(getattr(bpy.data, name)) for name in ("objects", "meshes", "materials", "images", "scenes")}
    source = bpy.data.images["source"]
    pixels = np.empty(len(source.pixels), dtype=np.float32)
    source.pixels.foreach_get(pixels)

    bake_base_color([obj], source_uv="UVMap", target_uv="Copy", resolution=4, margin=1, image_name="new")

    assert bpy.context.scene.render.engine == engine
    after = {name: len(getattr(bpy.data, name)) for name in counts}
    assert after == dict(counts, images=counts["images"] + 1)
    again = np.empty_like(pixels)
    source.pixels.foreach_get(again)
    np.testing.assert_array_equal(again, pixels)
    assert source.colorspace_settings.name == "sRGB"
    assert obj.material_slots[0].material.name == "textured"


def texel_centres_inside(triangle, resolution, *, eps=1e-3):
    """(rows, columns) of the texels whose centres lie strictly inside ``triangle`` ((3, 2) UVs, any tile)."""
    low = np.floor(triangle.min(axis=0) * resolution - 0.5).astype(int)
    high = np.ceil(triangle.max(axis=0) * resolution - 0.5).astype(int)
    columns, rows = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1))
    centres = (np.stack([columns.ravel(), rows.ravel()], axis=1) + 0.5) / resolution
    def cross(p, q):
        return p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]

    a, b, c = triangle
    area = cross(b - a, c - a)
    weights = np.stack([cross(c - b, centres - b), cross(a - c, centres - c), cross(b - a, centres - a)])
    inside = (weights / area > eps).all(axis=0) if area else np.zeros(len(centres), dtype=bool)
    return rows.ravel()[inside], columns.ravel()[inside]


def test_bake_writes_the_parts_of_spot_outside_the_unit_square_to_their_wrapped_texels(spot_obj):
    from perceptual_uv.bridge.material import base_color_image_node
    from perceptual_uv.bridge.mesh_io import import_model, read_mesh

    import_model(spot_obj)
    obj = next(obj for obj in bpy.context.scene.objects if obj.type == "MESH")
    uv_name = obj.data.uv_layers.active.name
    source = base_color_image_node(obj.material_slots[0].material).image
    resolution = source.size[0]
    triangles = read_mesh(obj, uv_name=uv_name).uv
    outside = (triangles.min(axis=(1, 2)) < 0) | (triangles.max(axis=(1, 2)) > 1)
    assert outside.sum() == 10  # spot: u down to -0.052, v up to 1.001

    # Where the triangles outside [0, 1]^2 land after wrapping (REPEAT), and which of those texels no triangle
    # covers in the unit square itself: without the tiles the bake left those at background.
    wrapped = np.zeros((resolution, resolution), dtype=bool)
    for triangle in triangles[outside]:
        rows, columns = texel_centres_inside(triangle, resolution)
        wrapped[rows % resolution, columns % resolution] = True
    unit = np.zeros_like(wrapped)  # generous at the edges, so only_wrapped errs towards fewer texels
    for triangle in triangles:
        rows, columns = texel_centres_inside(triangle, resolution, eps=-1e-3)
        keep = (rows >= 0) & (rows < resolution) & (columns >= 0) & (columns < resolution)
        unit[rows[keep], columns[keep]] = True
    only_wrapped = wrapped & ~unit
    assert only_wrapped.sum() > 500  # measured: 678 of the 2251 wrapped texels

    image = bake_base_color([obj], source_uv=uv_name, target_uv=uv_name, resolution=resolution, margin=2,
                            image_name="rebaked")
    baked = np.empty(resolution * resolution * 4, dtype=np.float32)
    image.pixels.foreach_get(baked)
    texture = np.empty(len(source.pixels), dtype=np.float32)
    source.pixels.foreach_get(texture)
    baked, texture = baked.reshape(resolution, resolution, 4), texture.reshape(resolution, resolution, -1)
    # Re-baking a map onto itself reads every texel centre back from the same source texel centre.
    assert texture[only_wrapped, :3].mean() > 0.2  # not black there, so background would fail the check
    np.testing.assert_allclose(baked[wrapped, :3], texture[wrapped, :3], atol=ONE_STEP)
    assert obj.data.uv_layers.keys() == [uv_name]


def test_bake_of_a_quad_in_tile_1_1_equals_the_same_quad_in_tile_0_0():
    rng = np.random.default_rng(3)
    texture = checker_texture(8)
    texture[..., 3] = rng.integers(64, 256, (8, 8)) / 255.0  # alpha < 1: the alpha bake goes through tiles too
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    obj = textured_quads([square], texture)
    inner = 0.25 + 0.5 * square
    for name, corners in (("Inside", inner), ("Shifted", inner + 1.0)):
        obj.data.uv_layers.new(name=name).uv.foreach_set("vector", corners.ravel())
    shifted = read_uv(obj, "Shifted")
    # A map in the unit square, even a float step past it, is baked once, as tile (0, 0); the shifted one as (1, 1).
    obj.data.uv_layers.new(name="Slop").uv.foreach_set("vector", (square * (1 + 1e-6)).ravel())
    assert [touched_tiles([obj], name, 16) for name in ("UVMap", "Slop", "Shifted")] == [[(0, 0)], [(0, 0)], [(1, 1)]]
    obj.data.uv_layers.remove(obj.data.uv_layers["Slop"])
    counts = {name: len(getattr(bpy.data, name)) for name in ("objects", "meshes", "materials", "images", "scenes")}

    def bake(name, margin):
        image = bake_base_color([obj], source_uv="UVMap", target_uv=name, resolution=16, margin=margin,
                                image_name=name)
        pixels = np.empty(16 * 16 * 4, dtype=np.float32)
        image.pixels.foreach_get(pixels)
        return pixels.reshape(16, 16, 4)

    inside, moved = bake("Inside", 0), bake("Shifted", 0)
    # the quad covers texels 4..11 in both directions
    assert inside[4:12, 4:12, :3].max() > 0.5 and inside[4:12, 4:12, 3].min() < 1.0
    np.testing.assert_array_equal(moved, inside)

    # With a margin, too, both maps give the same image.
    inside, moved = bake("Inside", 2), bake("Shifted", 2)
    np.testing.assert_array_equal(moved, inside)
    # Column 3 (texel centre 0.5 texel left of the quad's edge u = 0.25) is read by bilinear lookups on the quad
    # and holds the source value at the nearest edge point: source u = 0, i.e. halfway between source columns 7
    # (REPEAT) and 0, on source row i - 4 exactly (target row i's centre is source texel height i - 4 + 1/2).
    expected = 0.5 * (texture[0:8, 7] + texture[0:8, 0])
    np.testing.assert_allclose(moved[4:12, 3], expected, atol=ONE_STEP)
    # The corner texel (3, 3) is nearest to the quad's corner: source uv (0, 0), the mean of the four corner texels.
    corner = texture[[0, 0, 7, 7], [0, 7, 0, 7]].mean(axis=0)
    np.testing.assert_allclose(moved[3, 3], corner, atol=ONE_STEP)
    # Column 2 is out of the quad's reach (1.5 texels): the margin copies the nearest written texel, column 3.
    np.testing.assert_array_equal(moved[4:12, 2], moved[4:12, 3])
    assert not moved[[0, 15]].any()  # 2 past the footprint ring: background, black, alpha 0 from the alpha bake

    after = {name: len(getattr(bpy.data, name)) for name in counts}
    assert after == dict(counts, images=counts["images"] + 4)
    np.testing.assert_array_equal(read_uv(obj, "Shifted"), shifted)
    assert obj.data.uv_layers.keys() == ["UVMap", "Inside", "Shifted"]


def test_bake_refuses_a_map_spanning_too_many_tiles():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    obj = textured_quads([square], checker_texture(8))
    # 9 x 9 = 81 tiles: a texture repeated across a floor, say
    obj.data.uv_layers.new(name="Tiled").uv.foreach_set("vector", (9.0 * square).ravel())
    images = len(bpy.data.images)
    with pytest.raises(ValueError, match="spans 81 texture tiles"):
        bake_base_color([obj], source_uv="UVMap", target_uv="Tiled", resolution=16, margin=0, image_name="T")
    assert len(bpy.data.images) == images
