"""The loss overlay's colours (hand-computed ramp points)."""
import numpy as np

from perceptual_uv.bridge.loss_overlay import loss_ramp


def test_the_ramp_is_green_at_zero_yellow_at_the_bound_and_red_from_twice_the_bound():
    epsilon = 0.01
    rgba = loss_ramp([0.0, 0.005, 0.01, 0.015, 0.02, 0.5], epsilon)
    expected = np.array([[0.0, 1.0, 0.0, 1.0],   # E = 0
                         [0.5, 1.0, 0.0, 1.0],   # half the bound: t = 1/4
                         [1.0, 1.0, 0.0, 1.0],   # the bound
                         [1.0, 0.5, 0.0, 1.0],   # t = 3/4
                         [1.0, 0.0, 0.0, 1.0],   # twice the bound
                         [1.0, 0.0, 0.0, 1.0]])  # clipped
    assert rgba.dtype == np.float32
    np.testing.assert_array_equal(rgba, expected.astype(np.float32))
