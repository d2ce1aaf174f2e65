"""Packing with cardinal rotations only, and the Cycles bake between UV maps, on hand-made meshes."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge.bake import bake_base_color  # noqa: E402
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

    pack_uv_layer([obj], "Packed", margin_fraction=0.01, shape_method="AABB")

    after = read_uv(obj, "Packed")
    assert after.min() >= 0.0 and after.max() <= 1.0 + 1e-6
    scales = []
    for old, new in zip(before, after):
        # The linear part maps old edge vectors to new ones: it must be s * R(k pi/2), the same s for all islands.
        linear, *_ = np.linalg.lstsq(old[1:] - old[0], new[1:] - new[0], rcond=None)
        s = np.sqrt(abs(np.linalg.det(linear)))
        quarter_turns = [np.array([[1, 0], [0, 1]]), np.array([[0, 1], [-1, 0]]), -np.eye(2), np.array([[0, -1], [1, 0]])]
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
