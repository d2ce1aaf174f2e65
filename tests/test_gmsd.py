"""GMSD (DESIGN decision 4) against values pinned from the independent piq package, and by hand."""
import importlib.util
import json
import pathlib

import numpy as np
import pytest

from perceptual_uv.core.gmsd import GMSD_C, covered_gmsd, gmsd, gradient_magnitude, luma, pool2

REFERENCE = pathlib.Path(__file__).resolve().parent / "reference"


def _reference_module():
    spec = importlib.util.spec_from_file_location("make_gmsd_reference", REFERENCE / "make_gmsd_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_matches_piq_pinned_values():
    pinned = json.loads((REFERENCE / "gmsd_piq.json").read_text())["cases"]
    cases = _reference_module().make_cases()
    assert sorted(pinned) == sorted(name for name, _, _ in cases)
    for name, ref, dist in cases:
        channel_axis = -1 if ref.ndim == 3 else None
        assert gmsd(ref, dist, channel_axis=channel_axis) == pytest.approx(pinned[name], abs=1e-12), name
        # GMSD is symmetric in its arguments.
        assert gmsd(dist, ref, channel_axis=channel_axis) == pytest.approx(pinned[name], abs=1e-12), name


def test_identical_images_give_exactly_zero():
    rng = np.random.default_rng(0)
    image = rng.random((64, 64))
    assert gmsd(image, image) == 0.0
    assert gmsd(np.zeros((8, 8)), np.zeros((8, 8))) == 0.0


def test_gradient_magnitude_by_hand():
    # A single 1 in the middle of a 3 x 3 zero image: Prewitt/3 gives 0 at the centre, 1/3 at edge-adjacent
    # positions (one of gx, gy sees the 1 once) and sqrt(2)/3 at the corners (both do).
    image = np.zeros((3, 3))
    image[1, 1] = 1.0
    expected = np.array([[np.sqrt(2), 1, np.sqrt(2)], [1, 0, 1], [np.sqrt(2), 1, np.sqrt(2)]]) / 3
    np.testing.assert_allclose(gradient_magnitude(image), expected, atol=1e-15)
    # Zero padding: a constant image has border gradients (a step to 0 outside), interior ones vanish.
    g = gradient_magnitude(np.ones((4, 4)))
    np.testing.assert_allclose(g[1:3, 1:3], 0.0)
    np.testing.assert_allclose(g[0, 1], 1.0)  # gy = (0 + 0 + 0 - 3) / 3 in magnitude


def test_hand_gmsd_against_a_flat_reference():
    # Reference 0 everywhere: m_r = 0 and GMS = c / (m_d^2 + c). Distorted: a 2x2 block of ones in an 8 x 8
    # image pools to a single 1 at (1, 1) of a 4 x 4 map, whose gradient magnitudes are those above.
    dist = np.zeros((8, 8))
    dist[2:4, 2:4] = 1.0
    m = np.zeros((4, 4))
    m[0:3, 0:3] = np.array([[np.sqrt(2), 1, np.sqrt(2)], [1, 0, 1], [np.sqrt(2), 1, np.sqrt(2)]]) / 3
    gms = GMSD_C / (m * m + GMSD_C)
    assert gmsd(np.zeros((8, 8)), dist) == pytest.approx(np.std(gms), abs=1e-15)


def test_luma_and_pooling():
    rgb = np.array([[[1.0, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]])
    np.testing.assert_allclose(luma(rgb), [[0.299, 0.587], [0.114, 1.0]])
    rgba = np.concatenate([rgb, np.zeros((2, 2, 1))], axis=-1)
    np.testing.assert_allclose(luma(rgba), luma(rgb))
    np.testing.assert_allclose(pool2(np.arange(16.0).reshape(4, 4)), [[2.5, 4.5], [10.5, 12.5]])
    # Odd sides: piq appends a zero row and column, then pooling drops an incomplete pair.
    np.testing.assert_allclose(pool2(np.ones((3, 3))), [[1, 0.5], [0.5, 0.25]])
    assert pool2(np.ones((4, 5))).shape == (2, 3)


def test_options_and_validation():
    rng = np.random.default_rng(1)
    ref, dist = rng.random((2, 16, 16))
    assert gmsd(255 * ref, 255 * dist, data_range=255) == pytest.approx(gmsd(ref, dist), abs=1e-15)
    score, gms = gmsd(ref, dist, full=True)
    assert gms.shape == (8, 8) and score == pytest.approx(gms.std(), abs=1e-15)
    with pytest.raises(ValueError, match="shape"):
        gmsd(ref, dist[:8])
    with pytest.raises(ValueError, match="data_range"):
        gmsd(ref, dist, data_range=0)
    with pytest.raises(ValueError, match="channels"):
        gmsd(rng.random((4, 4, 2)), rng.random((4, 4, 2)), channel_axis=-1)


def _prewitt_gms_std(extended, reference_extended, rows, cols, c=GMSD_C):
    """GMS deviation at pooled cells (rows, cols) of two border-padded pooled grids, written out by hand."""
    def magnitude(grid, i, j):  # (i, j) inner cell; grid has a one-cell border
        window = grid[i:i + 3, j:j + 3]
        gx = (window[:, 0].sum() - window[:, 2].sum()) / 3.0
        gy = (window[0].sum() - window[2].sum()) / 3.0
        return np.hypot(gx, gy)
    gms = []
    for i in rows:
        for j in cols:
            mr, md = magnitude(reference_extended, i, j), magnitude(extended, i, j)
            gms.append((2 * mr * md + c) / (mr * mr + md * md + c))
    return float(np.std(gms))


def test_covered_gmsd_of_identical_or_flat_screens_is_zero():
    rng = np.random.default_rng(3)
    image = rng.random((8, 8))
    covered = np.zeros((8, 8), bool)
    covered[2:6, 1:7] = True
    assert covered_gmsd(image, image, covered) == 0.0
    # Two different flat patches on an empty background: plain GMSD sees the two different steps to 0 at the
    # patch's edge, the covered part has no gradient in either screen.
    flat_a, flat_b = np.where(covered, 0.5, 0.0), np.where(covered, 0.6, 0.0)
    assert gmsd(flat_a, flat_b) > 0
    assert covered_gmsd(flat_a, flat_b, covered) == 0.0
    # A cell with one covered pixel takes that pixel's value, not a quarter of it.
    one = np.zeros((4, 4), bool)
    one[0, 0] = True
    assert covered_gmsd(np.full((4, 4), 0.2), np.full((4, 4), 0.9), one) == 0.0
    assert covered_gmsd(image, 1 - image, np.zeros((8, 8), bool)) == 0.0


def test_covered_gmsd_of_full_and_half_screens_by_hand():
    rng = np.random.default_rng(4)
    reference, distorted = rng.random((8, 8)), rng.random((8, 8))
    # Fully covered: the pooled screens continue at the border (edge padding), deviation over all 16 cells.
    full = np.ones((8, 8), bool)
    expected = _prewitt_gms_std(np.pad(pool2(distorted), 1, mode="edge"), np.pad(pool2(reference), 1, mode="edge"),
                                range(4), range(4))
    assert covered_gmsd(reference, distorted, full) == pytest.approx(expected, abs=1e-14)
    # Left half covered (pooled columns 0-1): each row continues its last covered cell to the right, the
    # border rows repeat the rows next to them; the deviation is over the 8 covered cells only.
    half = np.zeros((8, 8), bool)
    half[:, :4] = True
    def extended(image):
        return np.pad(pool2(image)[:, :2], ((1, 1), (1, 3)), mode="edge")
    expected = _prewitt_gms_std(extended(distorted), extended(reference), range(4), range(2))
    assert covered_gmsd(reference, distorted, half) == pytest.approx(expected, abs=1e-14)
    assert expected > 0
