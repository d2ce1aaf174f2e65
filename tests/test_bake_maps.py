"""Every map of a material moves to the new UV map (issue 23, "Must show" items 3 and 4, Blender half).

A synthetic material with a base colour, a tangent-space normal map (Normal Map node), a packed
occlusion-roughness-metallic image (Separate Color, three channels) and an emissive map: after a run every map
has a new image of its own relative size, the material copy reads every one of them through the new UV map and no
node of it reads the old one, the packed image stays one image, and cancelling removes it all. The bakes on their
own: a data map re-baked on the same layout is exact within one 8-bit step, a tangent-space normal map is baked
into the new UV map's tangent frame, the texels next to its islands that Cycles leaves empty too. WaterBottle:
five texture slots in the .glb, every image new and sized as reported.
"""
import json
import pathlib

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge.bake import bake_maps  # noqa: E402
from perceptual_uv.bridge.material import read_material, read_object_materials  # noqa: E402
from perceptual_uv.bridge.material_roles import ROLES  # noqa: E402
from perceptual_uv.bridge.material_copy import map_scale, scaled_size  # noqa: E402
from perceptual_uv.bridge.pipeline import COPY_PROPERTY, optimize_objects, run_to_end  # noqa: E402
from perceptual_uv.core.settings import COST_ROLES, OptimizeSettings, role_cost  # noqa: E402

from conftest import reset_blender_scene  # noqa: E402  (tests/ is on sys.path under pytest)
from test_optimize_end_to_end import FAST  # noqa: E402
from test_robustness import textured_grid  # noqa: E402

pytestmark = pytest.mark.bpy
ONE_STEP = 1 / 255 + 1e-6
SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)


# --- building materials ------------------------------------------------------------------------------------

def new_image(name, size, rgb, *, data=True, alpha=None, float_buffer=False):
    image = bpy.data.images.new(name, size, size, alpha=alpha is not None, float_buffer=float_buffer)
    if data:
        image.colorspace_settings.name = "Non-Color"
    rgba = np.ones((size, size, 4), dtype=np.float32)
    rgba[..., :3] = rgb
    if alpha is not None:
        rgba[..., 3] = alpha
    image.pixels.foreach_set(rgba.ravel())
    return image


def add_normal_map(material, image):
    tree = material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    normal = tree.nodes.new("ShaderNodeNormalMap")
    tree.links.new(texture.outputs["Color"], normal.inputs["Color"])
    tree.links.new(normal.outputs["Normal"], tree.nodes["Principled BSDF"].inputs["Normal"])
    return texture


def add_orm(material, image):
    tree = material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    separate = tree.nodes.new("ShaderNodeSeparateColor")
    tree.links.new(texture.outputs["Color"], separate.inputs["Color"])
    principled = tree.nodes["Principled BSDF"]
    tree.links.new(separate.outputs["Green"], principled.inputs["Roughness"])
    tree.links.new(separate.outputs["Blue"], principled.inputs["Metallic"])
    # occlusion in the red channel, through the glTF importer's output group: three channels of one image
    group = bpy.data.node_groups.get("glTF Material Output")
    if group is None:
        group = bpy.data.node_groups.new("glTF Material Output", "ShaderNodeTree")
        group.interface.new_socket("Occlusion", in_out="INPUT", socket_type="NodeSocketFloat")
    output = tree.nodes.new("ShaderNodeGroup")
    output.node_tree = group
    tree.links.new(separate.outputs["Red"], output.inputs["Occlusion"])
    return texture


def add_emissive(material, image):
    tree = material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    principled = tree.nodes["Principled BSDF"]
    tree.links.new(texture.outputs["Color"], principled.inputs["Emission Color"])
    principled.inputs["Emission Strength"].default_value = 1.0
    return texture


def pbr_grid():
    """A 4 x 4 grid: 64 px base colour, 32 px normal map, 64 px packed ORM, 16 px emissive."""
    reset_blender_scene()
    obj = textured_grid("pbr", k=4, image_size=(64, 64))
    material = obj.material_slots[0].material
    rng = np.random.default_rng(5)
    tilt = np.stack([0.5 + 0.2 * rng.random((32, 32)), 0.5 + 0.2 * rng.random((32, 32)), np.ones((32, 32))], -1)
    add_normal_map(material, new_image("pbr_normal", 32, tilt))
    add_orm(material, new_image("pbr_orm", 64, rng.random((64, 64, 3))))
    add_emissive(material, new_image("pbr_emissive", 16, rng.random((16, 16, 3)), data=False))
    return obj


def quad(name="quad"):
    """One unit quad on the xy plane with UV maps "UVMap" (the unit square) and "Same" (a copy)."""
    reset_blender_scene()
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    mesh.uv_layers.new(name="UVMap").uv.foreach_set("vector", SQUARE.ravel())
    mesh.uv_layers.new(name="Same").uv.foreach_set("vector", SQUARE.ravel())
    mesh.uv_layers.active = mesh.uv_layers["UVMap"]
    material = bpy.data.materials.new(f"{name}_material")
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj, material


def pixels_of(image):
    pixels = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(image.size[1], image.size[0], -1)


def image_nodes(tree):
    for node in tree.nodes:
        if node.type == "GROUP" and node.node_tree is not None:
            yield from image_nodes(node.node_tree)
        elif node.type in ("TEX_IMAGE", "UVMAP", "NORMAL_MAP"):
            yield node


# --- the bakes on their own ------------------------------------------------------------------------------------

def test_a_packed_data_map_rebaked_on_the_same_layout_is_exact_and_stays_one_image():
    obj, material = quad()
    rng = np.random.default_rng(2)
    orm = rng.integers(0, 256, (8, 8, 3)) / 255.0
    add_orm(material, new_image("orm", 8, orm))
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    assert record.role == "metallic_roughness" and record.channels == "RGB"
    (result,) = bake_maps([obj], [record], source_uv="UVMap", target_uv="Same", resolutions=[8], margin=2,
                          names=["orm_new"])
    assert result.kind == "emit" and not result.alpha and not result.image.is_float
    assert result.image.colorspace_settings.name == "Non-Color" and tuple(result.image.size) == (8, 8)
    np.testing.assert_allclose(pixels_of(result.image)[..., :3], orm, atol=ONE_STEP)


def test_a_float_data_map_stays_float_and_a_base_colour_keeps_its_alpha():
    obj, material = quad()
    rng = np.random.default_rng(4)
    height = rng.random((8, 8, 3))
    tree = material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = new_image("height", 8, height, float_buffer=True)
    bump = tree.nodes.new("ShaderNodeBump")
    tree.links.new(texture.outputs["Color"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], tree.nodes["Principled BSDF"].inputs["Normal"])
    colour = tree.nodes.new("ShaderNodeTexImage")
    alpha = rng.integers(64, 256, (8, 8)) / 255.0
    colour.image = new_image("colour", 8, rng.integers(0, 256, (8, 8, 3)) / 255.0, data=False, alpha=alpha)
    tree.links.new(colour.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    tree.links.new(colour.outputs["Alpha"], tree.nodes["Principled BSDF"].inputs["Alpha"])
    records = {record.role: record for record in read_object_materials(obj, source_uv="UVMap")[0].maps}
    assert set(records) == {"base_color", "data"}
    results = bake_maps([obj], [records["data"], records["base_color"]], source_uv="UVMap", target_uv="Same",
                        resolutions=[8, 8], margin=1, names=["h", "c"])
    data, base = results
    assert data.image.is_float and data.image.colorspace_settings.name == "Non-Color"
    # Cycles' lookup sits ~1e-3 texel off the texel centre: a float map shows that bilinear mix, < one 8-bit step
    np.testing.assert_allclose(pixels_of(data.image)[..., :3], height, atol=ONE_STEP)
    assert base.alpha and base.image.colorspace_settings.name == "sRGB"
    np.testing.assert_allclose(pixels_of(base.image)[..., 3], alpha, atol=ONE_STEP)


def normal_quad(value, target_corners):
    obj, material = quad("normal")
    obj.data.uv_layers["Same"].uv.foreach_set("vector", np.asarray(target_corners, dtype=float).ravel())
    add_normal_map(material, new_image("normal", 8, value))
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    assert record.role == "normal_tangent"
    (result,) = bake_maps([obj], [record], source_uv="UVMap", target_uv="Same", resolutions=[8], margin=1,
                          names=["normal_new"])
    assert result.kind == "normal" and result.image.colorspace_settings.name == "Non-Color"
    return pixels_of(result.image)[..., :3]


def test_a_flat_normal_map_bakes_flat_on_the_same_layout():
    baked = normal_quad((0.5, 0.5, 1.0), SQUARE)
    np.testing.assert_allclose(baked, np.broadcast_to((0.5, 0.5, 1.0), baked.shape), atol=2 / 255)


def test_a_normal_map_is_baked_into_the_tangent_frame_of_the_new_uv_map():
    # (0.8, 0.5, 0.9) is the unit normal (0.6, 0, 0.8): tilted along the source tangent, +x on this quad.
    np.testing.assert_allclose(normal_quad((0.8, 0.5, 0.9), SQUARE), np.broadcast_to((0.8, 0.5, 0.9), (8, 8, 3)),
                               atol=2 / 255)
    # Target (u, v) = (1 - y, x): its tangent is -y and its bitangent +x, so the tilt moves to the green channel.
    turned = np.stack([1 - SQUARE[:, 1], SQUARE[:, 0]], axis=1)
    np.testing.assert_allclose(normal_quad((0.8, 0.5, 0.9), turned), np.broadcast_to((0.5, 0.8, 0.9), (8, 8, 3)),
                               atol=2 / 255)


# Two unit quads side by side on the xy plane, sharing the edge x = 1, cut apart in UV: island A (x in [0, 1])
# and island B (x in [1, 2]), rectangles whose edges lie between texel centres of a 16 px map, 2.4 texels apart.
SEAM_SIZE = 16
SEAM_ISLANDS = {"A": ((2.3, 7.3), (3.3, 12.7)), "B": ((9.7, 14.2), (3.3, 12.7))}  # (u range, v range) in texels


def ramp_normal(u, v):
    """The unit normal c = (1.4 (u - 1/2), 1.4 (v - 1/2), sqrt(1 - x^2 - y^2)) in the quads' tangent frame (+x, +y,
    +z) at source UV (u, v): linear in u and v in its first two channels, so a bilinear lookup gives them exactly."""
    x, y = 1.4 * (np.asarray(u) - 0.5), 1.4 * (np.asarray(v) - 0.5)
    return np.stack([x, y, np.sqrt(1 - x * x - y * y)], axis=-1)


def turn(uv):
    """A quarter turn of UVs: (u, v) -> (1 - v, u); on the quads its tangent is -y and its bitangent +x."""
    return np.stack([1 - uv[..., 1], uv[..., 0]], axis=-1)


def seam_quads(turned):
    reset_blender_scene()
    mesh = bpy.data.meshes.new("seam")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)], [],
                     [(0, 1, 4, 3), (1, 2, 5, 4)])
    corners = []
    for (u0, u1), (v0, v1) in SEAM_ISLANDS.values():
        corners += [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]  # the quads' corners, counter-clockwise from (x0, 0)
    source = np.array(corners) / SEAM_SIZE
    mesh.uv_layers.new(name="UVMap").uv.foreach_set("vector", source.ravel())
    mesh.uv_layers.new(name="Target").uv.foreach_set("vector", (turn(source) if turned else source).ravel())
    mesh.uv_layers.active = mesh.uv_layers["UVMap"]
    material = bpy.data.materials.new("seam_material")
    mesh.materials.append(material)
    obj = bpy.data.objects.new("seam", mesh)
    bpy.context.scene.collection.objects.link(obj)
    centres = (np.arange(SEAM_SIZE) + 0.5) / SEAM_SIZE
    u, v = np.meshgrid(centres, centres)  # row i at v = (i + 1/2) / 16
    add_normal_map(material, new_image("ramp", SEAM_SIZE, 0.5 * ramp_normal(u, v) + 0.5))
    return obj


@pytest.mark.parametrize("turned", [False, True], ids=["same_layout", "turned_layout"])
def test_seam_texels_of_a_normal_map_hold_the_source_normal_in_the_new_frame(turned):
    """Texels next to an island that Cycles leaves empty (their centres lie outside every triangle) hold the
    source normal at the island's nearest point, in the new UV map's frame, not a neighbour's copy."""
    obj = seam_quads(turned)
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    (result,) = bake_maps([obj], [record], source_uv="UVMap", target_uv="Target", resolutions=[SEAM_SIZE],
                          margin=2, names=["seam_new"])
    baked = pixels_of(result.image)[..., :3]
    rows, columns = np.mgrid[0:SEAM_SIZE, 0:SEAM_SIZE]
    centre = np.stack([columns + 0.5, rows + 0.5], axis=-1)  # texel space of the target map
    checked = 0
    for (u0, u1), (v0, v1) in SEAM_ISLANDS.values():
        low, high = np.array([u0, v0]), np.array([u1, v1])
        if turned:  # the island's target rectangle
            low, high = np.array([SEAM_SIZE - v1, u0]), np.array([SEAM_SIZE - v0, u1])
        nearest = np.clip(centre, low, high)
        distance = np.abs(nearest - centre).max(axis=-1)
        border = (distance > 0) & (distance < 1)  # outside the island, read by a bilinear lookup on it
        source = turn(turn(turn(nearest / SEAM_SIZE))) if turned else nearest / SEAM_SIZE  # back onto UVMap
        c = ramp_normal(source[..., 0], source[..., 1])
        # the quarter-turned frame (T, B, N) = (-y, +x, +z): c's coordinates (-c_y, c_x, c_z)
        expected = 0.5 * (np.stack([-c[..., 1], c[..., 0], c[..., 2]], axis=-1) if turned else c) + 0.5
        np.testing.assert_allclose(baked[border], expected[border], atol=2 / 255)
        checked += border.sum()
    # A: 7 x 12 texels around its 5 x 10 covered ones; B: 6 x 12 around 4 x 10 (either layout)
    assert checked == (84 - 50) + (72 - 40)


def test_the_seam_conversion_gives_what_cycles_writes_inside_the_triangles():
    """The conversion that fills seam texels (``bake_normal.normal_values``), applied where Cycles itself wrote:
    a sphere with flat and smooth faces, a random normal map, baked onto a mirrored quarter turn of its UV map.
    Measured: within 0.24 8-bit steps; with Blender's corner normals and tangents on Cycles' side too, 25."""
    from perceptual_uv.bridge.bake_normal import bake_tangent_normal, normal_values
    from perceptual_uv.bridge.mesh_io import read_mesh

    reset_blender_scene()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    obj = bpy.context.object
    for polygon in obj.data.polygons:
        polygon.use_smooth = polygon.index % 3 != 0
    uv = np.empty(2 * len(obj.data.loops))
    obj.data.uv_layers["UVMap"].uv.foreach_get("vector", uv)
    u, v = uv.reshape(-1, 2).T
    obj.data.uv_layers.new(name="Target").uv.foreach_set("vector", (0.05 + 0.9 * np.stack([1 - v, 1 - u], 1)).ravel())
    material = bpy.data.materials.new("sphere_material")
    obj.data.materials.append(material)
    rng = np.random.default_rng(3)
    c = np.kron(rng.normal(size=(8, 8, 3)) * (0.3, 0.3, 0.2) + (0, 0, 1), np.ones((4, 4, 1)))
    c /= np.linalg.norm(c, axis=2, keepdims=True)
    add_normal_map(material, new_image("sphere_normal", 32, 0.5 * c + 0.5))
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    size = 64
    pixels = bake_tangent_normal([obj], record, source_uv="UVMap", target_uv="Target", resolution=size, margin=0,
                                 tiles=[(0, 0)])
    # texel centres strictly inside a target triangle: Cycles wrote those
    mesh = read_mesh(obj, uv_name="Target")
    corners = mesh.uv * size
    rows, columns = np.mgrid[0:size, 0:size]
    centre = np.stack([columns.ravel() + 0.5, rows.ravel() + 0.5], axis=1)
    a, b, d = corners[:, 0], corners[:, 1], corners[:, 2]
    area = np.cross(b - a, d - a)
    live = np.abs(area) > 1e-9
    s = np.cross((b - a)[None], centre[:, None] - a[None]) / np.where(live, area, 1)[None]
    t = np.cross(centre[:, None] - a[None], (d - a)[None]) / np.where(live, area, 1)[None]
    bary = np.stack([1 - s - t, t, s], axis=-1)  # weights of a, b, d
    inside = live[None] & (bary > 1e-3).all(axis=-1)
    texel, face = np.nonzero(inside)
    assert len(np.unique(texel)) == len(texel) > 1000  # no overlaps; most of the map
    values, known = normal_values(obj, record, mesh, face, bary[texel, face], source_uv="UVMap", target_uv="Target")
    assert known.all()
    baked = pixels.reshape(-1, 4)[texel, :3]
    assert np.abs(values - baked).max() < 0.5 / 255


def test_a_fold_of_the_surface_bakes_the_normal_the_material_shows():
    """A 4 x 4 smooth grid with one triangle wound the other way (its geometric normal -z against corner normals
    near +z, like Avocado's triangle #550) and a constant normal map, baked on a copy of its UV map: the frame is
    the same, so every texel holds the source value. Cycles alone writes the negated normal on the fold:
    measured (0.20, 0.50, 0.10) against the source's (0.8, 0.5, 0.9)."""
    from perceptual_uv.bridge.bake_normal import bake_tangent_normal

    reset_blender_scene()
    k, size = 4, 32
    vertices = [(i / k, j / k, 0.0) for j in range(k + 1) for i in range(k + 1)]
    faces = []
    for j in range(k):
        for i in range(k):
            a, b, c, d = j * (k + 1) + i, j * (k + 1) + i + 1, (j + 1) * (k + 1) + i + 1, (j + 1) * (k + 1) + i
            faces += [(a, b, c), (a, c, d)]
    fold = 2 * (k + 1)  # the first triangle of the inner quad (1, 1)
    faces[fold] = faces[fold][::-1]
    mesh = bpy.data.meshes.new("fold")
    mesh.from_pydata(vertices, [], faces)
    for polygon in mesh.polygons:
        polygon.use_smooth = True
    uv = np.array([vertices[vertex][:2] for face in faces for vertex in face])
    mesh.uv_layers.new(name="UVMap").uv.foreach_set("vector", uv.ravel())
    mesh.uv_layers.new(name="Same").uv.foreach_set("vector", uv.ravel())
    mesh.uv_layers.active = mesh.uv_layers["UVMap"]
    material = bpy.data.materials.new("fold_material")
    mesh.materials.append(material)
    obj = bpy.data.objects.new("fold", mesh)
    bpy.context.scene.collection.objects.link(obj)
    add_normal_map(material, new_image("fold_normal", 16, (0.8, 0.5, 0.9)))
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    pixels = bake_tangent_normal([obj], record, source_uv="UVMap", target_uv="Same", resolution=size, margin=0,
                                 tiles=[(0, 0)])
    # the fold covers the texel centres (x, y) with 8 < y < x < 16 in texels (its corners (8, 8), (16, 16), (16, 8))
    np.testing.assert_allclose(pixels[11, 13, :3], (0.8, 0.5, 0.9), atol=2 / 255)
    np.testing.assert_allclose(pixels[..., :3], np.broadcast_to((0.8, 0.5, 0.9), (size, size, 3)), atol=2 / 255)


# --- sizes ---------------------------------------------------------------------------------------------------

def test_each_map_keeps_its_size_relative_to_its_input():
    assert scaled_size((300, 300), map_scale(1024, 2048)) == (150, 150)
    assert scaled_size((300, 300), map_scale(2048, 2048)) == (300, 300)
    assert scaled_size((20, 20), map_scale(64, 2048)) == (8, 8)  # at least 8 px
    # an override of 0.075 against a measured 0.3: half the side
    assert scaled_size((300, 300), map_scale(1024, 2048, role_cost=0.075, reference_cost=0.3)) == (75, 75)
    assert scaled_size((300, 200), map_scale(1024, 2048)) == (150, 100)  # a rectangle keeps its shape
    assert role_cost((("normal", 0.2),), "normal_tangent") == 0.2
    assert role_cost((("normal", 0.2), ("normal_tangent", 0.1)), "normal_tangent") == 0.1
    assert role_cost((("normal", 0.2),), "base_color") is None
    assert set(COST_ROLES) == set(ROLES) | {"normal"}
    with pytest.raises(ValueError, match="unknown role"):
        OptimizeSettings(role_costs=(("normals", 0.2),))
    with pytest.raises(ValueError, match=r"must be in \(0, 4\]"):
        OptimizeSettings(role_costs=(("normal", 0.0),))


def test_with_the_cost_in_memory_each_map_gets_that_share_of_its_own_pixels():
    from types import SimpleNamespace

    from perceptual_uv.bridge.material_copy import memory_resolution
    from perceptual_uv.bridge.pipeline import _memory_side

    def record(role, width, height=None):
        return SimpleNamespace(role=role, image=SimpleNamespace(size=(width, height or width), source="GENERATED"))

    quarter = OptimizeSettings(target_cost=0.25)
    # a 1k normal map beside a 2k base colour at a quarter of the memory: each keeps half its side
    assert _memory_side(record("base_color", 2048), quarter) == 1024
    assert _memory_side(record("normal_tangent", 1024), quarter) == 512
    # normal maps at a sixteenth: a quarter of the side; the other maps keep the run's cost
    override = OptimizeSettings(target_cost=0.25, role_costs=(("normal", 0.0625),))
    assert _memory_side(record("normal_tangent", 1024), override) == 256
    assert _memory_side(record("base_color", 2048), override) == 1024
    assert _memory_side(record("base_color", 64, 32), quarter) == 23  # sqrt(0.25 * 64 * 32) = 22.63
    assert _memory_side(record("emissive", 64), OptimizeSettings(target_cost=0.01)) == 8  # 6.4: at least 8
    assert memory_resolution((1024, 1024), 0.3) == 561  # sqrt(0.3) * 1024 = 560.87
    assert memory_resolution((16384, 16384), 4) == 16384  # 32768: at most 16384
    with pytest.raises(ValueError, match="positive"):
        memory_resolution((64, 64), 0)


# --- the whole run -------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def pbr_run():
    obj = pbr_grid()
    images_before = {image.name for image in bpy.data.images}
    result = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))
    return obj, result, images_before


def test_every_map_gets_a_new_image_of_its_relative_size(pbr_run):
    obj, result, images_before = pbr_run
    report = result.report
    width, height = report["resolution"]
    maps = {entry["role"]: entry for entry in report["maps"]}
    assert set(maps) == {"base_color", "normal_tangent", "metallic_roughness", "emissive"}
    # at 0.3 of the memory the 64, 32 and 16 px maps get sides round(sqrt(0.3) x): 35, 18 (17.5) and 9 (8.8); the
    # base colour's image takes the packing's shape, holding at most 35 x 35 pixels, and every map that shape
    assert width * height <= 35 * 35 and maps["base_color"]["new_size"] == [width, height]
    sides = {"base_color": 35, "metallic_roughness": 35, "normal_tangent": 18, "emissive": 9}
    for role, side in sides.items():
        expected = [max(8, round(width * side / 35)), max(8, round(height * side / 35))]
        assert maps[role]["new_size"] == expected, role
        assert maps[role]["new_image"] not in images_before
    assert len(result.images) == 4 and result.images[0] == result.image
    assert [image.name for image in result.images] == [entry["new_image"] for entry in report["maps"]]
    assert maps["normal_tangent"]["input_size"] == [32, 32] and maps["emissive"]["input_size"] == [16, 16]
    before = sum(entry["raw_bytes_before"] for entry in report["maps"])
    after = sum(entry["raw_bytes_after"] for entry in report["maps"])
    assert report["memory_ratio"] == pytest.approx(after / before)
    assert maps["metallic_roughness"]["raw_bytes_before"] == 64 * 64 * 3


def test_the_copy_reads_every_new_image_through_the_new_uv_map(pbr_run):
    obj, result, _ = pbr_run
    uv_name = result.uv_map
    (copy,) = result.materials
    assert obj.material_slots[0].material == copy and copy[COPY_PROPERTY] == "pbr_material"
    nodes = list(image_nodes(copy.node_tree))
    textures = [node for node in nodes if node.type == "TEX_IMAGE"]
    assert {node.image for node in textures} == set(result.images)  # the ORM is one image, one node
    for node in textures:
        (link,) = node.inputs["Vector"].links
        assert link.from_node.type == "UVMAP" and link.from_node.uv_map == uv_name
    assert all(node.uv_map == uv_name for node in nodes if node.type in ("UVMAP", "NORMAL_MAP"))
    # read through the old UV map, the copy has nothing left to move; through the new one, every map
    assert not read_material(copy, source_uv="UVMap", render_uv="UVMap").maps
    roles = {record.role for record in read_material(copy, source_uv=uv_name, render_uv="UVMap").maps}
    assert roles == {"base_color", "normal_tangent", "metallic_roughness", "emissive"}
    # the original material and its images are untouched
    original = bpy.data.materials["pbr_material"]
    assert {node.image.name for node in original.node_tree.nodes if node.type == "TEX_IMAGE"} == {
        "pbr_texture", "pbr_normal", "pbr_orm", "pbr_emissive"}


def test_a_second_run_optimizes_what_the_copy_shows(pbr_run):
    obj, first, _ = pbr_run
    with pytest.raises(ValueError, match=f"Make '{first.uv_map}' the active UV map"):
        run_to_end(optimize_objects([obj], OptimizeSettings(**FAST), source_uv="UVMap"))
    second = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))
    assert second.report["source_uv_map"] == first.uv_map and second.uv_map != first.uv_map
    assert {entry["image"] for entry in second.report["maps"]} == {image.name for image in first.images}
    (copy,) = second.materials
    assert copy[COPY_PROPERTY] == "pbr_material" and copy.name.startswith("pbr_material_perceptual")
    assert {node.image for node in image_nodes(copy.node_tree) if node.type == "TEX_IMAGE"} == set(second.images)
    assert not read_material(copy, source_uv=first.uv_map, render_uv="UVMap").maps


def test_a_memory_cost_sizes_every_map_from_its_own_pixels():
    """Cost 0.25 as image memory: the 64 px base colour and ORM and the 32 and 16 px normal and emissive maps
    each keep half their side, so the material's memory is a quarter of the input's; normal maps at 0.0625 keep a
    quarter of theirs."""
    sides = {}
    for role_costs in ((), (("normal", 0.0625),)):
        settings = OptimizeSettings(**dict(FAST, target_cost=0.25, cost_measure="memory", role_costs=role_costs,
                                           square_images=True))
        report = run_to_end(optimize_objects([pbr_grid()], settings)).report
        assert report["cost_measure"] == "memory" and report["resolution"] == [32, 32]
        sides[role_costs] = {entry["role"]: entry["new_size"] for entry in report["maps"]}
        if not role_costs:
            assert report["memory_ratio"] == pytest.approx(0.25, rel=1e-12)
        for entry in report["maps"]:
            share = (entry["new_size"][0] / entry["input_size"][0]) ** 2
            assert entry["raw_bytes_after"] == pytest.approx(share * entry["raw_bytes_before"], rel=1e-12)
    assert sides[()] == {"base_color": [32, 32], "metallic_roughness": [32, 32], "normal_tangent": [16, 16],
                         "emissive": [8, 8]}
    assert sides[(("normal", 0.0625),)] == dict(sides[()], normal_tangent=[8, 8])


def test_a_cancelled_run_removes_every_image_material_and_group():
    obj = pbr_grid()
    counts = {kind: len(getattr(bpy.data, kind)) for kind in ("images", "materials", "node_groups")}
    run = optimize_objects([obj], OptimizeSettings(**FAST))
    for progress in run:
        if progress.stage == "loss":
            break
    assert len(bpy.data.images) == counts["images"] + 4
    run.close()
    assert {kind: len(getattr(bpy.data, kind)) for kind in counts} == counts
    assert obj.material_slots[0].material.name == "pbr_material"


def test_a_map_without_pixels_is_refused_before_the_run(tmp_path):
    obj = pbr_grid()
    broken = bpy.data.images.new("normal.png", 4, 4)
    broken.source = "FILE"
    broken.filepath = str(tmp_path / "normal.png")
    broken.reload()
    node = next(node for node in obj.material_slots[0].material.node_tree.nodes
                if node.type == "TEX_IMAGE" and node.image.name == "pbr_normal")
    node.image = broken
    layers = obj.data.uv_layers.keys()
    with pytest.raises(ValueError, match="normal_tangent map 'normal.png'.*has no pixels") as refused:
        run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))
    assert str(tmp_path / "normal.png") in str(refused.value)
    assert obj.data.uv_layers.keys() == layers


def test_a_tiled_map_is_refused_before_the_run():
    obj = pbr_grid()
    node = next(node for node in obj.material_slots[0].material.node_tree.nodes
                if node.type == "TEX_IMAGE" and node.image.name == "pbr_orm")
    node.image = bpy.data.images.new("udim", 16, 16, tiled=True)
    images, layers = len(bpy.data.images), obj.data.uv_layers.keys()
    with pytest.raises(ValueError, match="map 'udim' of material 'pbr_material' is a UDIM tiled image"):
        run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))
    assert obj.data.uv_layers.keys() == layers and len(bpy.data.images) == images


# --- WaterBottle ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def waterbottle_glb(shared_models_dir, tmp_path_factory):
    """WaterBottle optimized at fast settings (the default cost: 0.3 of the image memory) into a .glb, with its
    report."""
    from test_gltf_export import FAST_ARGS, run_cli

    model = shared_models_dir / "WaterBottle" / "WaterBottle.gltf"
    if not model.is_file():
        pytest.skip(f"{model} is absent")
    folder = tmp_path_factory.mktemp("waterbottle")
    out, report_path = folder / "wb.glb", folder / "report.json"
    result = run_cli("optimize", str(model), "--out", str(out), "--report", str(report_path), *FAST_ARGS)
    assert result.returncode == 0, result.stderr[-3000:]
    return model, out, json.loads(report_path.read_text())


@pytest.mark.slow
def test_waterbottle_glb_has_five_texture_slots_with_new_images(waterbottle_glb):
    import gltf_validate
    from test_gltf_export import buffer_view_bytes, image_size, read_glb

    _, out, report = waterbottle_glb
    gltf, binary = read_glb(out)
    (material,) = gltf["materials"]
    pbr = material["pbrMetallicRoughness"]
    slots = {"baseColorTexture": pbr.get("baseColorTexture"), "metallicRoughnessTexture":
             pbr.get("metallicRoughnessTexture"), "normalTexture": material.get("normalTexture"),
             "occlusionTexture": material.get("occlusionTexture"), "emissiveTexture": material.get("emissiveTexture")}
    assert all(slots.values()), slots
    sizes = {entry["new_image"]: tuple(entry["new_size"]) for entry in report["maps"]}
    assert len(sizes) == 4  # base colour, normal, emissive, and one occlusion-roughness-metallic image
    for slot in slots.values():
        assert slot.get("texCoord", 0) == 0
        image = gltf["images"][gltf["textures"][slot["index"]]["source"]]
        data, _ = buffer_view_bytes(gltf, binary, image["bufferView"])
        assert image["name"] in sizes and image_size(data) == sizes[image["name"]]
    orm = {slots[name]["index"] for name in ("metallicRoughnessTexture", "occlusionTexture")}
    assert len({gltf["textures"][index]["source"] for index in orm}) == 1
    inputs = {entry["image"] for entry in report["maps"]}
    assert not inputs & set(sizes)
    assert 0 < report["memory_ratio"] < 1
    reason = gltf_validate.unavailable()
    if not reason:
        assert gltf_validate.validate(out)["errors"] == 0
    print("WaterBottle", json.dumps({"memory_ratio": report["memory_ratio"], "file_ratio": report["file_ratio"],
                                     "maps": [(e["role"], e["input_size"], e["new_size"], e["raw_bytes_before"],
                                               e["raw_bytes_after"], e["file_bytes_before"], e["file_bytes_after"])
                                              for e in report["maps"]], "times": report["times_s"]}))


SHADED_PIXELS = 256
ROUND_TRIP_FLOOR = 1e-5
"""Shaded q between the .glb's views and the views of the same run in Blender is below this (measured: see the
test)."""


@pytest.mark.slow
def test_waterbottle_shaded_views_of_the_glb_are_those_of_the_result_in_blender(shared_models_dir, tmp_path):
    """WaterBottle optimized at fast settings in Blender, then exported to .glb and imported again as a viewer
    gets it: the same 20 views of its whole material (Cycles, the shaded evaluation's lights and seed) show the
    same thing as the result in Blender (UV map, every new image, the tangent frame of the normal map). The
    figures against the input and the uniform downscale at the same memory are printed (docs/results/README.md,
    "Shaded evaluation", has them)."""
    from perceptual_uv.bridge.batch import textured_objects
    from perceptual_uv.bridge.evaluate import _dodecahedron_views, mesh_arrays
    from perceptual_uv.bridge.evaluate_shaded import evaluate_shaded, shaded_reference, shaded_views
    from perceptual_uv.bridge.gltf_export import export_glb
    from perceptual_uv.bridge.mesh_io import import_model
    from perceptual_uv.core.evaluation import perceptual_loss_of_views

    model = shared_models_dir / "WaterBottle" / "WaterBottle.gltf"
    if not model.is_file():
        pytest.skip(f"{model} is absent")
    reset_blender_scene()
    import_model(model)
    objects = textured_objects()
    uv = objects[0].data.uv_layers.active.name
    reference = shaded_reference(objects, uv, screen_pixels=SHADED_PIXELS)
    cameras = _dodecahedron_views(mesh_arrays(objects, uv)[0])
    # the uniform downscale at the run's cost, image memory: each map round(sqrt(0.3 w h)) on a side, as the run's
    downscale = evaluate_shaded(objects, uv, reference_uv=uv, costs=(FAST["target_cost"],), sizing="memory",
                                screen_pixels=SHADED_PIXELS, reference=reference)["points"][0]
    # square images: the downscale's sides exactly (a rectangle keeps to at most the square's pixels)
    result = run_to_end(optimize_objects(objects, OptimizeSettings(**dict(FAST, square_images=True))))
    assert result.report["memory_ratio"] == pytest.approx(downscale["memory_ratio"], rel=1e-9)
    in_blender = shaded_views(objects, cameras, screen_pixels=SHADED_PIXELS)
    out = tmp_path / "wb.glb"
    export_glb([(objects, result)], out)
    reset_blender_scene()
    import_model(out)
    exported = textured_objects()
    assert [len(obj.data.uv_layers) for obj in exported] == [1]  # TEXCOORD_0, the new UV map
    views = shaded_views(exported, cameras, screen_pixels=SHADED_PIXELS)
    round_trip = perceptual_loss_of_views(in_blender, views)
    q_blend, q_glb = (perceptual_loss_of_views(reference["shaded"], v) for v in (in_blender, views))
    print("WaterBottle shaded q:", json.dumps(dict(round_trip=round_trip, blend=q_blend, glb=q_glb,
                                                   downscale=downscale["q"], memory=result.report["memory_ratio"])))
    assert round_trip < ROUND_TRIP_FLOOR
    assert q_glb == pytest.approx(q_blend, rel=0.01)


def test_one_undo_removes_every_new_image_and_the_copy():
    import perceptual_uv

    perceptual_uv.register()
    try:
        obj = pbr_grid()
        bpy.context.view_layer.objects.active = obj
        names = {kind: sorted(block.name for block in getattr(bpy.data, kind))
                 for kind in ("images", "materials", "node_groups")}
        bpy.ops.ed.undo_push(message="before Optimize UVs")
        # The second argument asks for the undo push that a click in the UI makes.
        assert bpy.ops.uv.perceptual_optimize("EXEC_DEFAULT", True, **FAST) == {"FINISHED"}
        assert len(bpy.data.images) == len(names["images"]) + 4
        assert bpy.data.objects["pbr"].material_slots[0].material.name == "pbr_material_perceptual"
        bpy.ops.ed.undo()
        assert {kind: sorted(block.name for block in getattr(bpy.data, kind)) for kind in names} == names
        obj = bpy.data.objects["pbr"]
        assert obj.material_slots[0].material.name == "pbr_material"
        assert obj.data.uv_layers.keys() == ["UVMap"]
    finally:
        perceptual_uv.unregister()


def test_a_detail_normal_blended_after_the_normal_map_is_not_baked_into_it():
    obj, material = quad("detailed")
    add_normal_map(material, new_image("normal", 8, (0.5, 0.5, 1.0)))
    tree = material.node_tree
    normal_map = next(node for node in tree.nodes if node.type == "NORMAL_MAP")
    # normalize(n_map + n_detail): the copy keeps the blend, so baked in too the detail would apply twice
    detail = tree.nodes.new("ShaderNodeNormalMap")
    constant = tree.nodes.new("ShaderNodeRGB")
    constant.outputs[0].default_value = (0.8, 0.5, 0.9, 1.0)
    tree.links.new(constant.outputs[0], detail.inputs["Color"])
    add = tree.nodes.new("ShaderNodeVectorMath")
    add.operation = "ADD"
    normalize = tree.nodes.new("ShaderNodeVectorMath")
    normalize.operation = "NORMALIZE"
    tree.links.new(normal_map.outputs["Normal"], add.inputs[0])
    tree.links.new(detail.outputs["Normal"], add.inputs[1])
    tree.links.new(add.outputs["Vector"], normalize.inputs[0])
    tree.links.new(normalize.outputs["Vector"], tree.nodes["Principled BSDF"].inputs["Normal"])
    (record,) = [record for record in read_object_materials(obj, source_uv="UVMap")[0].maps
                 if record.role == "normal_tangent"]
    (result,) = bake_maps([obj], [record], source_uv="UVMap", target_uv="Same", resolutions=[8], margin=1,
                          names=["normal_new"])
    np.testing.assert_allclose(pixels_of(result.image)[..., :3], np.broadcast_to((0.5, 0.5, 1.0), (8, 8, 3)),
                               atol=2 / 255)


def add_mapping(material, texture, *, location=(0.5, 0.0, 0.0)):
    tree = material.node_tree
    coordinates = tree.nodes.new("ShaderNodeTexCoord")
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Location"].default_value = location
    tree.links.new(coordinates.outputs["UV"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], texture.inputs["Vector"])


def test_a_texture_transform_is_baked_into_the_new_image():
    obj, material = quad()
    rng = np.random.default_rng(6)
    orm = rng.integers(0, 256, (8, 8, 3)) / 255.0
    texture = add_orm(material, new_image("orm", 8, orm))
    add_mapping(material, texture)  # u + 0.5: half the image over, REPEAT
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    assert any("texture transform" in note for note in record.notes)
    (result,) = bake_maps([obj], [record], source_uv="UVMap", target_uv="Same", resolutions=[8], margin=1,
                          names=["orm_new"])
    np.testing.assert_allclose(pixels_of(result.image)[..., :3], np.roll(orm, -4, axis=1), atol=ONE_STEP)


@pytest.mark.parametrize("occlusion_offset, layouts", [((0.5, 0.0, 0.0), 1), ((0.25, 0.0, 0.0), 2)])
def test_one_image_through_different_texture_transforms_is_refused_before_the_run(occlusion_offset, layouts):
    # The glTF importer reads an occlusion-roughness-metallic image with two nodes, each through a Mapping node of
    # its own. Equal values are one layout, baked into one new image; different ones are two layouts that one new
    # image cannot hold (both nodes of a copy would read it): refused before the run, not baked half right.
    from perceptual_uv.bridge.material_copy import read_maps

    obj, material = quad()
    image = new_image("orm_twice", 8, np.random.default_rng(7).random((8, 8, 3)))
    tree = material.node_tree
    metal_rough = add_orm(material, image)
    occlusion = tree.nodes.new("ShaderNodeTexImage")
    occlusion.image = image
    separate = tree.nodes.new("ShaderNodeSeparateColor")
    tree.links.new(occlusion.outputs["Color"], separate.inputs["Color"])
    (group_output,) = [node for node in tree.nodes if node.type == "GROUP"]
    tree.links.new(separate.outputs["Red"], group_output.inputs["Occlusion"])  # replaces add_orm's own link
    add_mapping(material, metal_rough, location=(0.5, 0.0, 0.0))
    add_mapping(material, occlusion, location=occlusion_offset)
    (record,) = read_object_materials(obj, source_uv="UVMap")[0].maps
    assert len(record.nodes) == 2
    if layouts == 1:
        records, _ = read_maps([obj], "UVMap", image)
        assert [r.image for r in records] == [image]
    else:
        with pytest.raises(ValueError, match="2 Image Texture nodes read it through 2 different texture transforms"):
            read_maps([obj], "UVMap", image)


def test_one_image_as_colour_and_as_tangent_normal_map_is_refused_before_the_run():
    # The normal map's use needs the values re-expressed in the new UV map's tangent frame, the colour's as they
    # are: one new image cannot serve both (09_texture_transform of glTF-Blender-IO reads one image in every slot).
    from perceptual_uv.bridge.material_copy import read_maps

    obj, material = quad()
    image = new_image("both", 8, np.random.default_rng(8).random((8, 8, 3)))
    texture = add_normal_map(material, image)
    principled = material.node_tree.nodes["Principled BSDF"]
    material.node_tree.links.new(texture.outputs["Color"], principled.inputs["Base Color"])
    with pytest.raises(ValueError, match="read both as a tangent-space normal map and as base_color"):
        read_maps([obj], "UVMap", image)


def test_the_copy_of_a_transformed_map_reads_the_new_image_without_the_transform():
    obj = pbr_grid()
    material = obj.material_slots[0].material
    emissive = next(node for node in material.node_tree.nodes
                    if node.type == "TEX_IMAGE" and node.image.name == "pbr_emissive")
    add_mapping(material, emissive, location=(0.25, 0.1, 0.0))
    result = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))
    (copy,) = result.materials
    assert not [node for node in copy.node_tree.nodes if node.type in ("MAPPING", "TEX_COORD")]
    node = next(node for node in copy.node_tree.nodes if node.type == "TEX_IMAGE" and node.image in result.images
                and node.image.name.startswith("pbr_emissive"))
    (link,) = node.inputs["Vector"].links
    assert link.from_node.type == "UVMAP" and link.from_node.uv_map == result.uv_map
    assert [node.type for node in material.node_tree.nodes].count("MAPPING") == 1  # the original keeps its own


# --- the loss sees every map ---------------------------------------------------------------------------------

def detail_on_the_left(size, rng):
    """A (size, size) mask that is 1 where u < 0.5 (the grid's left half under textured_grid's UVs)."""
    return (np.arange(size)[None, :] < size // 2).astype(float) * np.ones((size, 1))


def area_ratio_left_to_right(obj, result):
    """Median of new / input UV area on the grid's left third over that on its right third."""
    from perceptual_uv.bridge.mesh_io import read_mesh

    before, after = read_mesh(obj, uv_name="UVMap"), read_mesh(obj, uv_name=result.uv_map)

    def areas(uv):
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])

    scale = areas(after.uv) / areas(before.uv)
    x = before.V[before.F].mean(axis=1)[:, 0]
    return np.median(scale[x < 1 / 3]) / np.median(scale[x > 2 / 3])


def flat_grid(name):
    reset_blender_scene()
    flat = new_image(f"{name}_flat", 64, np.full((64, 64, 3), 0.5), data=False)
    obj = textured_grid(name, k=8, image=flat)
    return obj, obj.material_slots[0].material


@pytest.mark.parametrize("where", ["normal", "roughness"])
def test_detail_only_in_another_map_keeps_its_triangles_large(where):
    # The base colour is flat everywhere: luma alone would shrink every triangle alike. The detail is on the
    # left half of the normal map (random tilts) or of the roughness channel; the right half is flat.
    obj, material = flat_grid(f"detail_{where}")
    rng = np.random.default_rng(3)
    left = detail_on_the_left(64, rng)[..., None]
    if where == "normal":
        tilt = np.stack([0.5 + 0.3 * rng.random((64, 64)), 0.5 + 0.3 * rng.random((64, 64)), np.ones((64, 64))], -1)
        add_normal_map(material, new_image("bumps", 64, left * tilt + (1 - left) * np.array([0.5, 0.5, 1.0])))
    else:
        orm = np.full((64, 64, 3), 0.5)
        orm[..., 1] = left[..., 0] * rng.random((64, 64)) + (1 - left[..., 0]) * 0.5
        add_orm(material, new_image("roughness", 64, orm))
    result = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))
    assert area_ratio_left_to_right(obj, result) > 3


@pytest.mark.parametrize("where", ["normal", "roughness"])
def test_a_material_without_a_base_colour_image_is_optimized_on_its_other_maps(where):
    # Base Color is a constant (no image at all): the run is framed by the material's other map, read in its own
    # role, and keeps the triangles carrying its detail large as when a flat base-colour image is beside it.
    from perceptual_uv.bridge.read_objects import target_problem

    obj, material = flat_grid(f"no_colour_{where}")
    tree = material.node_tree
    tree.nodes.remove(tree.nodes["Image Texture"])
    tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.3, 0.5, 0.7, 1.0)
    rng = np.random.default_rng(3)
    left = detail_on_the_left(64, rng)[..., None]
    if where == "normal":
        tilt = np.stack([0.5 + 0.3 * rng.random((64, 64)), 0.5 + 0.3 * rng.random((64, 64)), np.ones((64, 64))], -1)
        flat_normal = np.array([0.5, 0.5, 1.0])
        detail = add_normal_map(material, new_image("bumps_alone", 64, left * tilt + (1 - left) * flat_normal))
    else:
        orm = np.full((64, 64, 3), 0.5)
        orm[..., 1] = left[..., 0] * rng.random((64, 64)) + (1 - left[..., 0]) * 0.5
        detail = add_orm(material, new_image("roughness_alone", 64, orm))
    assert target_problem(obj) is None

    result = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST)))

    assert area_ratio_left_to_right(obj, result) > 3
    (copy,) = result.materials
    (new_image_node,) = [node for node in copy.node_tree.nodes if node.type == "TEX_IMAGE"]
    assert new_image_node.image in result.images and new_image_node.image is not detail.image
    assert new_image_node.image.colorspace_settings.name == "Non-Color"  # a data map stays data
    (link,) = new_image_node.inputs["Vector"].links
    assert link.from_node.type == "UVMAP" and link.from_node.uv_map == result.uv_map
    assert tuple(copy.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value) == \
        pytest.approx((0.3, 0.5, 0.7, 1.0))
    assert [map_["role"] for map_ in result.report["maps"]] == [
        "normal_tangent" if where == "normal" else "metallic_roughness"]


def test_an_object_whose_materials_read_no_image_is_refused_with_the_reason():
    from perceptual_uv.bridge.read_objects import source_image, target_problem

    obj, material = flat_grid("no_image_at_all")
    material.node_tree.nodes.remove(material.node_tree.nodes["Image Texture"])
    assert "no material that reads an image texture" in target_problem(obj)
    with pytest.raises(ValueError, match="none of the objects' materials reads an image texture"):
        source_image([obj])
