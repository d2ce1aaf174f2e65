"""E is finite for every deformation of the box, and a triangle whose E is not still does not end the run (issue 22).

A public vehicle (2048 px texture, overlapping islands, zero-UV-area triangles) crashed the triangle-wise stage
with ``ZeroDivisionError`` from the loss kernel: a Cholesky pivot of the re-bake's normal equations rounded to
zero or below, its square root was NaN, and numba's division check in a ``fastmath`` kernel raises on a NaN
divisor. Pixels of a zero-UV-area face all read one texture point, which makes a rank-1 block whose entries
grow with the pixel count while the ridge stays 1e-9.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from perceptual_uv.core import trianglewise as tw
from perceptual_uv.core.bake_lsq import DEFAULT_RIDGE, _band_cholesky_solve, _envelope_cholesky_solve
from perceptual_uv.core.loss import TriangleProblem, prepare_triangles

BOX = np.array([[0.0, np.pi / 2], [tw.LAMBDA_MIN, 1.0], [tw.LAMBDA_MIN, 1.0], [0.0, np.pi / 2]])


@pytest.mark.parametrize("pixels", [1e3, 1e6, 1e8, 1e9])
def test_a_rank_one_block_renders_its_target_whatever_its_weight(pixels):
    """``N`` pixels reading one point with bilinear weights ``w``: the normal matrix is ``N w w^T + r I`` and
    the right-hand side ``N t w``. By Sherman-Morrison the solution is ``x = N t w / (N |w|^2 + r)``, which
    renders ``w . x = t N |w|^2 / (N |w|^2 + r)``, i.e. ``t`` within ``r / (N |w|^2)``. From ``N`` about 1e7
    the pivots after the first round below zero in about one case in seven; each must still give ``t``."""
    rng = np.random.default_rng(3)
    ridge = DEFAULT_RIDGE
    for _ in range(200):
        fx, fy = rng.random(2)
        w = np.array([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
        t = rng.random()
        A = pixels * np.outer(w, w) + ridge * np.eye(4)
        rhs = pixels * t * w
        band = np.zeros((4, 4))
        for d in range(4):
            band[: 4 - d, d] = np.diagonal(A, d)
        x_band = rhs.copy()
        _band_cholesky_solve(band, x_band, ridge)
        first = np.zeros(4, np.int64)
        offset = np.array([0, 1, 3, 6, 10])
        env = np.concatenate([A[i, : i + 1] for i in range(4)])
        x_env = rhs.copy()
        _envelope_cholesky_solve(env, offset, first, x_env, ridge)
        exact = t * pixels * (w @ w) / (pixels * (w @ w) + ridge)
        for x in (x_band, x_env):
            assert np.all(np.isfinite(x))
            assert w @ x == pytest.approx(exact, abs=1e-6)


def _texture(size, seed):
    """A texture with detail at every scale (sums of random sinusoids) and a flat region."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    luma = np.zeros((size, size))
    for _ in range(12):
        fx, fy = rng.uniform(-size / 6, size / 6, 2)
        luma += np.sin(2 * np.pi * (fx * x + fy * y) + rng.uniform(0, 2 * np.pi))
    luma = (luma - luma.min()) / np.ptp(luma)
    luma[:, : size // 4] = 0.5
    return luma


TEXTURE_2048 = None


def _texture_2048():
    global TEXTURE_2048
    if TEXTURE_2048 is None:
        TEXTURE_2048 = _texture(2048, 0)
    return TEXTURE_2048


def _fan(sides, radius_texels, texture_size, *, centre, collapsed, overlapped, tilt):
    """A fan of ``sides`` triangles around vertex 0 on a near-planar surface, its UVs a disc of
    ``radius_texels``; ``collapsed`` neighbours get zero UV area (all corners on one point), ``overlapped``
    ones are moved onto the first triangle's UVs (an island laid over another)."""
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    V = np.vstack([[0.0, 0.0, 0.0], np.column_stack([np.cos(angles), np.sin(angles), tilt * np.cos(3 * angles)])])
    F = np.array([[0, 1 + i, 1 + (i + 1) % sides] for i in range(sides)])
    disc = np.vstack([[0.0, 0.0], np.column_stack([np.cos(angles), np.sin(angles)])])
    uv = (np.asarray(centre) + disc * radius_texels / texture_size)[F]
    for face in collapsed:
        uv[face] = uv[face, 0]
    for face in overlapped:
        uv[face] = uv[0]
    return V, F, uv


def _assert_finite_in_box(problem, params):
    values = problem.evaluate(params)
    assert np.all(np.isfinite(values)), params[~np.isfinite(values)]
    assert np.all((values >= 0) & (values <= 1))  # a standard deviation of GMS values in (0, 1]


def test_the_reported_shape_a_2000_texel_triangle_in_a_256_pixel_view_of_a_2048_texture():
    """Issue 22's failing triangles: ~2000 texels in UV on a 2048 px texture, views of 256 px with most pixels
    covered, neighbours of zero UV area and overlapping islands; E finite over the whole box."""
    texture = _texture_2048()
    # Legs of 70 texels: the first triangle spans 0.5 * 70^2 * sin(2 pi / 7) = 1915 texels.
    V, F, uv = _fan(7, 70.0, 2048, centre=(0.55, 0.45), collapsed=[2, 3, 5], overlapped=[4], tilt=0.05)
    problem = prepare_triangles(V, F, uv, texture, [0], screen_pixels=256)[0]
    assert 1800 < problem.uv_area < 2000
    assert len(problem.pixel) > 0.5 * 256 * 256
    rng = np.random.default_rng(0)
    params = BOX[:, 0] + (BOX[:, 1] - BOX[:, 0]) * rng.random((64, 4))
    corners = np.array([[a, l1, l2, b] for a in BOX[0] for l1 in BOX[1] for l2 in BOX[2] for b in BOX[3]])
    _assert_finite_in_box(problem, np.vstack([params, corners]))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sides=st.integers(3, 9), radius=st.floats(2.0, 120.0), view=st.sampled_from([64, 96, 128, 192, 256]),
       collapsed=st.sets(st.integers(1, 8), max_size=4), overlapped=st.sets(st.integers(1, 8), max_size=2),
       tilt=st.floats(0.0, 0.5), seed=st.integers(0, 2**16))
def test_loss_is_finite_for_random_triangles_views_and_deformations(sides, radius, view, collapsed, overlapped,
                                                                    tilt, seed):
    texture = _texture_2048()
    collapsed = [f for f in collapsed if f < sides]
    overlapped = [f for f in overlapped if f < sides and f not in collapsed]
    V, F, uv = _fan(sides, radius, 2048, centre=(0.3, 0.6), collapsed=collapsed, overlapped=overlapped, tilt=tilt)
    problem = prepare_triangles(V, F, uv, texture, [0], screen_pixels=view)[0]
    rng = np.random.default_rng(seed)
    _assert_finite_in_box(problem, BOX[:, 0] + (BOX[:, 1] - BOX[:, 0]) * rng.random((6, 4)))


def test_a_triangle_whose_loss_cannot_be_evaluated_is_skipped_and_counted(monkeypatch):
    """No worker may raise on valid input: face 1's loss raises (as the kernel did) and face 2's is NaN; both
    keep the identity (their input shape and size) with weights 0, and the others are optimized as before."""
    texture = _texture(256, 1)
    V, F, uv = _fan(4, 20.0, 256, centre=(0.5, 0.5), collapsed=[], overlapped=[], tilt=0.1)
    expected = tw.optimize_triangles(V, F, uv, texture, evaluations=20, workers=1)
    evaluate = TriangleProblem.evaluate

    def failing(self, params):
        if self.face == 1:
            raise ZeroDivisionError("division by zero")
        values = evaluate(self, params)
        return np.full_like(values, np.nan) if self.face == 2 else values

    monkeypatch.setattr(TriangleProblem, "evaluate", failing)
    result = tw.optimize_triangles(V, F, uv, texture, evaluations=20, workers=1)
    np.testing.assert_array_equal(result.unevaluated, [False, True, True, False])
    np.testing.assert_array_equal(result.params[[1, 2]], [[0.0, 1.0, 1.0, 0.0]] * 2)
    assert np.all(np.isnan(result.loss[[1, 2]])) and not result.feasible[[1, 2]].any()
    np.testing.assert_array_equal(result.w_R[[1, 2]], 0.0)
    np.testing.assert_array_equal(result.params[[0, 3]], expected.params[[0, 3]])
    targets = result.fit_targets(uv, texture)
    np.testing.assert_array_equal(targets[[1, 2]], [[0.0, 1.0, 1.0, 0.0]] * 2)
    np.testing.assert_array_equal(expected.unevaluated, False)
