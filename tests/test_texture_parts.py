"""Objects whose slots show several textures: split into one part per texture, results merged back."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import reset_blender_scene  # noqa: E402
from test_robustness import textured_grid  # noqa: E402

pytestmark = pytest.mark.bpy


def three_slot_grid():
    """A 2 x 2 grid of quads: slot 1 (faces 0, 3) shows one image, slot 2 (face 1) another, slot 3 (face 2) a
    material without an image."""
    reset_blender_scene()
    obj = textured_grid("mixed", k=2)
    other = textured_grid("other", k=2)
    obj.data.materials.append(other.data.materials[0])
    obj.data.materials.append(bpy.data.materials.new("untextured"))
    obj.data.polygons.foreach_set("material_index", np.array([0, 1, 2, 0], dtype=np.int32))
    obj.data.shade_smooth()  # the bumpy grid's vertex normals lean on every face around them
    bpy.data.objects.remove(other)
    return obj


def corner_uvs(mesh, name):
    uv = np.empty(2 * len(mesh.loops), dtype=np.float32)
    mesh.uv_layers[name].uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)


def test_one_part_per_texture_with_the_corners_faces_and_slots_it_came_from():
    from perceptual_uv.bridge.texture_parts import remove_parts, slot_textures, split_by_texture

    obj = three_slot_grid()
    textures = slot_textures(obj)
    assert [image.name if image else None for image in textures] == ["mixed_texture", "other_texture", None]

    first, second = split_by_texture(obj)

    assert (first.image, second.image) == (textures[0], textures[1])
    assert first.faces.tolist() == [0, 3] and second.faces.tolist() == [1]
    assert first.slots.tolist() == [0] and second.slots.tolist() == [1]
    # quads of 4 corners each, in face order: face 0 has corners 0-3, face 1 4-7, face 3 12-15
    assert first.corners.tolist() == [0, 1, 2, 3, 12, 13, 14, 15] and second.corners.tolist() == [4, 5, 6, 7]
    np.testing.assert_array_equal(corner_uvs(first.part.data, "UVMap"), corner_uvs(obj.data, "UVMap")[first.corners])
    assert [slot.material for slot in second.part.material_slots] == [obj.material_slots[1].material]
    for part in (first, second):  # smooth normals along the texture border as on the object, not just its side
        normals = np.empty(3 * len(part.corners), np.float32)
        part.part.data.corner_normals.foreach_get("vector", normals)
        original = np.empty(3 * len(obj.data.loops), np.float32)
        obj.data.corner_normals.foreach_get("vector", original)
        np.testing.assert_allclose(normals.reshape(-1, 3), original.reshape(-1, 3)[part.corners], atol=2e-4)
    assert len(obj.data.polygons) == 4 and len(obj.data.materials) == 3  # the object is left as it was
    assert split_by_texture(first.part) == []  # one texture: nothing to split
    remove_parts([first, second])
    assert [o.name for o in bpy.context.scene.objects] == ["mixed"]


def test_merge_writes_each_parts_uv_map_copies_and_overlay_onto_the_object():
    from perceptual_uv.bridge.loss_overlay import LOSS_ATTRIBUTE
    from perceptual_uv.bridge.texture_parts import merge_parts, split_by_texture

    obj = three_slot_grid()
    source = corner_uvs(obj.data, "UVMap")
    parts = split_by_texture(obj)
    copies = []
    for number, part in enumerate(parts):  # what a run leaves on a part
        mesh = part.part.data
        layer = mesh.uv_layers.new(name="PerceptualUV")
        layer.uv.foreach_set("vector", np.full(2 * len(mesh.loops), 0.1 * (number + 1), np.float32))
        mesh.attributes.new(LOSS_ATTRIBUTE, "FLOAT", "FACE").data.foreach_set(
            "value", np.full(len(mesh.polygons), 0.5 * (number + 1), np.float32))
        mesh.attributes.new("perceptual_loss_color", "BYTE_COLOR", "CORNER")
        copy = part.part.material_slots[0].material.copy()
        part.part.material_slots[0].link = "OBJECT"
        part.part.material_slots[0].material = copy
        copies.append(copy)

    merge_parts(parts, ["PerceptualUV", "PerceptualUV"], copies, source_uv="UVMap", epsilon=0.01)

    uv = corner_uvs(obj.data, "PerceptualUV")
    np.testing.assert_allclose(uv[[0, 1, 2, 3, 12, 13, 14, 15]], 0.1, rtol=1e-6)
    np.testing.assert_allclose(uv[4:8], 0.2, rtol=1e-6)
    np.testing.assert_array_equal(uv[8:12], source[8:12])  # the untextured face keeps its source coordinates
    np.testing.assert_array_equal(corner_uvs(obj.data, "UVMap"), source)
    losses = np.empty(4, np.float32)
    obj.data.attributes[LOSS_ATTRIBUTE].data.foreach_get("value", losses)
    np.testing.assert_allclose(losses, [0.5, 1.0, 0.0, 0.5])
    assert [(slot.link, slot.material) for slot in obj.material_slots[:2]] == [("OBJECT", copies[0]),
                                                                               ("OBJECT", copies[1])]
    assert obj.material_slots[2].link == "DATA" and obj.data.materials[0].name == "mixed_material"
    assert [o.name for o in bpy.context.scene.objects] == ["mixed"]
    assert not [mesh for mesh in bpy.data.meshes if mesh.name.endswith(".part")]


def test_a_slot_no_face_uses_makes_no_part():
    from perceptual_uv.bridge.texture_parts import split_by_texture

    obj = three_slot_grid()
    obj.data.polygons.foreach_set("material_index", np.array([0, 2, 2, 0], dtype=np.int32))

    assert split_by_texture(obj) == []


def test_a_runs_progress_is_relayed_as_its_share_of_the_whole_job():
    from perceptual_uv.bridge.pipeline import Progress
    from perceptual_uv.bridge.texture_sets import _relayed

    closed = []

    def run():
        try:
            for fraction in (0.0, 0.5, 1.0):
                yield Progress("triangle", 1, 2, "Triangle-wise optimization", fraction, 10.0)
        finally:
            closed.append(True)
        return "result"

    relayed = _relayed(run(), "Texture 2 of 2 ('b.png' on b): ", 30, 10, 40, started=0.0)
    steps = []
    with pytest.raises(StopIteration) as finished:
        while True:
            steps.append(next(relayed))

    assert finished.value.value == "result"
    assert [step.fraction for step in steps] == [0.75, 0.875, 1.0]  # 30 of 40 faces done before this run
    assert steps[0].message == "Texture 2 of 2 ('b.png' on b): Triangle-wise optimization"
    assert steps[-1].seconds_left == 0.0
    early = _relayed(run(), "", 0, 10, 40, started=0.0)
    next(early)
    early.close()
    assert closed == [True, True]  # closing the relay closes the run (which removes what it made)


def test_a_material_index_past_the_last_slot_counts_as_the_last_slot():
    from perceptual_uv.bridge.texture_parts import remove_parts, split_by_texture

    obj = three_slot_grid()
    obj.data.polygons.foreach_set("material_index", np.array([0, 1, 9, 0], dtype=np.int32))
    obj.data.materials[2] = obj.data.materials[1]  # the third slot shows the second texture too

    first, second = split_by_texture(obj)

    assert second.faces.tolist() == [1, 2] and second.slots.tolist() == [1, 2]
    index = np.empty(2, np.int32)
    second.part.data.polygons.foreach_get("material_index", index)
    assert index.tolist() == [0, 1]  # face 2 (index 9) on the part's slot of the object's third slot
    remove_parts([first, second])


def test_the_split_hands_control_back_within_each_part_and_a_cancel_removes_what_it_made():
    """A part copies its object's whole mesh (a few tenths of a second on a large one): the job hands control back
    to the interface three times while it makes a part and once after it, and closing it anywhere leaves the file
    as it was."""
    from perceptual_uv.bridge.texture_parts import remove_parts
    from perceptual_uv.bridge.texture_sets import iter_groups_and_parts

    obj = three_slot_grid()
    plain = textured_grid("plain", location=(3.0, 0.0, 0.0))  # one texture: nothing to split
    before = (sorted(bpy.data.objects.keys()), sorted(bpy.data.meshes.keys()))

    steps = iter_groups_and_parts([obj, plain])
    progress = []
    while True:
        try:
            step = next(steps)
        except StopIteration as finished:
            groups, parts = finished.value
            break
        progress.append((step.stage, step.done, step.total, step.message))
    # 3 steps inside each part (copied; read into a BMesh; the other faces dropped), then the part done
    assert progress == [("read", 0, 2, "Splitting 'mixed' by texture: 0/2")] * 3 + [
        ("read", 1, 2, "Splitting 'mixed' by texture: 1/2")] * 4 + [("read", 2, 2, "Splitting 'mixed' by texture: 2/2")]
    assert [p.part.name for p in parts] == ["mixed.mixed_texture.part", "mixed.other_texture.part"]
    assert sorted((image.name, [o.name for o in objects]) for image, objects in groups) == [
        ("mixed_texture", ["mixed.mixed_texture.part"]), ("other_texture", ["mixed.other_texture.part"]),
        ("plain_texture", ["plain"])]
    remove_parts(parts)
    assert (sorted(bpy.data.objects.keys()), sorted(bpy.data.meshes.keys())) == before

    for stop in range(len(progress)):  # a cancel at every step
        steps = iter_groups_and_parts([obj, plain])
        for _ in range(stop + 1):
            next(steps)
        steps.close()
        assert (sorted(bpy.data.objects.keys()), sorted(bpy.data.meshes.keys())) == before, stop
