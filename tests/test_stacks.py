"""Charts that share texels in the input stay stacked (core.stacks), through the post-processing and the packing."""
import numpy as np
import pytest

from perceptual_uv.core.chartfit import finish_charts, fit_charts
from perceptual_uv.core.packing import pack_charts
from perceptual_uv.core.stacks import packing_islands, restack_charts, stacked_charts, stacked_faces

# A square of side 1/4 as two triangles; charts are copies of it.
SQUARE = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]]) * 0.25


def _charts(*offsets):
    uv = np.concatenate([SQUARE + offset for offset in offsets])
    return uv, np.repeat(np.arange(len(offsets)), 2)


def test_charts_on_the_same_texels_stack_and_a_chart_elsewhere_does_not():
    # 0 and 1 coincide; 2 is elsewhere; 3 lies one unit to the right of 0 (the image repeats): same texels.
    uv, face_chart = _charts([0, 0], [0, 0], [0.5, 0.5], [1, 0])
    np.testing.assert_array_equal(stacked_charts(uv, face_chart), [0, 0, 1, 0])


def test_a_chain_of_overlaps_is_one_stack():
    # 0 overlaps 1 by half its area, 1 overlaps 2 by half: 0 and 2 share nothing but stack through 1.
    uv, face_chart = _charts([0, 0], [0.125, 0], [0.25, 0], [0.6, 0.6])
    np.testing.assert_array_equal(stacked_charts(uv, face_chart), [0, 0, 0, 1])


@pytest.mark.parametrize("shift, stacked", [(0.25 * 0.995, False), (0.25 * 0.985, True)])
def test_charts_stack_when_they_share_more_than_the_share_of_the_smaller(shift, stacked):
    # Two squares of area 1/16 overlapping in a strip 0.25 - shift wide: shared fraction (0.25 - shift) / 0.25,
    # 0.5 % and 1.5 % against the 1 % default.
    uv, face_chart = _charts([0, 0], [shift, 0])
    labels = stacked_charts(uv, face_chart)
    assert (labels[0] == labels[1]) == stacked


def test_restacked_charts_take_the_input_layout_at_their_summed_new_area():
    uv_in, face_chart = _charts([0, 0], [0, 0], [0.5, 0.5], [1, 0])
    uv_new = uv_in + [[0.0, 0.0]]
    uv_new[face_chart == 0] *= 2  # area 1/16 -> 1/4
    uv_new[face_chart == 1] = uv_new[face_chart == 1] * 0.5 + 3  # 1/16 -> 1/64, moved
    uv_new[face_chart == 2] *= 3  # not stacked: left as the method made it
    stack = stacked_charts(uv_in, face_chart)
    uv = restack_charts(uv_in, uv_new, face_chart, stack)
    # Stack {0, 1, 3}: input areas 3/16, new areas 1/4 + 1/64 + 1/16 = 21/64, so s^2 = (21/64) / (3/16) = 7/4.
    s = np.sqrt(7 / 4)
    for chart in (0, 1, 3):
        np.testing.assert_allclose(uv[face_chart == chart], SQUARE * s, atol=1e-12)
    np.testing.assert_array_equal(uv[face_chart == 2], uv_new[face_chart == 2])


def test_a_stack_turns_as_one_and_keeps_sharing_its_texels():
    uv_in, face_chart = _charts([0, 0], [0, 0], [0.5, 0.5])
    # Every triangle wants to turn by 30 degrees (Eq. 16's rotation target), weighed equally.
    alpha, w_R = np.full(6, np.pi / 6), np.ones(6)
    stack = stacked_charts(uv_in, face_chart)
    uv, restored, angles = finish_charts(uv_in, uv_in * 2, face_chart, alpha=alpha, w_R=w_R, stacks=stack)
    np.testing.assert_allclose(uv[face_chart == 0], uv[face_chart == 1], atol=1e-12)
    np.testing.assert_allclose(angles, np.pi / 6, atol=1e-6)
    edge = uv[0, 1] - uv[0, 0]
    np.testing.assert_allclose(np.arctan2(edge[1], edge[0]), np.pi / 6, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(edge), 0.5, atol=1e-12)  # the stack's area is kept
    assert restored.size == 0


def test_the_charts_of_a_stack_keep_the_same_fit():
    # Two coinciding unit squares, each wanting half its size; the measure prefers the fit with rotation terms
    # for chart 0's triangles and the fit without them for chart 1's, with chart 0's preference the stronger.
    square = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
    uv = np.concatenate([square, square])
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    targets = np.tile([[0.0, 0.5, 0.5, 0.0], [np.pi / 8, 0.5, 0.5, 0.0]], (2, 1))
    weights = np.full(4, 1e-3)

    def preferences():  # the fit measures the plain fit and the one with rotation terms, in that order
        def measure(fits):
            assert len(fits) == 2
            return np.array([[5.0, 5.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0]])
        return measure

    stack = stacked_charts(uv, np.repeat([0, 1], 2))
    np.testing.assert_array_equal(stack, [0, 0])
    fit = fit_charts(F, uv, targets, weights, weights, measure=preferences(), stacks=stack)
    # Per chart, chart 1 keeps the plain fit (0 < 1); as a stack, 0 + 2 < 10 + 0 gives both the turned one.
    np.testing.assert_array_equal(fit.rotation_fit, [True, True])
    np.testing.assert_allclose(fit.uv[:2], fit.uv[2:], atol=1e-12)
    unstacked = fit_charts(F, uv, targets, weights, weights, measure=preferences())
    np.testing.assert_array_equal(unstacked.rotation_fit, [True, False])


def test_a_stack_packs_as_one_island():
    uv_in, face_chart = _charts([0, 0], [0, 0], [0, 0], [0, 0], [0.5, 0.5])
    stack = stacked_charts(uv_in, face_chart)
    face_stack = stacked_faces(face_chart, stack)
    np.testing.assert_array_equal(face_stack, [0] * 8 + [-1, -1])
    islands = packing_islands(face_chart, face_stack)
    np.testing.assert_array_equal(islands, [1] * 8 + [0, 0])  # charts alone first, then the stacks
    packing = pack_charts(uv_in, islands, margin=1, texels_per_unit=32)
    for chart in (1, 2, 3):
        np.testing.assert_allclose(packing.uv[2 * chart:2 * chart + 2], packing.uv[:2], atol=1e-12)
    # Two islands where there were five: the packed image is smaller.
    assert packing.width < pack_charts(uv_in, face_chart, margin=1, texels_per_unit=32).width  # squares both


def test_islands_of_a_method_that_cuts_a_chart_keep_its_pieces_alone():
    # The method's charts (its own cuts) 0, 1, 2; faces 0-3 in stack 4 of the input: one island, the rest apart.
    islands = packing_islands(np.array([0, 0, 1, 1, 2, 2]), np.array([4, 4, 4, 4, -1, -1]))
    np.testing.assert_array_equal(islands, [1, 1, 1, 1, 0, 0])


def test_bad_input_is_refused():
    uv, face_chart = _charts([0, 0], [0, 0])
    with pytest.raises(ValueError, match="share"):
        stacked_charts(uv, face_chart, share=1.0)
    with pytest.raises(ValueError, match="face_chart"):
        stacked_charts(uv, face_chart[:3])
    with pytest.raises(ValueError, match="one stack per chart"):
        restack_charts(uv, uv, face_chart, [0])
