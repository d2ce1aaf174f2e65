import numpy as np
import pytest

from perceptual_uv.core.cost import (relative_cost, resolution_for_cost, size_for_cost, texel_cost, texel_reuse,
                                     uv_area)

# Two triangles: the lower-left half of the unit square (area 1/2) and a small one of area 1/8.
UV = np.array([[[0, 0], [1, 0], [0, 1]], [[0, 0], [0.5, 0], [0.5, 0.5]]], dtype=float)


def test_area_and_cost_by_hand():
    assert uv_area(UV) == pytest.approx(0.625)
    assert texel_cost(UV, 8) == pytest.approx(40.0)           # 64 * 0.625
    assert texel_cost(UV, (16, 4)) == pytest.approx(40.0)     # non-square: 16 * 4 * 0.625


def test_orientation_does_not_matter():
    mirrored = UV[:, ::-1]
    assert uv_area(mirrored) == pytest.approx(uv_area(UV))


def test_relative_cost_is_one_for_the_input_at_its_resolution():
    assert relative_cost(UV, 1024, reference_uv=UV, reference_resolution=1024) == pytest.approx(1.0)


def test_half_size_uvs_at_same_resolution_cost_a_quarter():
    assert relative_cost(UV * 0.5, 1024, reference_uv=UV, reference_resolution=1024) == pytest.approx(0.25)


def test_resolution_for_cost_by_hand():
    # c_r = r^2 * 0.625 / (1024^2 * 0.625) = 0.3 -> r = 1024 sqrt(0.3) = 560.88 -> 561.
    assert resolution_for_cost(UV, 0.3, reference_uv=UV, reference_resolution=1024) == 561
    # UVs at half size need twice the resolution for the same cost: 1121.76 -> 1122.
    assert resolution_for_cost(UV * 0.5, 0.3, reference_uv=UV, reference_resolution=1024) == 1122


def test_resolution_for_cost_picks_the_closer_integer():
    # Exact r = 10.4, i.e. r^2 = 108.16: r = 10 misses by 8.16 texels^2, r = 11 by 12.84, so 10.
    target = 10.4 ** 2 / 1024 ** 2
    assert resolution_for_cost(UV, target, reference_uv=UV, reference_resolution=1024) == 10


def test_size_for_cost_keeps_the_aspect_and_the_square_side():
    # c_r 0.3 of a 1024 px input: a square side of 560.88; at 2:1, 560.88 sqrt(2) = 793.2 by 560.88 / sqrt(2) = 396.6
    assert size_for_cost(UV, 0.3, reference_uv=UV, reference_resolution=1024) == (561, 561)
    assert size_for_cost(UV, 0.3, reference_uv=UV, reference_resolution=1024, aspect=2.0) == (793, 397)
    width, height = size_for_cost(UV, 0.3, reference_uv=UV, reference_resolution=1024, aspect=0.75)
    assert (width, height) == (486, 648)  # 560.88 sqrt(3/4) = 485.7, 560.88 / sqrt(3/4) = 647.6
    assert relative_cost(UV, (width, height), reference_uv=UV, reference_resolution=1024) == pytest.approx(0.3,
                                                                                                          rel=2e-3)
    with pytest.raises(ValueError, match="aspect"):
        size_for_cost(UV, 0.3, reference_uv=UV, reference_resolution=1024, aspect=0)


def test_zero_area_is_refused():
    flat = np.zeros((1, 3, 2))
    with pytest.raises(ValueError, match="zero area"):
        resolution_for_cost(flat, 0.3, reference_uv=UV, reference_resolution=64)
    with pytest.raises(ValueError, match="shape"):
        uv_area(np.zeros((3, 2)))


SQUARE = [[[0.0, 0.0], [0.5, 0.0], [0.5, 0.5]], [[0.0, 0.0], [0.5, 0.5], [0.0, 0.5]]]  # [0, 1/2]^2, two triangles


def test_texel_reuse_by_hand():
    # 8 x 8 texture: the square covers 16 texel centres and has area 16 texels.
    assert texel_reuse(SQUARE, (8, 8)) == 1.0
    assert texel_reuse(SQUARE * 3, (8, 8)) == 3.0  # three islands laid on the same texels
    unit = np.array(SQUARE) * 2.0
    assert texel_reuse(unit * 2.0, (8, 16)) == 4.0  # the whole texture tiled 2 x 2 (non-square: 8 rows, 16 columns)


def test_texel_reuse_wraps_like_the_texture():
    # The square moved across the texture's corner (REPEAT): still 16 texels used once each.
    assert texel_reuse(np.array(SQUARE) + 0.75, (8, 8)) == 1.0
    assert np.isnan(texel_reuse(np.array(SQUARE) * 1e-3 + 0.01, (8, 8)))  # covers no texel centre
