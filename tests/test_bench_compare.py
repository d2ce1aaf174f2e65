# SPDX-License-Identifier: GPL-3.0-or-later
"""bench.compare --reuse: earlier results are taken only when they were measured the same way."""
import json

import numpy as np
import pytest

from perceptual_uv.bench.compare import _previous_results
from perceptual_uv.bench.compare_report import memory_figures, model_markdown, q_at_memory


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
    text = model_markdown(table, {"input": _result([0.3])}, [0.3])
    assert "not recomputed: input, repacked." in text


def _points(*pairs):
    return [dict(memory_ratio=memory, q=q) for memory, q in pairs]


def test_q_at_memory_interpolates_log_q_linearly_in_memory():

    points = _points((0.2, 4e-3), (0.4, 1e-3))
    # halfway in memory: the geometric mean of the two q
    assert q_at_memory(points, 0.3) == pytest.approx(2e-3, rel=1e-12)
    assert q_at_memory(points, 0.25) == pytest.approx(4e-3 * 0.25 ** 0.25, rel=1e-12)
    assert q_at_memory(points, 0.201) == 4e-3  # within 2 % of a measured point: that point
    assert q_at_memory(points, 0.5) is None and q_at_memory(points, 0.1) is None


def test_memory_figures_compare_at_equal_memory_and_name_what_was_not_measured():

    results = {"input": {"points": _points((0.2, 3e-3), (0.3, 2e-3), (0.5, 1e-3))},
               "MINIMUM_STRETCH": {"points": _points((0.18, 2.4e-3), (0.28, 2.2e-3), (0.45, 1.2e-3))},
               "ours": {"points": _points((0.25, 2e-3), (0.35, 1.25e-3), (0.6, 5e-4))}}
    figures = memory_figures(results)
    # ours at 0.3: halfway between 2e-3 and 1.25e-3 in log -> sqrt(2e-3 * 1.25e-3) = 1.58e-3
    assert figures["q"]["ours"][1] == pytest.approx((2e-3 * 1.25e-3) ** 0.5, rel=1e-12)
    assert figures["q"]["ours"][0] is None  # below ours' points
    # MINIMUM_STRETCH at 0.3: 2.2e-3 * (1.2 / 2.2) ** (0.02 / 0.17)
    assert figures["q"]["MINIMUM_STRETCH"][1] == pytest.approx(2.2e-3 * (1.2 / 2.2) ** (2 / 17), rel=1e-12)
    assert figures["beaten_by"] == {"0.3": [], "0.5": []}
    assert figures["unmeasured"] == {"0.3": [], "0.5": ["MINIMUM_STRETCH"]}
    # the input's q at memory 0.5 (1e-3) is reached between ours' 0.35 (1.25e-3) and 0.6 (5e-4): linear in memory
    # with log q, at 0.35 + 0.25 * ln(1.25) / ln(2.5)
    assert figures["saving"]["memory"] == pytest.approx(0.35 + 0.25 * np.log(1.25) / np.log(2.5), rel=1e-9)
    assert figures["saving"]["position"] == "inside"
