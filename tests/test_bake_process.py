"""The maps baked in a background Blender process (issue 24, "Must show" item 5: Blender never freezes).

The child process bakes the same pixels as this process, bit for bit (synthetic PBR material with a base colour
using alpha, a packed ORM map, an emissive map and a tangent-space normal map, all generated images that exist
only in memory, on a turned target UV map; spot's file texture); driving the pipeline as the modal operator does
with the background bake on, no step of the bake stage takes longer than 0.25 s; closing the generator (Esc in
the modal operator) kills the child and removes its folder; a failing child gives a one-line error and leaves no
image behind.
"""
import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge import bake_process  # noqa: E402
from perceptual_uv.bridge.bake import bake_maps, iter_bake_maps  # noqa: E402
from perceptual_uv.bridge.material import base_color_image_node  # noqa: E402
from perceptual_uv.bridge.material_copy import read_maps  # noqa: E402
from perceptual_uv.bridge.pipeline import optimize_objects  # noqa: E402
from perceptual_uv.core.progress import run_generator  # noqa: E402
from perceptual_uv.core.settings import OptimizeSettings  # noqa: E402

from conftest import reset_blender_scene  # noqa: E402  (tests/ is on sys.path under pytest)
from test_bake_maps import pbr_grid, pixels_of  # noqa: E402
from test_optimize_end_to_end import FAST  # noqa: E402

pytestmark = pytest.mark.bpy
SPOT = pathlib.Path(__file__).parent / "data" / "spot" / "spot_triangulated.obj"
STEP_LIMIT = 0.25


def add_turned_uv(obj, name="Target"):
    """A copy of the object's "UVMap" (or first map) turned by 90 degrees and shrunk into [0.05, 0.95]^2: a new
    tangent frame for normal maps, and texels that fall between the source's."""
    mesh = obj.data
    source = mesh.uv_layers["UVMap"] if "UVMap" in mesh.uv_layers else mesh.uv_layers[0]
    uv = np.empty(2 * len(mesh.loops))
    source.uv.foreach_get("vector", uv)
    uv = uv.reshape(-1, 2)
    low, high = uv.min(axis=0), uv.max(axis=0)
    uv = (uv - low) / (high - low).max()
    mesh.uv_layers.new(name=name).uv.foreach_set("vector", np.stack([0.05 + 0.9 * uv[:, 1],
                                                                     0.95 - 0.9 * uv[:, 0]], 1).ravel())
    return source.name


def pbr_grid_with_alpha():
    obj = pbr_grid()
    image = base_color_image_node(obj.material_slots[0].material).image
    pixels = pixels_of(image).copy()
    pixels[..., 3] = np.random.default_rng(3).uniform(0.4, 1.0, pixels.shape[:2])
    image.pixels.foreach_set(pixels.ravel())
    return obj, image


def drive(generator):
    """Run ``generator`` to its end as the modal operator does; its value and (seconds, stage) per step, the
    time between two yields counted to the stage of the first."""
    steps, stage, started = [], "start", time.perf_counter()
    while True:
        try:
            progress = next(generator)
        except StopIteration as finished:
            steps.append((time.perf_counter() - started, stage))
            return finished.value, steps
        steps.append((time.perf_counter() - started, stage))
        stage = progress.stage if hasattr(progress, "stage") else "bake"
        started = time.perf_counter()


def assert_same_results(local, background):
    assert len(local) == len(background)
    for mine, theirs in zip(local, background):
        assert (mine.kind, mine.alpha, mine.image.is_float, mine.image.size[:]) == \
            (theirs.kind, theirs.alpha, theirs.image.is_float, theirs.image.size[:])
        assert mine.image.colorspace_settings.name == theirs.image.colorspace_settings.name
        np.testing.assert_array_equal(pixels_of(theirs.image), pixels_of(mine.image))


def test_the_background_bake_gives_the_pixels_of_this_process_bit_for_bit():
    obj, image = pbr_grid_with_alpha()
    source_uv = add_turned_uv(obj)
    records, _ = read_maps([obj], source_uv, image)
    assert [record.role for record in records] == ["base_color", "metallic_roughness", "normal_tangent", "emissive"]
    options = dict(source_uv=source_uv, target_uv="Target", resolutions=[64, 32, 64, 16], margin=2,
                   names=["base", "orm", "normal", "emissive"])
    local = bake_maps([obj], records, **options)
    background, steps = drive(iter_bake_maps([obj], records, in_background=True, **options))
    assert local[0].alpha and [result.kind for result in local] == ["emit", "emit", "normal", "emit"]
    assert_same_results(local, background)
    assert max(seconds for seconds, _ in steps[1:]) <= STEP_LIMIT  # the first includes importing the module


def test_reading_and_clipping_the_pixels_leave_the_stage_yielding(monkeypatch):
    """A 4k map's pixels take tenths of a second to read from the child's file and to clip: both run in threads,
    here made to take 0.4 s each."""
    from perceptual_uv.bridge import bake

    def slow(function):
        return lambda *args: (time.sleep(0.4), function(*args))[1]

    monkeypatch.setattr(bake_process, "_load_pixels", slow(bake_process._load_pixels))
    monkeypatch.setattr(bake, "_clip_to_unit", slow(bake._clip_to_unit))
    obj, image = pbr_grid_with_alpha()
    source_uv = add_turned_uv(obj)
    records, _ = read_maps([obj], source_uv, image)
    options = dict(source_uv=source_uv, target_uv="Target", resolutions=[64, 32, 64, 16], margin=2,
                   names=["base", "orm", "normal", "emissive"])
    results, steps = drive(iter_bake_maps([obj], records, in_background=True, **options))
    assert max(seconds for seconds, _ in steps[1:]) <= STEP_LIMIT, sorted(steps)[-3:]
    assert len(results) == 4 and np.all(pixels_of(results[0].image) <= 1.0)


def test_a_file_texture_bakes_the_same_in_the_background():
    from perceptual_uv.bridge.mesh_io import import_model

    reset_blender_scene()
    import_model(str(SPOT))
    (obj,) = [obj for obj in bpy.data.objects if obj.type == "MESH"]
    image = base_color_image_node(obj.material_slots[0].material).image
    assert image.source == "FILE" and not image.is_dirty
    source_uv = add_turned_uv(obj)
    records, _ = read_maps([obj], source_uv, image)
    options = dict(source_uv=source_uv, target_uv="Target", resolutions=[256] * len(records),
                   margin=2, names=["spot_new"] * len(records))
    local = bake_maps([obj], records, **options)
    background = run_generator(iter_bake_maps([obj], records, in_background=True, **options))
    assert_same_results(local, background)


def test_driving_the_pipeline_as_the_operator_does_no_bake_step_takes_longer_than_a_quarter_second(tmp_path):
    obj = pbr_grid()
    settings = OptimizeSettings(**FAST, bake_in_background=True)
    result, steps = drive(optimize_objects([obj], settings, output_dir=str(tmp_path)))
    bake_steps = [seconds for seconds, stage in steps if stage == "bake"]
    assert len(bake_steps) > len(result.images)  # yielded while the child baked, not once per map
    assert max(bake_steps) <= STEP_LIMIT, sorted(bake_steps)[-3:]
    assert len(result.images) == 4 and all(image.size[0] > 0 for image in result.images)


@pytest.fixture
def started_processes(monkeypatch):
    """The child processes the background bake starts."""
    started = []
    popen = subprocess.Popen

    def recording(*args, **kwargs):
        started.append(popen(*args, **kwargs))
        return started[-1]

    monkeypatch.setattr(bake_process.subprocess, "Popen", recording)
    return started


def bake_generator(obj):
    image = base_color_image_node(obj.material_slots[0].material).image
    records, _ = read_maps([obj], "UVMap", image)
    return iter_bake_maps([obj], records, source_uv="UVMap", target_uv="Target", resolutions=[64] * len(records),
                          margin=2, names=["new"] * len(records), in_background=True)


def test_closing_the_generator_kills_the_child_and_removes_its_folder(started_processes):
    obj = pbr_grid()
    add_turned_uv(obj)
    images_before = set(bpy.data.images.keys())
    generator = bake_generator(obj)
    while not started_processes:
        next(generator)
    (process,) = started_processes
    folder = process.args[-1].split("'folder': ")[1].split("'")[1]
    assert os.path.isdir(folder) and process.poll() is None
    generator.close()
    assert process.poll() is not None and not os.path.exists(folder)
    assert set(bpy.data.images.keys()) == images_before


def test_escape_during_the_background_bake_stops_the_child_and_leaves_nothing(started_processes):
    from types import SimpleNamespace

    from test_robustness import modal_operator, state

    obj = pbr_grid()
    before = state([obj])
    run = optimize_objects([obj], OptimizeSettings(**FAST, bake_in_background=True))
    for progress in run:
        if progress.stage == "bake" and started_processes:
            break
    (process,) = started_processes
    assert process.poll() is None
    operator, context, _ = modal_operator(run)
    assert operator.modal(context, SimpleNamespace(type="ESC")) == {"CANCELLED"}
    assert process.poll() is not None
    assert state([obj]) == before


def test_a_failing_child_gives_its_last_error_line_and_no_image(monkeypatch):
    obj = pbr_grid()
    add_turned_uv(obj)
    images_before = set(bpy.data.images.keys())
    failing = "import sys; sys.stderr.write('Traceback ...\\nMemoryError: out of memory\\n'); sys.exit(3)"
    monkeypatch.setattr(bake_process, "_child_command", lambda code: [sys.executable, "-c", failing])
    with pytest.raises(RuntimeError, match=r"exit code 3: MemoryError: out of memory$"):
        run_generator(bake_generator(obj))
    assert set(bpy.data.images.keys()) == images_before


def test_a_bake_the_child_refuses_is_the_same_value_error(tmp_path):
    (tmp_path / "error.json").write_text(json.dumps({"type": "ValueError", "message": "map 'x' cannot be baked"}))
    error = bake_process._failure(str(tmp_path), 1)
    assert isinstance(error, ValueError) and str(error) == "map 'x' cannot be baked"
