"""Optimize UVs end to end on a patch of the bundled model, with fast settings (issue 5, item 8)."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
bmesh = pytest.importorskip("bmesh")

import perceptual_uv  # noqa: E402
from perceptual_uv.bridge.loss_overlay import LOSS_ATTRIBUTE  # noqa: E402
from perceptual_uv.bridge.pipeline import optimize_objects  # noqa: E402
from perceptual_uv.core.cost import relative_cost  # noqa: E402
from perceptual_uv.core.settings import OptimizeSettings  # noqa: E402

from conftest import reset_blender_scene  # noqa: E402  (tests/ is on sys.path under pytest)

pytestmark = pytest.mark.bpy
FAST = dict(iterations=10, screen_pixels=32, max_screen_pixels=32, workers=1, target_cost=0.3)
ID_KINDS = ("objects", "meshes", "materials", "images", "scenes")


def spot_patch(spot_obj, *, above=0.9):
    """The bundled spot cut to the faces above a height: a real textured patch of ~700 triangles."""
    reset_blender_scene()
    bpy.ops.wm.obj_import(filepath=str(spot_obj))
    obj = bpy.context.selected_objects[0]
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bmesh.ops.delete(bm, geom=[f for f in bm.faces if f.calc_center_median().z < above], context="FACES")
    bm.to_mesh(obj.data)
    bm.free()
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def snapshot(obj):
    mesh = obj.data
    uv = np.empty(2 * len(mesh.loops), dtype=np.float32)
    mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv)
    co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    image = bpy.data.images["spot_texture.png"]
    pixels = np.empty(len(image.pixels), dtype=np.float32)
    image.pixels.foreach_get(pixels)
    return {"uv": uv, "co": co, "pixels": pixels, "uv_layers": [layer.name for layer in mesh.uv_layers],
            "attributes": sorted(a.name for a in mesh.attributes),
            "materials": [slot.material.name for slot in obj.material_slots],
            "ids": {kind: len(getattr(bpy.data, kind)) for kind in ID_KINDS}}


def assert_unchanged(obj, before):
    after = snapshot(obj)
    for key in ("uv", "co", "pixels"):
        np.testing.assert_array_equal(after[key], before[key])
    for key in ("uv_layers", "attributes", "materials", "ids"):
        assert after[key] == before[key], key


@pytest.fixture(scope="module")
def registered():
    perceptual_uv.register()
    yield
    perceptual_uv.unregister()


@pytest.fixture(scope="module")
def optimized(registered, spot_obj):
    obj = spot_patch(spot_obj)
    before = snapshot(obj)
    bpy.ops.ed.undo_push(message="before Optimize UVs")
    # The second argument asks for the undo push that a click in the UI makes. The paper's texel cost (Eq. 21):
    # test_new_uv_map_is_packed_and_meets_the_cost checks it.
    result = bpy.ops.uv.perceptual_optimize("EXEC_DEFAULT", True, **FAST, cost_measure="texels")
    return obj, before, result


def test_operator_adds_uv_map_image_and_loss_attribute(optimized):
    obj, before, result = optimized
    assert result == {"FINISHED"}
    mesh = obj.data
    assert [layer.name for layer in mesh.uv_layers] == ["UVMap", "PerceptualUV"]
    assert mesh.uv_layers.active.name == "UVMap"
    image = bpy.data.images["spot_texture_perceptual"]
    assert min(image.size) >= 8
    assert image.packed_file is not None  # the file is unsaved: the image travels inside it
    assert LOSS_ATTRIBUTE in mesh.attributes
    losses = np.empty(len(mesh.polygons), dtype=np.float32)
    mesh.attributes[LOSS_ATTRIBUTE].data.foreach_get("value", losses)
    assert np.all(losses >= 0) and np.all(np.isfinite(losses))
    slot = obj.material_slots[0]
    assert slot.link == "OBJECT" and slot.material.name == "spot_perceptual"
    assert mesh.materials[0].name == "spot"  # the mesh's own material list is untouched


def test_originals_are_bit_identical(optimized):
    obj, before, _ = optimized
    after = snapshot(obj)
    for key in ("uv", "co", "pixels"):
        np.testing.assert_array_equal(after[key], before[key])
    assert bpy.data.images["spot_texture.png"].colorspace_settings.name == "sRGB"
    assert bpy.data.materials["spot"].node_tree.nodes["Image Texture"].image.name == "spot_texture.png"


def test_new_uv_map_is_packed_and_meets_the_cost(optimized):
    obj, before, _ = optimized
    mesh = obj.data
    mesh.calc_loop_triangles()
    loops = np.empty(3 * len(mesh.loop_triangles), dtype=np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    per_loop = {}
    for name in ("UVMap", "PerceptualUV"):
        uv = np.empty(2 * len(mesh.loops))
        mesh.uv_layers[name].uv.foreach_get("vector", uv)
        per_loop[name] = uv.reshape(-1, 2)[loops.reshape(-1, 3)]
    new = per_loop["PerceptualUV"]
    assert new.min() >= 0 and new.max() <= 1
    size = tuple(bpy.data.images["spot_texture_perceptual"].size)
    cost = relative_cost(new, size, reference_uv=per_loop["UVMap"], reference_resolution=1024)
    assert abs(cost - FAST["target_cost"]) <= 0.05 * FAST["target_cost"]


def test_undo_restores_the_file(optimized):
    obj, before, _ = optimized
    bpy.ops.ed.undo()
    obj = bpy.data.objects["spot_triangulated"]
    assert_unchanged(obj, before)


STAGES = ("read", "triangle", "mesh", "pack", "bake", "loss", "done")


@pytest.mark.parametrize("stages", [
    ("triangle", "done"),  # before anything is written; after everything is
    pytest.param(STAGES, marks=pytest.mark.slow),
])
def test_cancel_leaves_nothing(registered, spot_obj, stages):
    obj = spot_patch(spot_obj, above=1.0)
    before = snapshot(obj)
    stages_seen = []
    for cancel_at in stages:
        run = optimize_objects([obj], OptimizeSettings(**FAST))
        for progress in run:
            if progress.stage == cancel_at:
                stages_seen.append(cancel_at)
                break
        run.close()
        assert_unchanged(obj, before)
    assert tuple(stages_seen) == stages


def test_reading_and_signal_stretch_hand_control_back_step_by_step(registered, spot_obj):
    """Driven one step at a time as the modal operator drives it, the run reads in several parts, builds the
    loss's planes a band of texture rows per step, measures the texture's signal stretch a slice of faces per
    step, counting up to every face, and packs a chart's bitmaps or a try per step."""
    import re

    obj = spot_patch(spot_obj, above=1.0)
    steps = [(progress.stage, progress.message) for progress in optimize_objects([obj], OptimizeSettings(**FAST))]
    reads = [message for stage, message in steps if stage == "read"]
    parts = ["Reading the mesh", "Loading the texture", "Reading the texture's pixels", "Checking the mesh and texture",
             "Reading the material's maps", "Looking for the results of an earlier run"]
    # A part that waits on a thread (the pixels' decode) repeats its message every 0.1 s while it waits.
    assert list(dict.fromkeys(message for message in reads if message in parts)) == parts
    planes = [message for message in reads if message.startswith("Building the loss's planes: ")]
    assert len(planes) >= 2 and planes[-1].startswith("Building the loss's planes: 1/1")
    signal = [re.search(r": (\d+)/(\d+)", message) for stage, message in steps
              if message.startswith("Measuring the texture's signal stretch")]
    done = [int(match[1]) for match in signal]
    assert len(signal) > 2 and done == sorted(done) and done[0] < done[-1] == int(signal[-1][2])
    assert len(obj.data.polygons) == done[-1]  # every face of the patch has surface area
    # One step before packing, then one per chart's bitmaps and per try (at least the patch's one chart and one
    # strip at each of the two densities the image-memory cost's fixed side needs).
    assert sum(stage == "pack" for stage, _ in steps) >= 1 + 2 * 2


def test_the_mesh_wise_stage_moves_the_bar_through_each_of_its_parts(registered, spot_obj):
    """Each part of the mesh-wise stage counts its own units in its line, and the stage's fraction is the shares
    of the parts before it plus its share times its count (bridge.meshwise_stage.PART_SHARES): the signal stretch
    counting every face does not take the bar to the stage's end, and the loss pass of the targets and both fits,
    which ends the stage, has lines of its own counting the optimized faces."""
    import re

    from perceptual_uv.bridge.meshwise_stage import PART_SHARES

    obj = spot_patch(spot_obj, above=1.0)
    run, steps = optimize_objects([obj], OptimizeSettings(**FAST)), []
    while True:
        try:
            steps.append(next(run))
        except StopIteration as finished:
            report = finished.value.report
            break
    mesh = [step for step in steps if step.stage == "mesh"]
    shares = list(PART_SHARES.values())
    before_loss_pass = sum(shares[:list(PART_SHARES).index("loss pass")]) / sum(shares)
    signal = [step for step in mesh if step.message.startswith("Measuring the texture's signal stretch: ")]
    assert signal and all(step.done / step.total <= shares[0] / sum(shares) + 1e-3 for step in signal)
    passes = [step for step in mesh if step.message.startswith("Measuring the loss of the targets and both fits: ")]
    counts = [tuple(map(int, re.search(r": (\d+)/(\d+)", step.message).groups())) for step in passes]
    assert counts[-1] == (report["optimized_triangles"], report["optimized_triangles"])
    for step, (done, total) in zip(passes, counts):
        expected = before_loss_pass + PART_SHARES["loss pass"] / sum(shares) * done / total
        assert step.total == 1000 and step.done == round(1000 * expected)
    fractions = [step.done / step.total for step in mesh]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    # The run's bar: short of the stage's end until the loss pass is done.
    assert passes[0].fraction < mesh[-1].fraction


def test_the_largest_view_reaches_both_triangle_wise_calls(registered, spot_obj, monkeypatch):
    from perceptual_uv.bridge.pipeline import run_to_end
    from perceptual_uv.core import loss_passes, trianglewise

    seen = {}

    def recording(function):
        def wrapper(*args, **kwargs):
            seen[function.__name__] = kwargs.get("max_screen_pixels")
            return function(*args, **kwargs)
        return wrapper

    # The optimization; the targets' and fits' losses, and the pass that measures them.
    calls = ((trianglewise, "iter_optimize_triangles"), (loss_passes, "iter_fit_losses"),
             (loss_passes, "iter_losses_of"))
    names = [name for _, name in calls]
    for module, name in calls:
        monkeypatch.setattr(module, name, recording(getattr(module, name)))
    obj = spot_patch(spot_obj, above=1.0)
    run_to_end(optimize_objects([obj], OptimizeSettings(**dict(FAST, screen_pixels=16, max_screen_pixels=24))))
    assert seen == dict.fromkeys(names, 24)


def test_an_image_the_islands_barely_cover_is_reported(registered, spot_obj, tmp_path):
    """The patch's input UVs squeezed to a fiftieth in v: its islands become strips that pack into a sliver
    of the square image, which then holds many times the texels the cost counts."""
    from perceptual_uv.bridge.pipeline import run_to_end

    obj = spot_patch(spot_obj, above=1.0)
    uv = np.empty(2 * len(obj.data.loops))
    obj.data.uv_layers["UVMap"].uv.foreach_get("vector", uv)
    uv = uv.reshape(-1, 2)
    uv[:, 1] = uv[:, 1].min() + 0.02 * (uv[:, 1] - uv[:, 1].min())
    obj.data.uv_layers["UVMap"].uv.foreach_set("vector", uv.ravel())
    report = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST), output_dir=str(tmp_path))).report
    assert report["image_coverage"] < 0.25
    notes = [note for note in report["notes"] if "cover" in note]
    assert len(notes) == 1 and f"{report['image_coverage']:.0%} of the" in notes[0]


def test_report_fields(registered, spot_obj, tmp_path):
    from perceptual_uv.bridge.pipeline import run_to_end

    obj = spot_patch(spot_obj, above=1.0)
    settings = OptimizeSettings(**FAST, cost_measure="texels")  # the paper's cost, checked below
    result = run_to_end(optimize_objects([obj], settings, output_dir=str(tmp_path)))
    report = result.report
    for key in ("faces", "vertices", "epsilon", "target_cost", "resolution", "relative_cost", "times_s",
                "flipped_triangles", "triangles_within_bound", "uv_map", "image"):
        assert key in report
    assert set(report["times_s"]) == {"triangle", "mesh", "pack", "bake", "total"}
    assert report["faces"] == len(obj.data.loop_triangles)
    assert report["flipped_triangles"] == 0
    overlaps = report["overlapping_pairs"]
    assert overlaps["total"] == overlaps["within_charts"] + overlaps["between_charts"] >= 0
    # no island overlaps itself more than the input did: folded charts get their input layout back
    from perceptual_uv.bridge.mesh_io import read_mesh
    from perceptual_uv.core.charts import uv_topology
    from perceptual_uv.core.overlap import count_overlaps

    source = read_mesh(obj, uv_name=report["source_uv_map"])
    before = count_overlaps(source.uv, uv_topology(source.F, source.uv).face_chart)
    assert overlaps["within_charts"] <= before.within_charts
    assert report["restored_charts"] >= 0
    assert 0 <= report["triangles_within_bound"] <= 1
    # issue 22: the bound measured on the textured triangles, at the fit's targets and after the fit; every
    # textured triangle above it is an optimized triangle above it
    bound = report["textured_above_bound"]
    assert set(bound) == {"textured_triangles", "targets", "fit"}
    assert 0 <= bound["textured_triangles"] <= report["optimized_triangles"]
    assert 0 <= bound["targets"] <= 1 and 0 <= bound["fit"] <= 1
    above = round(bound["fit"] * bound["textured_triangles"])
    assert above <= round((1 - report["triangles_within_bound"]) * report["optimized_triangles"])
    assert report["unevaluated_triangles"] == 0
    assert abs(report["relative_cost"] - 0.3) <= 0.015
    # the fraction of the image the packed islands cover: their UV area, read back from the new map
    new = read_mesh(obj, uv_name=report["uv_map"]).uv
    e1, e2 = new[:, 1] - new[:, 0], new[:, 2] - new[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    assert report["image_coverage"] == pytest.approx(area, rel=1e-9) and 0.25 < area <= 1
    assert not any("cover" in note for note in report["notes"])
    assert (tmp_path / "spot_texture_perceptual.png").is_file() and report["image_file"].startswith(str(tmp_path))


# --- the cost a user sets: image memory (issue 23, item 5) ---------------------------------------------------

def test_the_default_cost_is_the_images_memory(registered, spot_obj, tmp_path):
    """At the default measure the 1024 x 1024 input at cost 0.3 gives a 561 x 561 image (sqrt(0.3) * 1024 =
    560.87), the islands packed to fill it; the report's memory ratio is the cost within that rounding, and its
    relative cost stays the paper's texel cost of the saved map."""
    from perceptual_uv.bridge.mesh_io import read_mesh
    from perceptual_uv.bridge.pipeline import run_to_end

    obj = spot_patch(spot_obj, above=1.0)
    assert OptimizeSettings(**FAST).cost_measure == "memory"
    square = OptimizeSettings(**dict(FAST, square_images=True))
    report = run_to_end(optimize_objects([obj], square, output_dir=str(tmp_path))).report
    assert report["cost_measure"] == "memory" and report["target_cost"] == 0.3
    assert report["resolution"] == [561, 561] and bpy.data.images[report["image"]].size[:] == (561, 561)
    assert report["maps"][0]["new_size"] == [561, 561] and report["maps"][0]["input_size"] == [1024, 1024]
    assert report["memory_ratio"] == pytest.approx(561 ** 2 / 1024 ** 2, rel=1e-12)
    assert abs(report["memory_ratio"] - 0.3) <= (2 * 561 + 1) / 1024 ** 2  # one pixel of side either way
    new = read_mesh(obj, uv_name=report["uv_map"]).uv
    source = read_mesh(obj, uv_name=report["source_uv_map"]).uv
    assert new.min() >= 0 and new.max() <= 1 and report["image_coverage"] > 0.25
    assert report["relative_cost"] == pytest.approx(relative_cost(new, 561, reference_uv=source,
                                                                  reference_resolution=1024), rel=1e-6)
    # the patch uses a sliver of the input image: 0.3 of its memory holds far more texels than it had, said so
    assert report["relative_cost"] > 1
    (note,) = [note for note in report["notes"] if "texel density" in note]
    assert f"{report['relative_cost']:.2f} times the input's texels" in note


def test_the_new_images_take_the_shape_that_holds_the_islands_densest(registered, spot_obj, tmp_path):
    from perceptual_uv.bridge.pipeline import run_to_end
    from perceptual_uv.core.packing import IMAGE_ASPECTS, image_sizes

    square = run_to_end(optimize_objects([spot_patch(spot_obj, above=1.0)],
                                         OptimizeSettings(**dict(FAST, square_images=True)),
                                         output_dir=str(tmp_path))).report
    shaped = run_to_end(optimize_objects([spot_patch(spot_obj, above=1.0)], OptimizeSettings(**FAST),
                                         output_dir=str(tmp_path))).report
    width, height = shaped["resolution"]
    assert width != height  # this patch's islands fill a 1:2 image best (397 x 792, coverage 0.59 against 0.44)
    # 0.3 of the 1024 px image's memory: at most 561 x 561 pixels, in one of the shapes the packing tries
    assert (width, height) in image_sizes(561, IMAGE_ASPECTS) and width * height <= 561 ** 2
    assert bpy.data.images[shaped["image"]].size[:] == (width, height)
    assert shaped["maps"][0]["new_size"] == [width, height]
    assert shaped["memory_ratio"] == pytest.approx(width * height / 1024 ** 2, rel=1e-12)
    # the square is one of the shapes tried, so the chosen shape holds the same islands at least as densely
    assert shaped["relative_cost"] >= square["relative_cost"] * (1 - 1e-6)
    assert shaped["image_coverage"] >= square["image_coverage"] * (1 - 1e-6)


def test_an_explicit_resolution_wins_over_either_measure(registered, spot_obj, tmp_path):
    from perceptual_uv.bridge.pipeline import run_to_end

    obj = spot_patch(spot_obj, above=1.0)
    settings = OptimizeSettings(**dict(FAST, resolution=96))
    report = run_to_end(optimize_objects([obj], settings, output_dir=str(tmp_path))).report
    assert report["resolution"] == [96, 96] and report["cost_measure"] is None and report["target_cost"] is None


def test_the_sidebar_fields_become_settings(registered):
    from perceptual_uv.properties import ROLE_COST_FIELDS, settings_from

    reset_blender_scene()
    props = bpy.context.scene.perceptual_uv
    assert props.cost_measure == "memory" and settings_from(props).cost_measure == "memory"
    assert settings_from(props).role_costs == ()  # every per-map field 0: the Relative Cost
    assert {role for _, role, _ in ROLE_COST_FIELDS} == {"normal", "metallic_roughness", "emissive", "occlusion",
                                                         "alpha", "data"}
    props.cost_measure = "texels"
    props.cost_normal = 0.0625
    props.cost_emissive = 0.5
    settings = settings_from(props)
    assert settings.cost_measure == "texels"
    assert settings.role_costs == (("normal", 0.0625), ("emissive", 0.5))
    # the operator carries the same fields (redo panel, scripts)
    assert {"cost_measure", *(name for name, _, _ in ROLE_COST_FIELDS)} <= set(
        bpy.ops.uv.perceptual_optimize.get_rna_type().properties.keys())


class _Layout:
    """Records what a panel's draw puts in its layout (headless Blender cannot draw)."""

    def __init__(self, drawn):
        self.drawn = drawn

    def __getattr__(self, name):
        if name in ("column", "row", "box"):
            return lambda *args, **kwargs: self
        if name == "panel":
            return lambda idname, **kwargs: (self, self)
        if name in ("prop", "label", "operator"):
            return lambda *args, **kwargs: self.drawn.append((name, args[1] if name == "prop" else kwargs)) or self
        raise AttributeError(name)

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)


def test_the_sidebar_shows_the_measure_and_a_cost_per_kind_of_map(registered):
    from types import SimpleNamespace

    from perceptual_uv.panels.uv_sidebar import IMAGE_PT_perceptual_uv
    from perceptual_uv.properties import ROLE_COST_FIELDS

    reset_blender_scene()
    drawn = []
    panel = SimpleNamespace(layout=_Layout(drawn))
    IMAGE_PT_perceptual_uv.draw(panel, SimpleNamespace(scene=bpy.context.scene))
    props = [what for kind, what in drawn if kind == "prop"]
    costs = [name for name, _, _ in ROLE_COST_FIELDS]
    assert props[props.index("target_cost") + 1] == "cost_measure"
    assert props[props.index("cost_measure") + 1:props.index("cost_measure") + 1 + len(costs)] == costs
    assert ("label", {"text": "Per-Map Costs"}) in drawn


def test_islands_laid_on_the_same_texels_stay_stacked_unless_unstacked(registered, spot_obj, tmp_path):
    """The patch's second half of triangles laid on the UVs of its first half: every covered texel is used about
    twice. By default the two halves stay stacked (core.stacks): the new UV map lays them on the same texels
    too, its texel reuse is the input's, and the report says so. Unstacked, every triangle gets texels of its own
    (reuse about 1), and the report says the new map needs about twice the memory for the input's texel
    density. The patch's own UVs share nothing (reuse about 1, no note)."""
    from perceptual_uv.bridge.pipeline import run_to_end

    obj = spot_patch(spot_obj, above=1.0)
    report = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST), output_dir=str(tmp_path / "a"))).report
    assert abs(report["input_texel_reuse"] - 1.0) < 0.05
    assert report["stacked_charts"] == 0
    assert not [note for note in report["notes"] if "use each texel" in note or "stay stacked" in note]

    def laid_on_itself():
        obj = spot_patch(spot_obj, above=1.0)
        mesh = obj.data
        uv = np.empty(2 * len(mesh.loops))
        mesh.uv_layers["UVMap"].uv.foreach_get("vector", uv)
        uv = uv.reshape(-1, 2)
        polygons = list(mesh.polygons)
        half = len(polygons) // 2
        for first, second in zip(polygons[:half], polygons[half:2 * half]):
            assert first.loop_total == second.loop_total == 3
            uv[second.loop_start:second.loop_start + 3] = uv[first.loop_start:first.loop_start + 3]
        mesh.uv_layers["UVMap"].uv.foreach_set("vector", uv.ravel())
        return obj, half

    obj, half = laid_on_itself()
    result = run_to_end(optimize_objects([obj], OptimizeSettings(**FAST), output_dir=str(tmp_path / "b")))
    report = result.report
    assert 1.9 < report["input_texel_reuse"] < 2.1
    assert abs(report["texel_reuse"] - report["input_texel_reuse"]) < 0.05 * report["input_texel_reuse"]
    assert report["stacked_charts"] >= 2
    assert len([note for note in report["notes"] if "stay stacked" in note]) == 1
    assert not [note for note in report["notes"] if "use each texel" in note]
    new_uv = np.empty(2 * len(obj.data.loops))
    obj.data.uv_layers[result.uv_map].uv.foreach_get("vector", new_uv)
    new_uv = new_uv.reshape(-1, 3, 2)  # every polygon of the patch is a triangle
    np.testing.assert_allclose(new_uv[half:2 * half], new_uv[:half], atol=1e-6)
    # The halves cover their texels once: the image's covered fraction is the UV area of one half (and of the
    # rest of the patch, if any), counted in texels (within a few per cent at this size).
    e1, e2 = new_uv[:, 1] - new_uv[:, 0], new_uv[:, 2] - new_uv[:, 0]
    areas = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    once = areas.sum() - areas[half:2 * half].sum()
    assert report["image_coverage"] == pytest.approx(once, rel=0.05)

    obj, _ = laid_on_itself()
    settings = OptimizeSettings(**FAST, keep_stacks=False)
    report = run_to_end(optimize_objects([obj], settings, output_dir=str(tmp_path / "c"))).report
    assert report["stacked_charts"] == 0 and report["texel_reuse"] < 1.1
    notes = [note for note in report["notes"] if "use each texel" in note]
    assert len(notes) == 1 and f"{report['input_texel_reuse']:.1f} times on average" in notes[0]
    assert f"the new UV map's {report['texel_reuse']:.1f} times" in notes[0]
