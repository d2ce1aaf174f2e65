import numpy as np
import pytest

from perceptual_uv.core.chartfit import fit_charts
from perceptual_uv.core.charts import uv_topology

# Two unit squares, one chart each. In both, the two triangles want half their size (lambda = 0.5) and angles
# pi/8 apart: without rotation terms a similarity meets both stretches exactly, with them the chart bends.
SQUARE = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
UV = np.concatenate([SQUARE, SQUARE + [2, 0]])
TARGETS = np.tile([[0.0, 0.5, 0.5, 0.0], [np.pi / 8, 0.5, 0.5, 0.0]], (2, 1))
WEIGHTS = np.full(4, 1e-3)


def _jacobians(new_uv):
    def edges(t):
        return np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]], axis=-1)
    return edges(new_uv) @ np.linalg.inv(edges(UV))


def _angle_error(J, alpha=TARGETS[:, 0]):
    angle = np.arctan2(J[:, 1, 0] - J[:, 0, 1], J[:, 0, 0] + J[:, 1, 1]) - alpha
    return np.abs(np.mod(angle + np.pi / 4, np.pi / 2) - np.pi / 4)


def _chart_loss_of(new_uv):
    """Chart 0 is judged by anisotropy (sigma1 / sigma2 - 1), chart 1 by the angle error to the targets."""
    J = _jacobians(new_uv)
    sigma = np.linalg.svd(J, compute_uv=False)
    return np.where(np.arange(4) < 2, sigma[:, 0] / sigma[:, 1] - 1, _angle_error(J))


def _chart_loss(fits):
    """``fit_charts``'s measure: :func:`_chart_loss_of` of each of the two fits."""
    assert len(fits) == 2
    return np.stack([_chart_loss_of(new_uv) for new_uv in fits])


def test_each_chart_keeps_the_fit_its_losses_prefer():
    calls = []
    fit = fit_charts(F, UV, TARGETS, WEIGHTS, WEIGHTS, measure=_chart_loss, progress=lambda *p: calls.append(p))
    np.testing.assert_array_equal(fit.rotation_fit, [False, True])
    # Chart 0, without rotation terms: a similarity of scale 0.5, then turned to the angle that minimizes
    # (1 - cos theta) + (1 - cos(theta - pi/8)), i.e. pi/16.
    np.testing.assert_allclose(fit.angles[0], np.pi / 16, atol=1e-6)
    J = _jacobians(fit.uv)
    np.testing.assert_allclose(np.linalg.svd(J[:2], compute_uv=False), 0.5, atol=1e-6)
    np.testing.assert_allclose(_angle_error(J[:2], TARGETS[:2, 0]), np.pi / 16, atol=1e-6)
    # Chart 1 kept the bent fit: its angle errors are below the pi/16 each that the similarity leaves at best.
    assert np.all(fit.losses[2:] < np.pi / 16 - 0.05)
    np.testing.assert_allclose(fit.losses, _chart_loss_of(fit.uv), atol=1e-12)
    assert fit.flipped == 0 and fit.restored.size == 0 and len(fit.fits) == 2
    done = [d for d, _ in calls]
    assert done == sorted(done) and calls[-1][0] == calls[-1][1]


def test_a_measure_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match="one loss per face"):
        fit_charts(F, UV, TARGETS, WEIGHTS, WEIGHTS, measure=lambda fits: np.zeros((2, 3)))
    with pytest.raises(ValueError, match="each of the two fits"):  # one fit's losses only
        fit_charts(F, UV, TARGETS, WEIGHTS, WEIGHTS, measure=lambda fits: _chart_loss_of(fits[0]))
    with pytest.raises(ValueError, match="targets"):
        fit_charts(F, UV, TARGETS[:, :3], WEIGHTS, WEIGHTS, measure=_chart_loss)
    with pytest.raises(ValueError, match="topology does not belong"):
        fit_charts(F, UV, TARGETS, WEIGHTS, WEIGHTS, measure=_chart_loss, topology=uv_topology(F[:2], UV[:2]))


def test_a_given_topology_gives_the_same_fit():
    fit = fit_charts(F, UV, TARGETS, WEIGHTS, WEIGHTS, measure=_chart_loss, topology=uv_topology(F, UV))
    np.testing.assert_array_equal(fit.uv, fit_charts(F, UV, TARGETS, WEIGHTS, WEIGHTS, measure=_chart_loss).uv)
