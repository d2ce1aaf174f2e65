"""bench.paired_downscale: which memories it measures the downscale at and how it pairs them (hand-made results)."""
import json

import pytest

from perceptual_uv.bench import paired_downscale
from perceptual_uv.bench.paired_downscale import paired_markdown, paired_table, points_to_pair

RESULTS = {
    "input": {"points": [{"target_cost": 0.3, "memory_ratio": 0.3, "q": 8.0e-5}]},
    "ours": {"points": [{"target_cost": 0.3, "memory_ratio": 0.266, "q": 9.0e-5},
                        {"target_cost": 0.2, "memory_ratio": 0.177, "q": 1.5e-4}]},
    "MINIMUM_STRETCH": {"points": [{"target_cost": 0.2, "memory_ratio": 0.192, "q": 1.3e-4},
                                   {"target_cost": 0.5, "memory_ratio": None, "q": 6.0e-5}]},
}


def test_every_point_of_the_methods_is_paired_at_its_own_memory_in_cost_order():
    assert points_to_pair(RESULTS, ["ours", "MINIMUM_STRETCH"]) == [
        ("ours", 0.2, 0.177), ("ours", 0.3, 0.266), ("MINIMUM_STRETCH", 0.2, 0.192)]  # no memory: not paired


def test_a_method_the_results_do_not_hold_is_refused():
    with pytest.raises(ValueError, match="SSP"):
        points_to_pair(RESULTS, ["SSP"])


def test_each_ratio_is_over_the_downscale_measured_at_that_memory():
    downscale = {repr(0.177): {"q": 1.2e-4, "memory_ratio": 0.1771},
                 repr(0.266): {"q": 1.0e-4, "memory_ratio": 0.2659}}
    table = paired_table(RESULTS, downscale, ["ours", "MINIMUM_STRETCH"])
    assert [row["target_cost"] for row in table["ours"]] == [0.2, 0.3]
    assert [row["ratio"] for row in table["ours"]] == pytest.approx([1.5 / 1.2, 0.9])
    assert table["ours"][1]["downscale_memory"] == 0.2659
    assert table["MINIMUM_STRETCH"] == []  # its memory was not measured yet
    # sqrt(1.25 * 0.9) = 1.0607
    assert table["geometric_mean"] == {"ours": pytest.approx(1.0606602), "MINIMUM_STRETCH": None}
    text = paired_markdown("M", table, ["ours", "MINIMUM_STRETCH"])
    assert "| ours | 0.3 | 0.266 | 9e-05 | 0.0001 (0.266) | 0.900 |" in text
    assert "ours: geometric mean of q / downscale's q 1.061 over 2 points" in text


def test_a_results_file_that_is_not_shaded_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "m.obj").write_text("v 0 0 0\n")
    results = tmp_path / "m.json"
    results.write_text(json.dumps({"table": {"shaded": False}, "results": RESULTS}))
    assert paired_downscale.main([str(tmp_path / "m.obj"), "--results", str(results), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_a_results_file_that_cannot_be_read_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "m.obj").write_text("v 0 0 0\n")
    (tmp_path / "cut.json").write_text('{"table": ')
    for results in (tmp_path / "missing.json", tmp_path / "cut.json"):
        assert paired_downscale.main([str(tmp_path / "m.obj"), "--results", str(results), "--out", str(tmp_path)]) == 2
        assert capsys.readouterr().err.count("\n") == 1
