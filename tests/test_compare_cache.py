# SPDX-License-Identifier: GPL-3.0-or-later
"""bench.compare's result cache: keyed by model, settings and the code each method runs, written as each method is
measured, so that a rerun recomputes only what changed and an interrupted run loses only the method it measured."""
import json
import pathlib
import shutil

import numpy as np
import pytest

from perceptual_uv.bench import compare
from perceptual_uv.bench.compare import ResultCache, method_key, method_settings, method_sources
from perceptual_uv.bench.source_hash import code_hash

PACKAGE = pathlib.Path(compare.__file__).resolve().parent.parent


@pytest.fixture
def package(tmp_path):
    """A copy of the package's Python sources, to change."""
    root = tmp_path / "pkg"
    for folder in ("core", "bridge", "bench"):
        (root / folder).mkdir(parents=True)
        for file in (PACKAGE / folder).glob("*.py"):
            shutil.copy(file, root / folder / file.name)
    return root


def _hashes(package):
    return {m: code_hash(method_sources(m), package) for m in ("input", "repacked", "CONFORMAL", "SSP", "SSPOP",
                                                                  "ours", "ours_common", "paper",
                                                                  "not_a_listed_method")}


def _edit(file, old, new):
    text = file.read_text()
    assert old in text
    file.write_text(text.replace(old, new, 1))


def test_a_change_to_one_baseline_changes_only_its_key(package):
    before = _hashes(package)
    _edit(package / "bridge" / "baselines.py", "def ssp_uv(", "def ssp_uv(  # changed\n")
    after = _hashes(package)
    # a method not listed depends on any change
    assert [m for m in before if before[m] != after[m]] == ["SSP", "not_a_listed_method"]


def test_a_change_to_a_module_changes_the_methods_that_import_it(package):
    before = _hashes(package)
    (package / "core" / "trianglewise.py").write_text((package / "core" / "trianglewise.py").read_text() + "\n# x\n")
    after = _hashes(package)
    assert {m for m in before if before[m] != after[m]} == {"ours", "ours_common", "paper", "not_a_listed_method"}
    (package / "core" / "overlap.py").write_text((package / "core" / "overlap.py").read_text() + "\n# x\n")
    again = _hashes(package)
    # the fold restore is post-processing every method but the input and its repacking gets; the stacks
    # (core.stacks finds them with core.overlap) reach the repacking too
    assert {m for m in after if after[m] != again[m]} == {"repacked", "CONFORMAL", "SSP", "SSPOP", "ours",
                                                           "ours_common", "paper", "not_a_listed_method"}


def test_the_evaluation_is_part_of_every_key(package):
    before = _hashes(package)
    (package / "core" / "gmsd.py").write_text((package / "core" / "gmsd.py").read_text() + "\n# x\n")
    after = _hashes(package)
    assert all(before[m] != after[m] for m in before)


def test_settings_that_a_method_ignores_do_not_change_its_key():
    kw = dict(costs=[0.3, 0.1], screen=512, evaluations=100, epsilon=0.01)
    ssp = method_settings("SSP", **kw)
    assert ssp == method_settings("SSP", **{**kw, "epsilon": 0.02, "evaluations": 10, "costs": [0.1, 0.3]})
    assert ssp != method_settings("SSP", **{**kw, "screen": 256})
    assert method_settings("ours", **kw) != method_settings("ours", **{**kw, "epsilon": 0.02})
    assert method_settings("ours_eps0.005", **kw)["epsilon"] == 0.005
    assert method_settings("ours_common", **kw) != method_settings("ours", **kw)
    key = method_key("SSP", model="m", settings=ssp, code="c")
    assert key != method_key("SSPOP", model="m", settings=ssp, code="c")
    assert key != method_key("SSP", model="n", settings=ssp, code="c")


def test_the_seed_enters_the_keys_of_the_methods_it_changes_and_only_when_not_0():
    """Results measured before ``--seed`` existed (seed 0) keep their keys; another seed is another result for ours
    and its variants, and changes nothing for a method without a triangle-wise stage."""
    kw = dict(costs=[0.3], screen=512, evaluations=100, epsilon=0.01)
    assert method_settings("ours", **kw, seed=0) == method_settings("ours", **kw)
    assert "seed" not in method_settings("ours", **kw)
    assert method_settings("ours", **kw, seed=2)["seed"] == 2
    assert method_settings("paper", **kw, seed=2)["seed"] == 2
    assert method_settings("SSP", **kw, seed=2) == method_settings("SSP", **kw)
    model = dict(model="m", code="c")
    assert method_key("ours", settings=method_settings("ours", **kw, seed=1), **model) != \
        method_key("ours", settings=method_settings("ours", **kw), **model)


def test_the_seed_reaches_the_triangle_wise_stage_and_its_cache_file(monkeypatch, tmp_path):
    from perceptual_uv.bridge import baselines

    calls = []
    monkeypatch.setattr(baselines, "loss_planes", lambda objects, source_uv, maps: ("plane",))
    monkeypatch.setattr(baselines, "triangle_targets", lambda objects, **kw: calls.append(kw) or ("result", 1.0))
    for seed in (0, 3):
        maps = compare.UVMaps([], "UVMap", evaluations=100, epsilon=0.01, workers=1, cache=(tmp_path, "m"), seed=seed)
        assert maps.triangles(0.01) == "result"
    assert [call["seed"] for call in calls] == [0, 3]
    assert [call["cache"].name for call in calls] == ["m_eps0.01_n100.npz", "m_eps0.01_n100_seed3.npz"]


def test_reuse_refuses_results_of_another_seed(tmp_path):
    file = tmp_path / "m.json"
    result = {"screen_pixels": 512, "points": [_point(0.3, 0.01)]}
    file.write_text(json.dumps({"table": {"seed": 1}, "results": {"ours": result}, "times_s": {}}))
    with pytest.raises(SystemExit, match="--seed 1, this run has 0"):
        compare._previous_results(file, ["ours"], costs=[0.3], screen=512)
    assert compare._previous_results(file, ["ours"], costs=[0.3], screen=512, seed=1)[0] == {"ours": result}


def _point(c, q):
    return {"target_cost": c, "relative_cost": c, "q": q, "resolution": 64}


def test_cache_round_trip_and_a_file_cut_off_is_measured_again(tmp_path):
    model = tmp_path / "m" / "m.obj"
    model.parent.mkdir()
    model.write_text("v 0 0 0\n")
    cache = ResultCache(tmp_path / "cache", costs=[0.3], screen=512, evaluations=100, epsilon=0.01)
    assert cache.load(model, "ours") is None
    result = {"screen_pixels": 512, "e_iso": 1.0, "points": [_point(0.3, 0.01)]}
    uv = np.random.default_rng(0).random((4, 3, 2))
    cache.save(model, "ours", result=result, times={"ours": 2.0, "triangle": 30.0}, uv=uv)
    entry = cache.load(model, "ours")
    assert entry["result"] == result and entry["times"]["triangle"] == 30.0
    np.testing.assert_array_equal(entry["uv"], uv)
    assert not list((tmp_path / "cache").rglob("*.part"))
    # another texture is another model (the model's files are hashed once per run)
    (model.parent / "m.png").write_bytes(b"png")
    cache = ResultCache(tmp_path / "cache", costs=[0.3], screen=512, evaluations=100, epsilon=0.01)
    assert cache.load(model, "ours") is None
    cache.save(model, "SSP", result=result, times={"SSP": 1.0})
    file = cache.file(model, "SSP")
    file.write_text(file.read_text()[:20])
    assert cache.load(model, "SSP") is None
    assert ResultCache(None, costs=[0.3], screen=512, evaluations=100, epsilon=0.01).load(model, "SSP") is None


def test_progress_prints_one_line_per_method_with_an_eta(capsys):
    progress = compare.Progress(3, 4)
    progress.model(1, 1, "m", 3, 1)
    progress.method("m", "input", 0.0, "cached")
    progress.method("m", "SSP", 10.0, "measured")
    progress.method("m", "SSPOP", 20.0, "measured")
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 4 and lines[1].endswith("ETA unknown")
    assert "1 to measure, ETA 15 s" in lines[3]


@pytest.fixture
def fake_measurements(monkeypatch):
    """compare_model without renders: the evaluation returns fixed points and counts its calls."""
    pytest.importorskip("bpy")
    from perceptual_uv.bridge import evaluate

    calls, state = [], {}

    def evaluate_uv_map(objects, name, *, costs, **kw):
        calls.append(name)
        if name == "Repacked" and state.get("interrupt"):
            raise KeyboardInterrupt
        return {"screen_pixels": 512, "e_iso": 1.0, "points": [_point(c, 0.1 * c) for c in costs]}

    monkeypatch.setattr(evaluate, "evaluate_uv_map", evaluate_uv_map)
    monkeypatch.setattr(evaluate, "render_views", lambda *a, **kw: [np.zeros((8, 8, 4))])
    monkeypatch.setattr(evaluate, "reference_resolution", lambda objects: (256, 256))
    monkeypatch.setattr(compare, "plot_curves", lambda *a, **kw: None)
    monkeypatch.setattr(compare, "render_crops", lambda *a, **kw: None)
    return calls, state


def test_a_rerun_measures_only_what_is_not_cached(spot_obj, tmp_path, fake_measurements):
    calls, state = fake_measurements
    out = tmp_path / "out"
    out.mkdir()
    kw = dict(costs=[0.3, 0.5], methods=["input", "repacked"], evaluations=100, screen=512, epsilon=0.01,
              epsilons=[], workers=1, out=out)
    cache = ResultCache(out / "cache", costs=[0.3, 0.5], screen=512, evaluations=100, epsilon=0.01)
    # cut off while measuring the second method: the first one is on disk
    state["interrupt"] = True
    with pytest.raises(KeyboardInterrupt):
        compare.compare_model(spot_obj, cache=cache, **kw)
    assert calls == [calls[0], "Repacked"]
    assert cache.load(spot_obj, "input") is not None and cache.load(spot_obj, "repacked") is None
    state["interrupt"] = False
    calls.clear()
    compare.compare_model(spot_obj, cache=cache, **kw)
    assert calls == ["Repacked"]
    calls.clear()
    compare.compare_model(spot_obj, cache=cache, **kw)
    assert calls == []
    table = json.loads((out / "spot_triangulated.json").read_text())["table"]
    assert table["cached"] == ["input", "repacked"]


def test_the_shaded_mode_has_keys_of_its_own_and_leaves_the_flat_keys_alone(package):
    """``--shaded`` adds its settings and the shaded evaluation's code to every key; the flat keys carry neither,
    so adding the shaded mode left every flat key as it was. ``downscale`` re-bakes the input UV map: its key
    depends on its sizing and the evaluation."""
    kw = dict(costs=[0.3], screen=512, evaluations=100, epsilon=0.01)
    assert "shaded" not in method_settings("input", **kw)
    shaded = method_settings("input", **kw, shaded=True)
    assert shaded["shaded"] is True and shaded["sizing"] == "texels"
    assert method_settings("downscale", **kw, shaded=True)["sizing"] == "memory"
    assert "bridge.evaluate_shaded" in method_sources("ours", shaded=True)
    assert "bridge.evaluate_shaded" not in method_sources("ours")
    flat = {m: code_hash(method_sources(m), package) for m in ("input", "ours")}
    _edit(package / "bridge" / "evaluate_shaded.py", "SAMPLES = 16", "SAMPLES = 32")
    assert flat == {m: code_hash(method_sources(m), package) for m in ("input", "ours")}
    assert code_hash(method_sources("input", True), package) != code_hash(method_sources("input", True), PACKAGE)
    assert method_sources("downscale") == ("bench.compare:SIZING",) + compare.EVALUATION_SOURCES


def test_downscale_is_shaded_only(tmp_path, capsys):
    with pytest.raises(SystemExit) as stopped:
        compare.main(["--models", str(tmp_path), "--out", str(tmp_path / "out"), "--methods", "input,downscale"])
    assert stopped.value.code == 2 and "downscale is measured with --shaded only" in capsys.readouterr().err


def test_the_shaded_comparison_measures_downscale_on_the_input_map_by_memory(spot_obj, tmp_path, monkeypatch):
    pytest.importorskip("bpy")
    from perceptual_uv.bridge import evaluate_shaded

    calls = []

    def fake(objects, name, *, reference_uv, costs, sizing, **kw):
        calls.append((name, reference_uv, sizing))
        return {"screen_pixels": 512, "e_iso": 1.0, "points": [
            {**_point(c, 0.1 * c), "memory_ratio": c, "maps": [{"role": "base_color", "q": 0.1 * c,
                                                                 "resolution": 64}]} for c in costs]}

    monkeypatch.setattr(evaluate_shaded, "evaluate_shaded", fake)
    monkeypatch.setattr(evaluate_shaded, "shaded_reference", lambda *a, **kw: {"shaded": [], "maps": []})
    monkeypatch.setattr(compare, "plot_curves", lambda *a, **kw: None)
    out = tmp_path / "out"
    out.mkdir()
    cache = ResultCache(out / "cache", costs=[0.3], screen=512, evaluations=100, epsilon=0.01, shaded=True)
    compare.compare_model(spot_obj, costs=[0.3], methods=["input", "downscale"], evaluations=100, screen=512,
                          epsilon=0.01, epsilons=[], workers=1, out=out, cache=cache, shaded=True)
    source = calls[0][1]
    assert calls == [(source, source, "texels"), (source, source, "memory")]
    data = json.loads((out / "spot_triangulated_shaded.json").read_text())
    assert data["table"]["shaded"] is True and set(data["results"]) == {"input", "downscale"}
    assert "| downscale | 0.3 | 0.300 |" in (out / "spot_triangulated_shaded.md").read_text()
    assert cache.file(spot_obj, "input") != ResultCache(out / "cache", costs=[0.3], screen=512, evaluations=100,
                                                        epsilon=0.01).file(spot_obj, "input")


def test_ours_depends_on_how_the_materials_maps_are_read(package):
    """Ours and its variants read every map of the material (``bridge.material_copy``): a change there
    recomputes them and no other method."""
    before = _hashes(package)
    _edit(package / "bridge" / "material_copy.py", "def read_maps(", "def read_maps(  # changed\n")
    after = _hashes(package)
    assert {m for m in before if before[m] != after[m]} == {"ours", "ours_common", "paper", "not_a_listed_method"}
    kw = dict(costs=[0.3], screen=512, evaluations=100, epsilon=0.01)
    assert method_settings("ours", **kw)["loss_maps"] == "material"
    assert method_settings("ours_luma", **kw)["loss_maps"] == "luma"
    assert method_sources("ours_luma") == method_sources("ours")


@pytest.fixture
def fake_baselines(monkeypatch):
    """``bridge.baselines`` without Blender's objects: the planes of each kind are fixed stacks, and the
    triangle-wise and mesh-wise stages record the planes they are given."""
    pytest.importorskip("bpy")
    from perceptual_uv.bridge import baselines
    from perceptual_uv.core.loss_planes import PlaneStack

    rng = np.random.default_rng(0)
    luma = rng.random((8, 8))
    stacks = {"material": PlaneStack([luma, rng.random((4, 4))], ["base_color.luma", "normal_tangent.light0"]),
              "luma": PlaneStack([luma], ["base_color.luma"])}
    calls = []

    def loss_planes(objects, *, source_uv, maps="material"):
        calls.append(("planes", maps))
        return PlaneStack(list(stacks[maps]), stacks[maps].names)  # a new stack each time, as a real read

    def triangle_targets(objects, *, planes, **kw):
        calls.append(("triangle", planes.names, kw.get("formulation")))
        return object(), 1.0

    def perceptual_uv(objects, *, triangles, planes, **kw):
        calls.append(("mesh", planes.names))
        return {"mesh": 0.5}

    monkeypatch.setattr(baselines, "loss_planes", loss_planes)
    monkeypatch.setattr(baselines, "triangle_targets", triangle_targets)
    monkeypatch.setattr(baselines, "perceptual_uv", perceptual_uv)
    return stacks, calls


def test_every_variant_of_ours_sees_the_materials_planes_and_ours_luma_the_luma(fake_baselines):
    stacks, calls = fake_baselines
    maps = compare.UVMaps([], "UVMap", evaluations=10, epsilon=0.01, workers=1)
    for method in ("ours", "ours_common", "paper", "ours_luma", "ours_eps0.02"):
        maps.make(method)
    material, luma = stacks["material"].names, stacks["luma"].names
    assert calls == [("planes", "material"), ("triangle", material, None), ("mesh", material),
                     ("mesh", material),  # ours_common: ours' triangle-wise result
                     ("triangle", material, "barrier"), ("mesh", material),  # paper: its own stage, the same maps
                     ("planes", "luma"), ("triangle", luma, None), ("mesh", luma),
                     ("triangle", material, None), ("mesh", material)]  # ours at another epsilon
    assert {"triangle", "triangle_paper", "triangle_luma", "triangle_eps0.02"} <= set(maps.times)


def test_ours_luma_reuses_ours_triangles_when_the_material_is_its_luma(fake_baselines):
    stacks, calls = fake_baselines
    stacks["material"] = stacks["luma"]  # a material whose only varying map is the base colour
    maps = compare.UVMaps([], "UVMap", evaluations=10, epsilon=0.01, workers=1)
    maps.make("ours")
    maps.make("ours_luma")
    assert [call[0] for call in calls] == ["planes", "triangle", "mesh", "planes", "mesh"]
    assert maps.planes("ours_luma") is maps.planes("ours")
