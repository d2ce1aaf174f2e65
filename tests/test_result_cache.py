"""core.result_cache: stage results kept in memory and on disk, keyed by inputs, settings and code."""
import dataclasses

import numpy as np
import pytest

from perceptual_uv.core import result_cache
from perceptual_uv.core.result_cache import ResultCache, default_cache_folder, result_key, stage_results


@dataclasses.dataclass(frozen=True)
class Result:
    params: np.ndarray
    flags: np.ndarray
    epsilon: float
    backend: str
    optional: np.ndarray = None


def result(seed=0):
    rng = np.random.default_rng(seed)
    return Result(params=rng.normal(size=(5, 4)), flags=rng.random(5) > 0.5, epsilon=0.01, backend="fast")


def test_key_changes_with_every_input_setting_and_the_code(monkeypatch):
    V = np.arange(12.0).reshape(4, 3)
    base = result_key(V, np.arange(3), epsilon=0.01, seed=0)
    assert result_key(V.copy(), np.arange(3), seed=0, epsilon=0.01) == base  # setting order does not count
    changed = V.copy()
    changed[2, 1] += 1e-12
    assert result_key(changed, np.arange(3), epsilon=0.01, seed=0) != base
    assert result_key(V.astype(np.float32), np.arange(3), epsilon=0.01, seed=0) != base
    assert result_key(V.reshape(3, 4), np.arange(3), epsilon=0.01, seed=0) != base
    assert result_key(V, np.arange(3), epsilon=0.02, seed=0) != base
    assert result_key(V, np.arange(3), epsilon=0.01, seed=1) != base
    monkeypatch.setattr(result_cache, "core_source_hash", lambda: "another version of core")
    assert result_key(V, np.arange(3), epsilon=0.01, seed=0) != base


def test_a_stage_cache_is_made_once_in_its_holder_under_the_cache_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("PERCEPTUAL_UV_RESULTS_CACHE", str(tmp_path))
    holder = []
    made = stage_results(holder, Result, "meshwise")
    assert holder == [made] and made.kind is Result and made.folder == tmp_path / "meshwise"
    assert stage_results(holder, Result, "meshwise") is made  # kept, not made again
    assert stage_results([], Result).folder == tmp_path


def test_a_result_comes_back_from_memory_and_from_disk(tmp_path):
    stored = result()
    ResultCache(Result, folder=tmp_path).put("k", stored)
    loaded = ResultCache(Result, folder=tmp_path).get("k")  # a new session: from the file
    np.testing.assert_array_equal(loaded.params, stored.params)
    np.testing.assert_array_equal(loaded.flags, stored.flags)
    assert loaded.flags.dtype == bool and loaded.epsilon == 0.01 and loaded.backend == "fast"
    assert loaded.optional is None
    assert ResultCache(Result, folder=tmp_path).get("other") is None


def test_memory_keeps_the_most_recent_and_the_folder_the_newest_files(tmp_path):
    cache = ResultCache(Result, folder=None, memory=2)
    for key in "abc":
        cache.put(key, result())
    assert cache.get("a") is None and cache.get("b") is not None and cache.get("c") is not None
    on_disk = ResultCache(Result, folder=tmp_path, files=2)
    for key in "abc":
        on_disk.put(key, result())
    assert sorted(path.stem for path in tmp_path.glob("*.npz")) == ["b", "c"]


def test_a_damaged_file_counts_as_missing_and_clear_removes_everything(tmp_path):
    cache = ResultCache(Result, folder=tmp_path)
    cache.put("good", result())
    (tmp_path / "bad.npz").write_bytes(b"not a zip file")
    assert ResultCache(Result, folder=tmp_path).get("bad") is None
    assert not (tmp_path / "bad.npz").exists()
    whole = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(whole[:len(whole) // 2])  # a zip cut off (a full disk)
    assert ResultCache(Result, folder=tmp_path).get("cut") is None
    assert not (tmp_path / "cut.npz").exists()
    assert cache.clear() == 1
    assert cache.get("good") is None and not list(tmp_path.glob("*.npz"))


def test_discard_forgets_a_result_in_memory_and_on_disk(tmp_path):
    cache = ResultCache(Result, folder=tmp_path)
    cache.put("k", result())
    cache.put("other", result(1))
    cache.discard("k")
    cache.discard("never stored")
    assert cache.get("k") is None and ResultCache(Result, folder=tmp_path).get("k") is None
    assert cache.get("other") is not None


def test_an_unwritable_folder_keeps_results_in_memory(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    cache = ResultCache(Result, folder=blocker / "results")
    cache.put("k", result())
    assert cache.get("k") is not None


def test_default_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("PERCEPTUAL_UV_RESULTS_CACHE", str(tmp_path))
    assert default_cache_folder() == tmp_path
    monkeypatch.delenv("PERCEPTUAL_UV_RESULTS_CACHE")
    assert default_cache_folder().name == "results"


def test_the_pipeline_reuses_triangle_and_mesh_wise_results_and_only_then(spot_obj):
    pytest.importorskip("bpy")
    from conftest import reset_blender_scene
    from perceptual_uv.bridge.batch import textured_objects
    from perceptual_uv.bridge.meshwise_stage import meshwise_results
    from perceptual_uv.bridge.mesh_io import import_model
    from perceptual_uv.bridge.pipeline import optimize_objects, run_to_end
    from perceptual_uv.bridge.trianglewise_stage import triangle_results
    from perceptual_uv.core.settings import OptimizeSettings

    def run(**settings):  # each run on a fresh copy of the file, as the redo panel's undo gives it
        reset_blender_scene()
        import_model(spot_obj)
        [obj] = textured_objects()
        options = dict(iterations=10, screen_pixels=32, max_screen_pixels=32, workers=1, cost_measure="texels")
        finished = run_to_end(optimize_objects([obj], OptimizeSettings(**dict(options, **settings))))
        values = np.empty(2 * len(obj.data.loops))
        obj.data.uv_layers[finished.uv_map].uv.foreach_get("vector", values)
        return finished.report, values

    def reused(report):
        return ["triangle-wise" in note for note in report["notes"] if "reused" in note]

    first, uv_first = run(target_cost=0.3)
    assert first["times_s"]["triangle"] > 0.5 and reused(first) == []
    assert len(list(triangle_results().folder.glob("*.npz"))) == 1
    assert len(list(meshwise_results().folder.glob("*.npz"))) == 1
    second, _ = run(target_cost=0.2, margin=2)  # what the redo panel reruns: both stages reused
    assert second["times_s"]["triangle"] < 0.1 * first["times_s"]["triangle"]
    assert sorted(reused(second)) == [False, True]
    assert second["relative_cost"] == pytest.approx(0.2, rel=0.02)
    third, uv_third = run(target_cost=0.3, reuse_triangle_results=False)
    assert reused(third) == []
    np.testing.assert_array_equal(uv_third, uv_first)  # what was reused is what the stages compute
    again, uv_again = run(target_cost=0.3)
    assert sorted(reused(again)) == [False, True]
    np.testing.assert_array_equal(uv_again, uv_first)
    unstacked, _ = run(target_cost=0.3, keep_stacks=False)  # the fit changes, the triangle-wise stage does not
    assert reused(unstacked) == [True]
    fourth, _ = run(iterations=12)
    assert reused(fourth) == []  # another setting of the triangle-wise stage


def test_a_run_stopped_in_the_triangle_wise_stage_resumes_from_the_faces_done(spot_obj, monkeypatch):
    pytest.importorskip("bpy")
    from conftest import reset_blender_scene
    from perceptual_uv.bridge.batch import textured_objects
    from perceptual_uv.bridge.mesh_io import import_model
    from perceptual_uv.bridge.pipeline import optimize_objects, run_to_end
    from perceptual_uv.bridge.trianglewise_stage import triangle_results
    from perceptual_uv.core import trianglewise
    from perceptual_uv.core.settings import OptimizeSettings

    monkeypatch.setattr(trianglewise, "CHECKPOINT_SECONDS", 0.0)  # the faces done kept after every chunk
    options = dict(target_cost=0.3, iterations=10, screen_pixels=32, max_screen_pixels=32, workers=1,
                   cost_measure="texels")

    def fresh_object():
        reset_blender_scene()
        import_model(spot_obj)
        [obj] = textured_objects()
        return obj

    def uv_of(obj, finished):
        values = np.empty(2 * len(obj.data.loops))
        obj.data.uv_layers[finished.uv_map].uv.foreach_get("vector", values)
        return values

    obj = fresh_object()
    whole = run_to_end(optimize_objects([obj], OptimizeSettings(**options, reuse_triangle_results=False)))
    uv_whole = uv_of(obj, whole)
    triangle_results().clear()
    obj = fresh_object()
    run = optimize_objects([obj], OptimizeSettings(**options))
    for step in run:  # the user cancels a third of the way through the stage
        if step.stage == "triangle" and 3 * step.done >= step.total > 0:
            total = step.total
            run.close()
            break
    [partial] = triangle_results().folder.glob("*-partial.npz")
    obj = fresh_object()
    resumed = run_to_end(optimize_objects([obj], OptimizeSettings(**options)))
    [note] = [note for note in resumed.report["notes"] if "stopped before its end" in note]
    assert int(note.split()[4]) >= total // 3 and f"of {total} triangles" in note
    assert not partial.exists() and len(list(triangle_results().folder.glob("*.npz"))) == 1
    np.testing.assert_array_equal(uv_of(obj, resumed), uv_whole)  # as if never stopped


def test_the_mesh_wise_key_follows_the_triangle_key_the_loss_image_and_keep_stacks():
    from perceptual_uv.bridge.meshwise_stage import meshwise_key

    texture = np.linspace(0.0, 1.0, 48, dtype=np.float32).reshape(4, 4, 3)
    key = meshwise_key("a" * 64, texture, keep_stacks=True)
    assert key == meshwise_key("a" * 64, texture.copy(), keep_stacks=True) and len(key) == 64
    changed = texture.copy()
    changed[0, 0, 2] += 0.25  # a colour the loss's luma may not show, signal stretch does
    others = {meshwise_key("b" * 64, texture, keep_stacks=True), meshwise_key("a" * 64, changed, keep_stacks=True),
              meshwise_key("a" * 64, texture, keep_stacks=False)}
    assert key not in others and len(others) == 3
