# SPDX-License-Identifier: GPL-3.0-or-later
"""bridge.mesh_io on the bundled spot model: arrays, hand-checked corners from the OBJ text, UV write-back."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge import mesh_io  # noqa: E402
from perceptual_uv.core.mesh import MeshArrays, concatenate_meshes  # noqa: E402

pytestmark = pytest.mark.bpy

# From tests/data/spot/spot_triangulated.obj, read by hand (1-based OBJ indices):
#   face 1    "f 739/1 735/2 736/3"        face 1000 "f 1531/992 390/957 1532/991"
#   v 739 = (0.317288, -0.397295, 0.364448)  v 735 = (0.313121, -0.40468, 0.424303)
#   v 1531 = (0.143329, 0.804627, -0.337252)
#   vt 1 = (0.800375, 0.667457)  vt 2 = (0.789584, 0.668215)  vt 3 = (0.799923, 0.663933)
#   vt 992 = (0.209393, 0.413479)  vt 957 = (0.205359, 0.404085)
# Blender's OBJ importer turns the file's Y-up into Z-up: world (x, y, z) = (x_file, -z_file, y_file).
HAND_CHECKED_CORNERS = [  # (polygon, corner, world position, uv)
    (0, 0, (0.317288, -0.364448, -0.397295), (0.800375, 0.667457)),
    (0, 1, (0.313121, -0.424303, -0.40468), (0.789584, 0.668215)),
    (0, 2, None, (0.799923, 0.663933)),
    (999, 0, (0.143329, 0.337252, 0.804627), (0.209393, 0.413479)),
    (999, 1, None, (0.205359, 0.404085)),
]


@pytest.fixture
def spot(empty_scene, spot_obj):
    objects = mesh_io.import_model(spot_obj)
    (obj,) = [obj for obj in objects if obj.type == "MESH"]
    return obj


def test_read_mesh_shapes_and_dtypes(spot):
    mesh = mesh_io.read_mesh(spot)
    assert isinstance(mesh, MeshArrays)
    assert mesh.V.shape == (2930, 3) and mesh.V.dtype == np.float64
    assert mesh.F.shape == (5856, 3) and mesh.F.dtype == np.int64
    assert mesh.uv.shape == (5856, 3, 2) and mesh.uv.dtype == np.float64
    assert mesh.tri_loops.shape == (5856, 3) and mesh.tri_loops.dtype == np.int64
    assert mesh.tri_polygons.shape == (5856,) and mesh.material_index.shape == (5856,)
    assert mesh.uv_name == "UVMap" and mesh.object_names == (spot.name,)
    # all triangles: one loop per corner, each loop used exactly once
    assert np.array_equal(np.sort(mesh.tri_loops.ravel()), np.arange(3 * 5856))
    # spot's UVs leave [0, 1] slightly (README of the model); nothing wild
    assert -0.06 < mesh.uv.min() and mesh.uv.max() < 1.01


def test_corners_match_the_obj_file(spot):
    mesh = mesh_io.read_mesh(spot)
    loop_start = np.empty(len(spot.data.polygons), dtype=np.int32)
    spot.data.polygons.foreach_get("loop_start", loop_start)
    for polygon, corner, position, uv in HAND_CHECKED_CORNERS:
        loop = loop_start[polygon] + corner
        triangle, slot = np.argwhere(mesh.tri_loops == loop)[0]
        assert mesh.tri_polygons[triangle] == polygon
        # float32 storage in Blender: compare to ~1e-6
        np.testing.assert_allclose(mesh.uv[triangle, slot], uv, atol=1e-6)
        if position is not None:
            np.testing.assert_allclose(mesh.V[mesh.F[triangle, slot]], position, atol=1e-6)


def test_world_space_applies_object_transform(spot):
    local = mesh_io.read_mesh(spot).V
    spot.location = (1.0, 2.0, 3.0)
    spot.scale = (2.0, 2.0, 2.0)
    bpy.context.view_layer.update()
    moved = mesh_io.read_mesh(spot).V
    np.testing.assert_allclose(moved, 2.0 * local + [1.0, 2.0, 3.0], atol=1e-5)


def test_quads_are_triangulated_and_mapped_to_their_loops(empty_scene):
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    cube = bpy.context.active_object
    mesh = mesh_io.read_mesh(cube)
    assert mesh.F.shape == (12, 3)
    assert np.array_equal(np.bincount(mesh.tri_polygons), [2] * 6)
    loop_vertex = np.empty(24, dtype=np.int32)
    cube.data.loops.foreach_get("vertex_index", loop_vertex)
    assert np.array_equal(loop_vertex[mesh.tri_loops], mesh.F)
    # every triangle of a size-2 cube has area 2
    e1, e2 = mesh.V[mesh.F[:, 1]] - mesh.V[mesh.F[:, 0]], mesh.V[mesh.F[:, 2]] - mesh.V[mesh.F[:, 0]]
    np.testing.assert_allclose(0.5 * np.linalg.norm(np.cross(e1, e2), axis=1), 2.0)


def test_read_image_bottom_row_first_and_stored_bytes(empty_scene):
    image = bpy.data.images.new("probe", 3, 2, alpha=True)
    pixels = np.zeros((2, 3, 4), dtype=np.float32)
    pixels[0, 0] = (1.0, 0.0, 0.0, 1.0)  # bottom-left in Blender's storage
    pixels[1, 2] = (0.0, 128 / 255, 1.0, 1.0)  # top-right
    image.pixels.foreach_set(pixels.ravel())
    read = mesh_io.read_image(image)
    assert read.shape == (2, 3, 4) and read.dtype == np.float32
    np.testing.assert_array_equal(read[0, 0], [1.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(read[1, 2], [0.0, 128 / 255, 1.0, 1.0], atol=1e-7)


def test_load_textured_mesh_reads_spot_texture(spot_obj, empty_scene):
    mesh, texture, image_name = mesh_io.load_textured_mesh(spot_obj)
    assert image_name == "spot_texture.png"
    assert texture.shape == (1024, 1024, 4) and texture.dtype == np.float32
    # 8-bit values as stored: multiples of 1/255
    sample = texture[::97, ::89, :3]
    np.testing.assert_allclose(sample * 255, np.round(sample * 255), atol=1e-4)
    assert mesh.n_faces == 5856


def test_write_uv_layer_round_trip_leaves_original_untouched(spot):
    mesh = mesh_io.read_mesh(spot)
    original = np.empty(2 * len(spot.data.loops), dtype=np.float32)
    spot.data.uv_layers["UVMap"].uv.foreach_get("vector", original)
    new_uv = 0.5 * mesh.uv + 0.25
    mesh_io.write_uv_layer(spot, "PerceptualUV", new_uv, mesh.tri_loops)
    assert [layer.name for layer in spot.data.uv_layers] == ["UVMap", "PerceptualUV"]
    assert spot.data.uv_layers.active.name == "UVMap"
    after = np.empty_like(original)
    spot.data.uv_layers["UVMap"].uv.foreach_get("vector", after)
    assert np.array_equal(original, after)
    reread = mesh_io.read_mesh(spot, uv_name="PerceptualUV")
    np.testing.assert_allclose(reread.uv, new_uv, atol=1e-6)
    with pytest.raises(ValueError, match="already has a UV map"):
        mesh_io.write_uv_layer(spot, "PerceptualUV", new_uv, mesh.tri_loops)


def test_write_uv_layer_averages_corners_shared_inside_a_quad(empty_scene):
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    mesh = mesh_io.read_mesh(plane)
    uv = mesh.uv.copy()
    shared = np.isin(mesh.tri_loops, np.intersect1d(mesh.tri_loops[0], mesh.tri_loops[1]))  # the diagonal
    assert shared.sum() == 4
    uv[1][shared[1]] += 0.1
    mesh_io.write_uv_layer(plane, "Averaged", uv, mesh.tri_loops)
    reread = mesh_io.read_mesh(plane, uv_name="Averaged").uv
    expected = mesh.uv.copy()
    expected[shared] += 0.05
    np.testing.assert_allclose(reread, expected, atol=1e-6)


def test_errors_are_value_errors(tmp_path, spot):
    with pytest.raises(ValueError, match="not found"):
        mesh_io.import_model(tmp_path / "missing.obj")
    (tmp_path / "model.stl").write_text("")
    with pytest.raises(ValueError, match="unsupported model type"):
        mesh_io.import_model(tmp_path / "model.stl")
    with pytest.raises(ValueError, match="no UV map 'Nope'"):
        mesh_io.read_mesh(spot, uv_name="Nope")
    mesh = mesh_io.read_mesh(spot)
    with pytest.raises(ValueError, match="shape"):
        mesh_io.write_uv_layer(spot, "Bad", mesh.uv[:, :2], mesh.tri_loops)
    with pytest.raises(ValueError, match="outside"):
        mesh_io.write_uv_layer(spot, "Bad", mesh.uv, mesh.tri_loops + 10**6)
    assert "Bad" not in spot.data.uv_layers


def test_mesh_arrays_validation_and_concatenation():
    V = np.zeros((3, 3))
    F = np.array([[0, 1, 2]], dtype=np.int64)
    fields = dict(uv=np.zeros((1, 3, 2)), tri_loops=np.array([[0, 1, 2]], dtype=np.int64),
                  tri_polygons=np.zeros(1, dtype=np.int64), material_index=np.zeros(1, dtype=np.int64),
                  object_index=np.zeros(1, dtype=np.int64), object_names=("a",))
    with pytest.raises(ValueError, match="F indexes vertices"):
        MeshArrays(V=V, F=F + 1, **fields)
    with pytest.raises(ValueError, match="dtype int64"):
        MeshArrays(V=V, F=F.astype(np.int32), **fields)
    first = MeshArrays(V=V, F=F, **fields)
    joined = concatenate_meshes([first, MeshArrays(V=V + 1, F=F, **{**fields, "object_names": ("b",)})])
    assert np.array_equal(joined.F, [[0, 1, 2], [3, 4, 5]])
    assert np.array_equal(joined.object_index, [0, 1]) and joined.object_names == ("a", "b")


def test_blend_file_round_trip(spot, tmp_path):
    before = mesh_io.read_mesh(spot)
    path = tmp_path / "spot.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    mesh, texture, image_name = mesh_io.load_textured_mesh(path)
    assert image_name == "spot_texture.png" and texture.shape == (1024, 1024, 4)
    np.testing.assert_array_equal(mesh.V, before.V)
    np.testing.assert_array_equal(mesh.uv, before.uv)
    np.testing.assert_array_equal(mesh.F, before.F)


# Triangle counts and texture sizes from ../shared/models/README.md; sofa_03: the file has 8,004 triangles
# and Blender's glTF importer drops one of them (the mesh Blender holds is what we read and write back to).
SHARED_MODELS = [
    ("Avocado/Avocado.gltf", 682, 1, 2048),
    ("spot/spot_triangulated.obj", 5856, 1, 1024),
    ("bob/bob_tri.obj", 10688, 1, 2048),
    ("CesiumMan/CesiumMan.gltf", 4672, 1, 1024),
    ("WaterBottle/WaterBottle.gltf", 4510, 1, 2048),
    ("BoomBox/BoomBox.gltf", 6036, 1, 2048),
    ("YcbBanana/textured_simple_reoriented.obj", 15728, 1, 4096),
    ("tea_set_01/tea_set_01_1k.gltf", 40296, 10, 1024),
    ("wooden_bookshelf_worn/wooden_bookshelf_worn_1k.gltf", 10106, 1, 1024),
    ("sofa_03/sofa_03_1k.gltf", 8003, 1, 1024),
]


@pytest.mark.parametrize("model, triangles, objects, size", SHARED_MODELS,
                         ids=[entry[0].split("/")[0] for entry in SHARED_MODELS])
def test_every_shared_model_loads(model, triangles, objects, size, shared_models_dir, empty_scene):
    path = shared_models_dir / model
    if not path.is_file():
        pytest.skip(f"{path} not available")
    mesh, texture, _ = mesh_io.load_textured_mesh(path)
    assert mesh.n_faces == triangles
    assert len(mesh.object_names) == objects
    assert texture.shape[:2] == (size, size)
    # the importers put glTF's flipped V back: UVs live in the unit square (up to spot's small overhang)
    assert mesh.uv.min() > -0.1 and mesh.uv.max() < 1.1
    # every triangle has positive area in world space (the join keeps each object's vertices apart)
    e1 = mesh.V[mesh.F[:, 1]] - mesh.V[mesh.F[:, 0]]
    e2 = mesh.V[mesh.F[:, 2]] - mesh.V[mesh.F[:, 0]]
    assert np.median(np.linalg.norm(np.cross(e1, e2), axis=1)) > 0


def test_gltf_texture_coordinates_are_flipped_to_blender(shared_models_dir, empty_scene):
    """Avocado's UVs read through Blender equal (u, 1 - v) of the TEXCOORD_0 accessor in the .bin file."""
    import json

    folder = shared_models_dir / "Avocado"
    if not (folder / "Avocado.gltf").is_file():
        pytest.skip("Avocado not available")
    gltf = json.loads((folder / "Avocado.gltf").read_text())
    accessor = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    view = gltf["bufferViews"][accessor["bufferView"]]
    assert accessor["componentType"] == 5126 and accessor["type"] == "VEC2"  # float32 pairs
    data = (folder / gltf["buffers"][view["buffer"]]["uri"]).read_bytes()
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    stored = np.frombuffer(data, dtype="<f4", count=2 * accessor["count"], offset=start).reshape(-1, 2)
    expected = np.column_stack([stored[:, 0], 1.0 - stored[:, 1]])
    mesh, _, _ = mesh_io.load_textured_mesh(folder / "Avocado.gltf")
    read = mesh.uv.reshape(-1, 2)
    # the importer may reorder and split vertices: compare as point sets, both ways
    from scipy.spatial import cKDTree

    assert cKDTree(expected).query(read)[0].max() < 1e-6
    assert cKDTree(read).query(expected)[0].max() < 1e-6
    # and the unflipped coordinates are not what Blender holds
    assert cKDTree(stored).query(read)[0].max() > 0.1


def test_object_without_base_colour_image_is_refused(empty_scene, tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    bpy.context.active_object.name = "Plain"
    path = tmp_path / "plain.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    with pytest.raises(ValueError, match="'Plain' has no image texture"):
        mesh_io.load_textured_mesh(path, object_name="Plain")
    with pytest.raises(ValueError, match="no object 'Missing'"):
        mesh_io.load_textured_mesh(path, object_name="Missing")
    with pytest.raises(ValueError, match="no mesh object in .* has an image texture"):
        mesh_io.load_textured_mesh(path)


def test_edit_mode_is_refused(spot):
    bpy.context.view_layer.objects.active = spot
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        with pytest.raises(ValueError, match="Edit Mode"):
            mesh_io.read_mesh(spot)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
    assert mesh_io.read_mesh(spot).n_faces == 5856
