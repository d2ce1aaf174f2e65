"""Messy inputs and faults (issue 7): each is handled or refused with a clear message, originals untouched."""
import dataclasses
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge import pipeline  # noqa: E402
from perceptual_uv.bridge.pipeline import optimize_objects, run_to_end  # noqa: E402
from perceptual_uv.bridge.read_objects import target_problem  # noqa: E402
from perceptual_uv.core.settings import OptimizeSettings  # noqa: E402

from conftest import reset_blender_scene  # noqa: E402  (tests/ is on sys.path under pytest)
from test_optimize_end_to_end import FAST, ID_KINDS  # noqa: E402

pytestmark = pytest.mark.bpy
SETTINGS = OptimizeSettings(**FAST)


def grid_polygons(k, kind):
    """Faces of a k x k grid of unit cells: quads, triangles, or n-gons (pairs of cells merged into hexagons)."""
    index = lambda i, j: i * (k + 1) + j  # noqa: E731
    faces = []
    for i in range(k):
        j = 0
        while j < k:
            a, b, c, d = index(i, j), index(i, j + 1), index(i + 1, j + 1), index(i + 1, j)
            if kind == "ngons" and j + 1 < k:
                faces.append((a, b, index(i, j + 2), index(i + 1, j + 2), c, d))
                j += 2
                continue
            faces += [(a, b, c), (a, c, d)] if kind == "tris" else [(a, b, c, d)]
            j += 1
    return [face[::-1] for face in faces]  # counter-clockwise seen from +z, as are the UVs (u, v) = (x, y)


def textured_grid(name="grid", *, k=3, kind="quads", image_size=(64, 64), float_image=False, image=None,
                  uv_scale=0.8, uv_offset=0.1, location=(0.0, 0.0, 0.0)):
    """A bumpy k x k grid with UV map "UVMap" (its xy, scaled) and a random image feeding Base Color."""
    rng = np.random.default_rng(len(name))
    xs = np.arange(k + 1, dtype=float) / k
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    Z = 0.1 * np.sin(3 * X) * np.cos(2 * Y)
    verts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.tolist(), [], grid_polygons(k, kind))
    layer = mesh.uv_layers.new(name="UVMap")
    loop_vertex = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", loop_vertex)
    layer.uv.foreach_set("vector", (verts[loop_vertex, :2] * uv_scale + uv_offset).ravel())
    if image is None:
        width, height = image_size
        image = bpy.data.images.new(f"{name}_texture", width, height, alpha=True, float_buffer=float_image)
        rgba = np.ones((height, width, 4), dtype=np.float32)
        rgba[..., :3] = rng.random((height, width, 3))
        image.pixels.foreach_set(rgba.ravel())
    material = bpy.data.materials.new(f"{name}_material")
    node = material.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    material.node_tree.links.new(node.outputs["Color"],
                                 material.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def image_of(obj):
    return obj.material_slots[0].material.node_tree.nodes["Image Texture"].image


def state(objects):
    """Everything a run must not change: per object its UV maps, positions, attributes, slots; image pixels."""
    out = {"ids": {kind: len(getattr(bpy.data, kind)) for kind in ID_KINDS}}
    for obj in objects:
        mesh = obj.data
        co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
        mesh.vertices.foreach_get("co", co)
        layers = {}
        for layer in mesh.uv_layers:
            uv = np.empty(2 * len(mesh.loops), dtype=np.float32)
            layer.uv.foreach_get("vector", uv)
            layers[layer.name] = uv.tobytes()
        out[obj.name] = {"co": co.tobytes(), "uv": layers,
                         "attributes": sorted(a.name for a in mesh.attributes),
                         "slots": [(slot.link, slot.material.name if slot.material else None)
                                   for slot in obj.material_slots]}
    for image in bpy.data.images:
        pixels = np.empty(len(image.pixels), dtype=np.float32)
        if len(pixels):
            image.pixels.foreach_get(pixels)
        out[f"image {image.name}"] = pixels.tobytes()
    return out


def refused(objects, *, match, **kwargs):
    """Run the pipeline, expect a ValueError matching ``match``, and check nothing was changed."""
    before = state(objects)
    with pytest.raises(ValueError, match=match) as error:
        run_to_end(optimize_objects(objects, SETTINGS, **kwargs))
    assert state(objects) == before
    assert "\n" not in str(error.value)
    return str(error.value)


def optimized(objects, settings=SETTINGS, **kwargs):
    """Run the pipeline to the end; check the originals are bit-identical and the result is flip-free."""
    before = state(objects)
    result = run_to_end(optimize_objects(objects, settings, **kwargs))
    after = state(objects)
    for obj in objects:
        kept = before[obj.name]
        now = after[obj.name]
        assert now["co"] == kept["co"]
        assert all(now["uv"][name] == uv for name, uv in kept["uv"].items())
        assert set(now["uv"]) == set(kept["uv"]) | {result.uv_map}
    assert all(after[key] == value for key, value in before.items() if key.startswith("image "))
    assert result.report["flipped_triangles"] == 0
    return result


def new_uv_per_triangle(obj, name="PerceptualUV"):
    mesh = obj.data
    mesh.calc_loop_triangles()
    loops = np.empty(3 * len(mesh.loop_triangles), dtype=np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    uv = np.empty(2 * len(mesh.loops))
    mesh.uv_layers[name].uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)[loops.reshape(-1, 3)]


def signed_areas(uv):
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


@pytest.fixture(autouse=True)
def clean_scene():
    reset_blender_scene()
    yield


# ---------------------------------------------------------------------------------------------------- refusals
def test_no_uv_map_is_refused_by_poll_and_pipeline():
    obj = textured_grid()
    obj.data.uv_layers.remove(obj.data.uv_layers["UVMap"])
    assert "has no UV map: unwrap it first" in target_problem(obj)
    assert target_problem(obj).startswith(f"Object '{obj.name}'")  # the name --object and the outliner show
    refused([obj], match="has no UV map")


def test_uv_map_collapsed_to_a_point_is_refused():
    obj = textured_grid()
    obj.data.uv_layers["UVMap"].uv.foreach_set("vector", np.full(2 * len(obj.data.loops), 0.5, np.float32))
    message = refused([obj], match="collapsed to a point")
    assert "UV map 'UVMap'" in message and "Unwrap" in message


def test_uv_map_collapsed_to_a_line_is_refused():
    obj = textured_grid()
    uv = np.empty(2 * len(obj.data.loops), dtype=np.float32)
    obj.data.uv_layers["UVMap"].uv.foreach_get("vector", uv)
    uv[1::2] = 0.25  # every v equal: all UV triangles flat
    obj.data.uv_layers["UVMap"].uv.foreach_set("vector", uv)
    refused([obj], match="collapsed to a line")


def test_no_image_texture_is_refused():
    obj = textured_grid()
    tree = obj.material_slots[0].material.node_tree
    tree.nodes.remove(tree.nodes["Image Texture"])
    assert "no material that reads an image texture" in target_problem(obj)
    refused([obj], match="no material that reads an image texture")


def test_materials_an_importer_left_empty_are_named_when_no_texture_is_found():
    from perceptual_uv.bridge.texture_sets import texture_groups

    first = textured_grid("first")
    second = textured_grid("second", location=(2.0, 0.0, 0.0))
    for obj in (first, second):  # as Blender's USD importer leaves a MaterialX material: no nodes at all
        obj.material_slots[0].material.node_tree.nodes.clear()
    with pytest.raises(ValueError) as error:
        texture_groups([first, second])
    assert str(error.value).endswith("(2 of their materials have no shader nodes, e.g. 'first_material': an importer "
                                     "left them empty, as Blender's USD importer does with MaterialX materials)")
    tree = first.material_slots[0].material.node_tree  # one with an output node and no image: not named
    tree.nodes.new("ShaderNodeOutputMaterial")
    with pytest.raises(ValueError, match=r"\(1 of their materials have no shader nodes, e.g. 'second_material'"):
        texture_groups([first, second])


def test_missing_image_file_is_refused_with_its_path(tmp_path):
    missing = tmp_path / "gone.png"
    image = bpy.data.images.new("gone.png", 4, 4)
    image.source = "FILE"
    image.filepath = str(missing)
    image.reload()
    obj = textured_grid(image=image)
    message = refused([obj], match="has no pixels")
    assert str(missing) in message and "missing" in message


def test_one_pixel_image_is_refused():
    obj = textured_grid(image_size=(1, 1))
    refused([obj], match=r"1 x 1 pixels.*at least 2 x 2")


def test_empty_mesh_and_loose_geometry_are_refused():
    obj = textured_grid()
    empty = bpy.data.meshes.new("empty")
    empty.from_pydata([(0, 0, 0), (1, 0, 0), (2, 1, 0)], [(0, 1)], [])  # a loose edge and a loose vertex
    empty.uv_layers.new(name="UVMap")
    empty.materials.append(obj.material_slots[0].material)
    obj.data = empty
    refused([obj], match="has no faces.*nothing to optimize")


def test_nan_coordinates_are_refused():
    obj = textured_grid()
    co = np.empty(3 * len(obj.data.vertices), dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    co[4] = np.nan
    obj.data.vertices.foreach_set("co", co)
    refused([obj], match="1 vertices with NaN or infinite coordinates")


def test_infinite_uvs_are_refused():
    obj = textured_grid()
    uv = np.empty(2 * len(obj.data.loops), dtype=np.float32)
    obj.data.uv_layers["UVMap"].uv.foreach_get("vector", uv)
    uv[:2] = np.inf
    obj.data.uv_layers["UVMap"].uv.foreach_set("vector", uv)
    refused([obj], match="UV map 'UVMap' of 'grid' has NaN or infinite coordinates on 1 face corners")


def test_two_images_on_one_object_are_refused_naming_the_slots():
    obj = textured_grid()
    other = textured_grid("other")
    obj.data.materials.append(other.material_slots[0].material)
    polygons = np.zeros(len(obj.data.polygons), dtype=np.int32)
    polygons[::2] = 1
    obj.data.polygons.foreach_set("material_index", polygons)
    message = refused([obj], match="uses 2 different images")
    assert "'grid_texture' on slot 1" in message and "'other_texture' on slot 2" in message
    assert "Separate > By Material" in message


def test_linked_library_data_is_refused(tmp_path):
    textured_grid("linked")
    library = tmp_path / "library.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(library))
    reset_blender_scene()
    with bpy.data.libraries.load(str(library), link=True) as (data_from, data_to):
        data_to.objects = ["linked"]
    obj = data_to.objects[0]
    bpy.context.scene.collection.objects.link(obj)
    assert "is linked from the library" in target_problem(obj)
    with pytest.raises(ValueError, match="Make Local"):
        run_to_end(optimize_objects([obj], SETTINGS))
    assert [layer.name for layer in obj.data.uv_layers] == ["UVMap"]


def test_udim_tiled_image_is_refused():
    obj = textured_grid()
    image_of(obj).source = "TILED"
    refused([obj], match="UDIM tiled image")


def test_memory_budget_is_checked_before_the_pixels_are_read(monkeypatch):
    obj = textured_grid()
    monkeypatch.setattr("perceptual_uv.core.validate._physical_memory", lambda: 1024 ** 2)
    read = []
    monkeypatch.setattr("perceptual_uv.bridge.mesh_io.read_image", lambda image: read.append(image))
    message = refused([obj], match=r"needs about \d+ KiB .*more than the memory budget of 512 KiB")
    assert "mesh-wise" in message and "fewer workers" in message
    assert read == []


# ---------------------------------------------------------------------------------------------------- handled
def test_quads_and_ngons_are_written_back_to_their_loops():
    quads = textured_grid("quads", kind="quads")
    result = optimized([quads])
    assert result.report["faces"] == 18
    ngons = textured_grid("ngons", kind="ngons")
    assert max(len(p.vertices) for p in ngons.data.polygons) == 6
    # A 1 px margin: the packed map nearly fills [0, 1], so it differs from the input's [0.1, 0.9] even where the
    # fit keeps (or a folded chart gets back) the input's shape.
    result = optimized([ngons], dataclasses.replace(SETTINGS, margin=1))
    uv = new_uv_per_triangle(ngons)
    # Flip-free and inside the image. Each hexagon's triangle fan has one triangle on three collinear corners
    # (zero UV area in the input); it has no Jacobian to keep positive, so it only must not flip.
    areas, input_areas = signed_areas(uv), signed_areas(new_uv_per_triangle(ngons, "UVMap"))
    assert (input_areas < 1e-12).sum() == 1
    assert np.all(areas[input_areas > 1e-12] > 0) and np.all(areas > -1e-12) and uv.min() >= 0 and uv.max() <= 1
    # Every loop of every polygon got a new UV: corners shared inside an n-gon agree.
    mesh = ngons.data
    per_loop = np.empty(2 * len(mesh.loops))
    mesh.uv_layers[result.uv_map].uv.foreach_get("vector", per_loop)
    original = np.empty(2 * len(mesh.loops))
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", original)
    assert not np.allclose(per_loop, original)


def test_packed_non_square_image():
    obj = textured_grid(image_size=(96, 48))
    image_of(obj).pack()
    result = optimized([obj])
    assert result.report["input_resolution"] == [96, 48]
    assert list(result.image.size) == result.report["resolution"]
    assert image_of(obj).packed_file is not None


def test_float_image_gives_a_float_result_with_the_same_values():
    obj = textured_grid(float_image=True)
    image = image_of(obj)
    assert image.is_float
    result = run_to_end(optimize_objects([obj], OptimizeSettings(**dict(FAST, resolution=64))))
    assert result.image.is_float  # an 8-bit sRGB image would read the linear values as sRGB (darker)
    source = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(source)
    baked = np.empty(len(result.image.pixels), dtype=np.float32)
    result.image.pixels.foreach_get(baked)
    # Same texture on a smaller map: the mean colour stays (the bake copies stored values).
    assert abs(baked.reshape(-1, 4)[:, :3].mean() - source.reshape(-1, 4)[:, :3].mean()) < 0.05


def test_hdr_values_are_clipped_for_the_loss_and_said_so():
    obj = textured_grid(float_image=True)
    image = image_of(obj)
    pixels = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(pixels)
    image.pixels.foreach_set(pixels * 3.0)
    result = optimized([obj])
    assert any("outside [0, 1]" in note for note in result.report["notes"])


def test_zero_area_triangles_are_skipped_but_get_new_uvs():
    obj = textured_grid("degenerate", kind="tris")
    mesh = obj.data
    # Triangle 0 collapses in 3D (its corner moved onto the opposite edge's midpoint) ...
    co = np.empty((len(mesh.vertices), 3), dtype=np.float32)
    mesh.vertices.foreach_get("co", co.ravel())
    a, b, c = mesh.polygons[0].vertices
    co[b] = 0.5 * (co[a] + co[c])
    mesh.vertices.foreach_set("co", co.ravel())
    # ... and triangle 10 collapses in UV (its three corners on one line, all in one face: nothing shared).
    uv = np.empty((len(mesh.loops), 2), dtype=np.float32)
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv.ravel())
    loops = list(mesh.polygons[10].loop_indices)
    uv[loops[2]] = 0.5 * (uv[loops[0]] + uv[loops[1]])
    mesh.uv_layers["UVMap"].uv.foreach_set("vector", uv.ravel())
    result = optimized([obj])
    report = result.report
    assert report["skipped_triangles"] == 2 and report["optimized_triangles"] == report["faces"] - 2
    assert any("zero area in 3D" in note for note in report["notes"])
    assert any("zero area in UV map 'UVMap'" in note for note in report["notes"])
    new = new_uv_per_triangle(obj)
    assert np.all(np.isfinite(new)) and new.min() >= 0 and new.max() <= 1
    keep = np.ones(len(new), dtype=bool)
    keep[10] = False
    assert np.all(signed_areas(new[keep]) > 0)


def test_mirrored_overlapping_and_repeating_uvs():
    obj = textured_grid("mirror", k=4, kind="tris", uv_scale=1.2, uv_offset=-0.1)  # leaves [0, 1]: repeat
    mesh = obj.data
    uv = np.empty((len(mesh.loops), 2), dtype=np.float32)
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv.ravel())
    loop_vertex = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", loop_vertex)
    co = np.empty((len(mesh.vertices), 3), dtype=np.float32)
    mesh.vertices.foreach_get("co", co.ravel())
    right = co[loop_vertex, 0] > 0.5 + 1e-6
    uv[right, 0] = 1.0 - uv[right, 0]  # the right half mirrored onto the left half's texels
    mesh.uv_layers["UVMap"].uv.foreach_set("vector", uv.ravel())
    before = new_uv_per_triangle(obj, "UVMap")
    assert (signed_areas(before) < 0).any() and (signed_areas(before) > 0).any()
    optimized([obj])
    after = new_uv_per_triangle(obj)
    # Each triangle keeps its orientation (mirrored ones stay mirrored); the result lies in [0, 1].
    np.testing.assert_array_equal(np.sign(signed_areas(after)), np.sign(signed_areas(before)))
    assert after.min() >= 0 and after.max() <= 1


def test_objects_sharing_an_atlas_are_optimized_together():
    first = textured_grid("first")
    second = textured_grid("second", image=image_of(first), uv_offset=0.05, uv_scale=0.3, location=(2, 0, 0))
    result = optimized([first, second])
    assert result.report["objects"] == ["first", "second"]
    assert result.report["faces"] == 36
    for obj in (first, second):
        assert result.uv_map in obj.data.uv_layers
    assert len(result.materials) == 2 and all(m.node_tree.nodes["Image Texture"].image == result.image
                                              for m in result.materials)


def test_objects_with_different_uv_map_names_are_refused_naming_them():
    first = textured_grid("named_a")
    second = textured_grid("named_b", image=image_of(first), location=(2.0, 0.0, 0.0))
    second.data.uv_layers["UVMap"].name = "Lightmap"
    message = refused([first, second], match="mesh 'named_b' has no UV map 'UVMap'")
    assert "its UV maps: 'Lightmap'" in message and "same name" in message


def test_a_texture_read_through_another_uv_map_than_the_active_one_optimizes_that_one():
    # The image node has no Vector input, so it reads the render UV map; the active one (for editing) is new.
    def grid_editing_another_uv_map(name):
        obj = textured_grid(name)
        obj.data.uv_layers.active = obj.data.uv_layers.new(name="Edit")
        assert obj.data.uv_layers["UVMap"].active_render
        return obj

    result = optimized([grid_editing_another_uv_map("other_active")])

    assert result.report["source_uv_map"] == "UVMap"
    assert ("the texture 'other_active_texture' is read through UV map 'UVMap', not the active 'Edit': 'UVMap' is "
            "the one optimized") in result.report["notes"]
    message = refused([grid_editing_another_uv_map("named")], source_uv="Edit",  # named, it is not overruled
                      match="is not read through UV map 'Edit' \\(it is read through 'UVMap'\\)")
    assert "pass --uv UVMap" in message


def test_modifiers_are_left_on_and_the_base_mesh_is_optimized():
    obj = textured_grid()
    obj.modifiers.new("Subdivision", "SUBSURF")
    result = optimized([obj])
    assert result.report["faces"] == 18  # the 9 base quads, not the subdivided ones
    assert any("base mesh is optimized" in note and "Subdivision" in note for note in result.report["notes"])
    assert [modifier.name for modifier in obj.modifiers] == ["Subdivision"]


def test_material_slot_without_the_image_is_not_optimized():
    obj = textured_grid()
    plain = bpy.data.materials.new("plain")
    obj.data.materials.append(plain)
    obj.data.polygons[0].material_index = 1
    result = optimized([obj])
    assert result.report["skipped_triangles"] == 2
    assert any("use a material without image 'grid_texture'" in note for note in result.report["notes"])


def test_tiny_image_gets_a_sane_resolution():
    # 16 x 16 with a 4 px margin: the margin cannot be met; the resolution must not run away.
    result = optimized([textured_grid(image_size=(16, 16))])
    assert 8 <= min(result.report["resolution"]) and max(result.report["resolution"]) <= 32


def test_the_image_memory_side_takes_no_shape_narrower_than_the_smallest_image():
    # image_sizes: width round(side sqrt(a)), height side^2 // width. At side 8 every rectangle has a side below 8
    # (4:3 is 9 x 7, 1:2 is 6 x 10); at 11 only 2:1 does (16 x 7; 1:2 is 8 x 15); at 12 none (2:1 is 17 x 8).
    from perceptual_uv.core.packing import IMAGE_ASPECTS

    assert pipeline._memory_aspects(8, SETTINGS) == (1.0,)
    assert pipeline._memory_aspects(11, SETTINGS) == tuple(a for a in IMAGE_ASPECTS if a != 2.0)
    assert pipeline._memory_aspects(12, SETTINGS) == IMAGE_ASPECTS
    assert pipeline._memory_aspects(1024, dataclasses.replace(SETTINGS, square_images=True)) == (1.0,)


def test_islands_that_fit_no_image_at_any_scale_are_refused_before_the_run():
    # Two grids, two islands on separate texels of one 8 x 8 texture: at image memory 0.3 the new image is the
    # smallest side, 8 (every other shape is narrower than 8), and with the 4 px margin an island's bitmap is at
    # least 5 x 5: one fits, two do not, at any scale. The run is refused before the triangle-wise stage.
    reset_blender_scene()
    first = textured_grid("first", image_size=(8, 8), uv_scale=0.4, uv_offset=0.05)
    second = textured_grid("second", uv_scale=0.4, uv_offset=0.55, location=(2.0, 0.0, 0.0))
    second.material_slots[0].material = first.material_slots[0].material
    objects = [first, second]
    before = state(objects)
    stages = []
    with pytest.raises(ValueError, match=r"the 2 UV islands do not fit a 8 x 8 px image with a 4 px margin at any "
                                         r"scale \(it holds 1\): lower the margin") as error:
        for progress in optimize_objects(objects, SETTINGS):
            stages.append(progress.stage)
    assert "read" in stages and "triangle" not in stages
    assert state(objects) == before and "\n" not in str(error.value)
    # with a 1 px margin (bitmaps of 3 x 3 at least) both fit
    result = optimized(objects, dataclasses.replace(SETTINGS, margin=1))
    assert list(result.image.size) == result.report["resolution"] == [8, 8]


def test_part_of_the_uv_map_collapsed_to_a_point():
    # As on parts of some glTF assets: a few faces' UVs all at one point, the rest unwrapped.
    obj = textured_grid("partial", k=4)
    mesh = obj.data
    uv = np.empty((len(mesh.loops), 2), dtype=np.float32)
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv.ravel())
    for polygon in (0, 5):
        uv[list(mesh.polygons[polygon].loop_indices)] = 0.95
    mesh.uv_layers["UVMap"].uv.foreach_set("vector", uv.ravel())
    result = optimized([obj])
    assert result.report["skipped_triangles"] == 4
    new = new_uv_per_triangle(obj)
    assert np.all(np.isfinite(new)) and new.min() >= 0 and new.max() <= 1


def test_non_manifold_edge_loose_vertex_and_loose_edge():
    import bmesh

    obj = textured_grid("messy", k=3)
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bm.verts.ensure_lookup_table()
    a, b = bm.verts[5], bm.verts[6]  # an interior edge of the grid, already shared by two faces
    fin = bm.faces.new((a, b, bm.verts.new((0.5, 0.5, 1.0))))  # a third face on it: non-manifold
    loose = bm.verts.new((3.0, 3.0, 3.0))
    bm.edges.new((loose, bm.verts.new((4.0, 3.0, 3.0))))  # a loose edge, and a loose vertex below
    bm.verts.new((5.0, 5.0, 5.0))
    uv_layer = bm.loops.layers.uv["UVMap"]
    for loop, corner in zip(fin.loops, ((0.05, 0.05), (0.3, 0.05), (0.15, 0.3))):
        loop[uv_layer].uv = corner
    bm.to_mesh(obj.data)
    bm.free()
    non_manifold = [edge for edge in obj.data.edges if sum(edge.key == key for p in obj.data.polygons
                                                            for key in p.edge_keys) > 2]
    assert len(non_manifold) == 1
    result = optimized([obj])
    assert result.report["faces"] == 19 and result.report["vertices"] == 16 + 4


def test_mirroring_object_transform():
    obj = textured_grid()
    obj.scale = (-1.0, 1.0, 1.0)
    bpy.context.view_layer.update()
    result = optimized([obj])
    assert result.report["skipped_triangles"] == 0


def test_linked_duplicates_are_optimized_once():
    obj = textured_grid()
    twin = obj.copy()  # shares obj.data
    twin.location = (2, 0, 0)
    bpy.context.scene.collection.objects.link(twin)
    result = optimized([obj, twin])
    assert result.report["objects"] == ["grid"] and result.report["faces"] == 18
    assert any("shares mesh 'grid' with 'grid'" in note for note in result.report["notes"])
    assert [layer.name for layer in twin.data.uv_layers] == ["UVMap", "PerceptualUV"]


def test_full_set_of_uv_maps_is_refused_before_the_run():
    obj = textured_grid()
    for index in range(7):
        obj.data.uv_layers.new(name=f"extra{index}")
    refused([obj], match="already has 8 UV maps")


# ---------------------------------------------------------------------------------------------------- faults
def test_cancel_after_saving_removes_the_image_file(tmp_path):
    obj = textured_grid()
    before = state([obj])
    run = optimize_objects([obj], SETTINGS, output_dir=str(tmp_path))
    for progress in run:
        if progress.stage == "done":  # the last step: the image is saved already
            break
    assert [p.name for p in tmp_path.iterdir()] == ["grid_texture_perceptual.png"]
    run.close()
    assert list(tmp_path.iterdir()) == [] and state([obj]) == before


def test_an_existing_image_file_is_never_overwritten(tmp_path):
    (tmp_path / "grid_texture_perceptual.png").write_bytes(b"someone else's file")
    result = optimized([textured_grid()], output_dir=str(tmp_path))
    assert result.report["image_file"] == str(tmp_path / "grid_texture_perceptual.001.png")
    assert (tmp_path / "grid_texture_perceptual.png").read_bytes() == b"someone else's file"

def test_failed_image_save_keeps_the_result_and_warns(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    obj = textured_grid()
    result = optimized([obj], output_dir=str(blocker / "images"))
    assert result.image.name in bpy.data.images and result.image.packed_file is not None
    (warning,) = result.report["warnings"]
    assert "could not save the image" in warning and "packed into the .blend" in warning
    assert result.report["image_file"] is None
    assert result.uv_map in obj.data.uv_layers


def test_operator_reports_the_refusal_instead_of_raising():
    import perceptual_uv

    perceptual_uv.register()
    try:
        obj = textured_grid(image_size=(1, 1))
        before = state([obj])
        # Headless, Blender turns an operator's ERROR report into a RuntimeError carrying the message.
        with pytest.raises(RuntimeError, match="1 x 1 pixels") as error:
            bpy.ops.uv.perceptual_optimize("EXEC_DEFAULT", **FAST)
        assert "Traceback" not in str(error.value)
        assert state([obj]) == before
    finally:
        perceptual_uv.unregister()


@pytest.mark.parametrize("stage", ["read", "triangle", "mesh", "pack", "bake", "loss", "done"])
def test_error_at_any_stage_leaves_nothing(monkeypatch, stage):
    """An exception thrown into the run at each stage (as a cancel or a fault would) removes what it made."""
    obj = textured_grid()
    before = state([obj])
    run = optimize_objects([obj], SETTINGS)
    for progress in run:
        if progress.stage == stage:
            break
    with pytest.raises(KeyboardInterrupt):
        run.throw(KeyboardInterrupt)
    assert state([obj]) == before


def test_save_error_message_is_one_line_for_a_missing_drive():
    # A folder that can never be created: the warning is one sentence, not Blender's multi-line error dump.
    obj = textured_grid()
    path = os.path.join(os.sep, "proc", "perceptual_uv_cannot_write_here")
    result = optimized([obj], output_dir=path)
    (warning,) = result.report["warnings"]
    assert "\n" not in warning and path in warning


# ---------------------------------------------------------------------------------------------------- CLI
def saved_blend(path, obj):
    for image in bpy.data.images:
        if image.has_data and image.packed_file is None:
            image.pack()
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def assert_one_line_refusal(result, *needles):
    assert result.returncode == 2, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("perceptual_uv: error: ")
    for needle in needles:
        assert needle in last


def test_cli_refuses_a_collapsed_uv_map_in_one_line(tmp_path):
    from test_cli_optimize import FAST_ARGS, run_cli

    obj = textured_grid()
    obj.data.uv_layers["UVMap"].uv.foreach_set("vector", np.zeros(2 * len(obj.data.loops), np.float32))
    blend = saved_blend(tmp_path / "in.blend", obj)
    out = tmp_path / "out" / "o.blend"
    result = run_cli("optimize", str(blend), "--out", str(out), *FAST_ARGS)
    assert_one_line_refusal(result, "collapsed to a point")
    assert list(out.parent.iterdir()) == []


def test_cli_refuses_an_unwritable_output_folder_before_running(tmp_path):
    from test_cli_optimize import FAST_ARGS, run_cli

    blend = saved_blend(tmp_path / "in.blend", textured_grid())
    (tmp_path / "file").write_text("a file, not a folder")
    result = run_cli("optimize", str(blend), "--out", str(tmp_path / "file" / "o.blend"), *FAST_ARGS)
    assert_one_line_refusal(result, "cannot write into the output folder", str(tmp_path / "file"))
    assert "[read]" not in result.stderr  # refused before the model was even opened


# ---------------------------------------------------------------------------------------------------- modal operator
class _Recorder:
    """Stands in for the window manager, workspace and operator reports of a modal run."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *args, **kwargs: self.calls.append((name, args))


def modal_operator(pipeline):
    from types import SimpleNamespace

    from perceptual_uv.operators.optimize_uvs import UV_OT_perceptual_optimize as Operator

    class FakeOperator:
        modal, _end_modal, _restore_mode = Operator.modal, Operator._end_modal, Operator._restore_mode
        _finish = Operator._finish

        def __init__(self):
            self._pipeline, self._timer, self._previous_mode = pipeline, "timer", "OBJECT"
            self.reports = []

        def report(self, kind, message):
            self.reports.append((set(kind), message))

    recorder = _Recorder()
    context = SimpleNamespace(window_manager=recorder, workspace=recorder)
    return FakeOperator(), context, recorder


def test_modal_run_ends_cleanly_on_an_internal_failure():
    def failing():
        yield pipeline.Progress("triangle", 0, 1, "working")
        raise RuntimeError("worker lost")

    operator, context, recorder = modal_operator(failing())
    from types import SimpleNamespace

    assert operator.modal(context, SimpleNamespace(type="TIMER")) == {"CANCELLED"}
    (kind, message), = operator.reports
    assert kind == {"ERROR"} and "RuntimeError: worker lost" in message and "nothing was changed" in message
    names = [name for name, _ in recorder.calls]
    assert "event_timer_remove" in names and "progress_end" in names and ("status_text_set", (None,)) in recorder.calls


def test_modal_escape_during_the_triangle_stage_leaves_nothing():
    from types import SimpleNamespace

    obj = textured_grid()
    before = state([obj])
    run = optimize_objects([obj], SETTINGS)
    for progress in run:
        if progress.stage == "triangle":
            break
    operator, context, recorder = modal_operator(run)
    assert operator.modal(context, SimpleNamespace(type="ESC")) == {"CANCELLED"}
    assert operator.reports == [({"WARNING"}, "Optimize UVs cancelled; nothing was changed")]
    assert state([obj]) == before
    assert "event_timer_remove" in [name for name, _ in recorder.calls]


# ---------------------------------------------------------------------------------------------------- real assets
@pytest.mark.slow
def test_water_bottle_with_zero_area_uv_triangles(shared_models_dir):
    """WaterBottle (glTF) has 80 UV triangles of zero area: skipped, said so, and the rest is flip-free."""
    from perceptual_uv.bridge.mesh_io import import_model

    objects = [obj for obj in import_model(shared_models_dir / "WaterBottle" / "WaterBottle.gltf")
               if obj.type == "MESH"]
    result = optimized(objects, OptimizeSettings(**FAST, cost_measure="texels"))  # the paper's cost, checked below
    report = result.report
    assert report["skipped_triangles"] == 80 and report["optimized_triangles"] == report["faces"] - 80
    assert any("80 of 4510 triangles have zero area in UV map" in note for note in report["notes"])
    assert abs(report["relative_cost"] - FAST["target_cost"]) <= 0.05 * FAST["target_cost"]


def test_an_operator_run_reads_a_png_texture_without_blender_loading_it(tmp_path):
    """With the bake in a background process (the modal operator's setting) the run decodes the texture's file in a
    thread and takes its size from the header: Blender's copy of the image is never loaded in this process."""
    from PIL import Image

    rgb = (np.random.default_rng(5).random((64, 64, 3)) * 255).astype(np.uint8)
    Image.fromarray(rgb, "RGB").save(tmp_path / "texture.png")
    image = bpy.data.images.load(str(tmp_path / "texture.png"))
    obj = textured_grid(image=image)
    settings = dataclasses.replace(SETTINGS, bake_in_background=True)
    result = run_to_end(optimize_objects([obj], settings, output_dir=str(tmp_path / "out")))
    assert not image.has_data
    (entry,) = result.report["maps"]
    assert entry["input_size"] == [64, 64] and entry["raw_bytes_before"] == 64 * 64 * 3
    assert result.uv_map in obj.data.uv_layers and os.path.isfile(entry["new_image_file"])


def test_the_operator_optimizes_every_selected_texture_in_one_run(tmp_path):
    from types import SimpleNamespace

    from perceptual_uv.bridge.texture_sets import iter_optimize_textures
    from perceptual_uv.operators.optimize_uvs import _objects

    first = textured_grid("first")
    sharing = textured_grid("sharing", image=first.material_slots[0].material.node_tree.nodes["Image Texture"].image,
                            location=(2.0, 0.0, 0.0))
    other = textured_grid("other", location=(4.0, 0.0, 0.0))
    assert _objects(SimpleNamespace(active_object=first, selected_objects=[other, first, sharing])) == [
        first, other, sharing]

    runs = run_to_end(iter_optimize_textures([first, other, sharing], SETTINGS, output_dir=str(tmp_path)))

    assert [(objects, result.report["objects"]) for objects, result in runs] == [
        ([first, sharing], ["first", "sharing"]), ([other], ["other"])]
    for obj in (first, sharing, other):
        assert "PerceptualUV" in obj.data.uv_layers
    assert runs[0][1].image != runs[1][1].image


def test_a_cancel_in_the_second_texture_removes_what_the_first_made(tmp_path):
    from perceptual_uv.bridge.texture_sets import iter_optimize_textures

    first = textured_grid("first")
    other = textured_grid("other", location=(2.0, 0.0, 0.0))
    before = (sorted(bpy.data.images.keys()), sorted(bpy.data.materials.keys()), sorted(bpy.data.objects.keys()),
              sorted(bpy.data.meshes.keys()))
    job = iter_optimize_textures([first, other], SETTINGS, output_dir=str(tmp_path))
    for progress in job:
        if progress.message.startswith("Texture 2 of 2") and progress.stage == "triangle":
            break
    assert "PerceptualUV" in first.data.uv_layers and list(tmp_path.iterdir())  # the first texture is done

    job.close()

    assert (sorted(bpy.data.images.keys()), sorted(bpy.data.materials.keys()), sorted(bpy.data.objects.keys()),
            sorted(bpy.data.meshes.keys())) == before
    assert [layer.name for layer in first.data.uv_layers] == ["UVMap"] == [layer.name for layer in other.data.uv_layers]
    assert [slot.material.name for slot in first.material_slots] == ["first_material"]
    assert list(tmp_path.iterdir()) == []


def test_texture_groups_frame_a_part_without_base_colour_by_its_own_largest_map():
    from perceptual_uv.bridge.texture_sets import texture_groups

    coloured = textured_grid("coloured")
    plain = textured_grid("plain", image_size=(32, 32), location=(2.0, 0.0, 0.0))
    tree = plain.material_slots[0].material.node_tree
    node = tree.nodes["Image Texture"]
    node.image.colorspace_settings.name = "Non-Color"
    for link in list(node.outputs["Color"].links):
        tree.links.remove(link)
    tree.links.new(node.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Roughness"])
    untextured = textured_grid("untextured", location=(4.0, 0.0, 0.0))
    untextured.data.materials[0] = bpy.data.materials.new("untextured_plain")
    second_uv = textured_grid("second_uv", location=(6.0, 0.0, 0.0))  # its only map read through another UV map
    second_uv.data.uv_layers.new(name="Other")
    tree = second_uv.material_slots[0].material.node_tree
    node = tree.nodes["Image Texture"]
    for link in list(node.outputs["Color"].links):
        tree.links.remove(link)
    tree.links.new(node.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Roughness"])
    uv_node = tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = "Other"
    tree.links.new(uv_node.outputs["UV"], node.inputs["Vector"])

    groups = texture_groups(bpy.context.scene.objects)

    assert [(image.name, objects) for image, objects in groups] == [
        ("coloured_texture", [coloured]), ("plain_texture", [plain])]
