# SPDX-License-Identifier: GPL-3.0-or-later
"""bench.compare --reuse: earlier results are taken only when they were measured the same way."""
import json

import pytest

from perceptual_uv.bench.compare import _model_markdown, _previous_results


def _result(costs, screen=512):
    return {"screen_pixels": screen, "e_iso": 2.0,
            "points": [{"target_cost": c, "relative_cost": c, "q": 0.1 * c, "resolution": 64} for c in costs]}


@pytest.fixture
def earlier(tmp_path):
    file = tmp_path / "model.json"
    file.write_text(json.dumps({"times_s": {"repacked": 2.5}, "results": {
        "input": _result([0.2, 0.3]), "repacked": _result([0.2, 0.3])}}))
    return file


def test_reused_results_are_the_earlier_ones(earlier):
    results, times = _previous_results(earlier, ["input", "repacked"], costs=[0.3, 0.2], screen=512)
    assert results["repacked"]["points"][1]["q"] == pytest.approx(0.03)
    assert times == {"input": None, "repacked": 2.5}


@pytest.mark.parametrize("costs, screen, methods", [
    ([0.2, 0.3, 0.5], 512, ["input"]),  # another cost
    ([0.2, 0.3], 256, ["input"]),  # another screen
    ([0.2, 0.3], 512, ["SSPOP"]),  # never run
])
def test_results_measured_otherwise_are_refused(earlier, costs, screen, methods):
    with pytest.raises(SystemExit, match="--reuse"):
        _previous_results(earlier, methods, costs=costs, screen=screen)


def test_a_missing_file_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="does not exist"):
        _previous_results(tmp_path / "none.json", ["input"], costs=[0.3], screen=512)


def test_the_table_names_the_reused_methods():
    table = dict(model="m", vertices=3, faces=1, input_resolution=64, input_cost=10.0, epsilon=0.01,
                 evaluations=100, t_triangle=1.0, t_mesh=1.0, screen_pixels=512, surface_area=1.0,
                 pixel_saving=None, beaten_by={}, failures={}, reused=["input", "repacked"])
    text = _model_markdown(table, {"input": _result([0.3])}, [0.3])
    assert "not recomputed: input, repacked." in text
