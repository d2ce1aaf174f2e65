# SPDX-License-Identifier: GPL-3.0-or-later
"""core.signal_metric and core.ssp (Sander et al. 2002): metric tensors, expected stretch, SSP solve and SSPOP
targets."""
import pathlib

import numpy as np
import pytest

from perceptual_uv.core.charts import uv_topology
from perceptual_uv.core.deformation import jacobian
from perceptual_uv.core.evaluation import _triangle_frames
from perceptual_uv.core.mesh import read_obj
from perceptual_uv.core import signal_metric
from perceptual_uv.core.progress import run_generator
from perceptual_uv.core.signal_metric import iter_signal_metric_tensors, signal_metric_tensors
from perceptual_uv.core.ssp import expected_stretch, iter_ssp_targets, solve_ssp, ssp_energy, ssp_targets

TRIANGLE = np.array([[[0.2, 0.2], [0.8, 0.2], [0.3, 0.9]]])
FACE = np.array([[0, 1, 2]])


def _flat(uv, scale):
    """3D triangles lying in z = 0 as the UVs times ``scale`` (so the frame's x axis is along edge 0-1)."""
    m = uv.shape[0]
    V = np.concatenate([uv.reshape(-1, 2) * scale, np.zeros((3 * m, 1))], axis=1)
    return V, np.arange(3 * m).reshape(m, 3)


def _grid(k):
    xs = np.linspace(0.0, 1.0, k + 1)
    P = np.array([[x, y, 0.0] for y in xs for x in xs])
    F = []
    for j in range(k):
        for i in range(k):
            a = j * (k + 1) + i
            F += [[a, a + 1, a + k + 2], [a, a + k + 2, a + k + 1]]
    F = np.array(F)
    return P, F, P[:, :2][F].copy()


def _uv_det(uv):
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


# --- metric tensor ------------------------------------------------------------------------------------------

def test_horizontal_ramp_has_one_eigenvalue_along_u():
    h, w = 32, 64
    ramp = np.tile(np.arange(w) * 0.5 / w, (h, 1))  # f rises 0.5 per unit of u, constant in v
    V, F = _flat(TRIANGLE, 3.0)  # the surface is the UV triangle scaled by 3: grad_x f = (0.5 / 3, 0)
    gamma = signal_metric_tensors(V, F, TRIANGLE, ramp)
    area = 0.5 * 9.0 * abs(_uv_det(TRIANGLE)[0])
    np.testing.assert_allclose(gamma[0], [[area * (0.5 / 3) ** 2, 0.0], [0.0, 0.0]], atol=1e-15)
    # Colour: the three channels add up (the ramp in R and G, constant B) unless luma is asked for.
    rgb = np.dstack([ramp, ramp, np.full_like(ramp, 0.3)])
    np.testing.assert_allclose(signal_metric_tensors(V, F, TRIANGLE, rgb), 2 * gamma, atol=1e-15)
    luma = (0.299 + 0.587) ** 2 * gamma
    np.testing.assert_allclose(signal_metric_tensors(V, F, TRIANGLE, rgb, channels="luma"), luma, atol=1e-15)


def test_tensor_is_intrinsic_to_the_surface():
    # The ramp again on a triangle rotated in 3D and with rotated UVs: the eigenvalues stay area * 0.25 / 9
    # and 0, and the eigenvector is the 3D direction along which u grows.
    h, w = 32, 64
    ramp = np.tile(np.arange(w) * 0.5 / w, (h, 1))
    V, F = _flat(TRIANGLE, 3.0)
    c, s = np.cos(0.4), np.sin(0.4)
    Rz = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    gamma = signal_metric_tensors(V @ Rz.T, F, TRIANGLE, ramp)
    area = 0.5 * 9.0 * abs(_uv_det(TRIANGLE)[0])
    np.testing.assert_allclose(np.linalg.eigvalsh(gamma[0]), [0.0, area * 0.25 / 9], atol=1e-15)


def test_constant_texture_gives_zero_tensor():
    V, F = _flat(TRIANGLE, 1.0)
    assert np.all(signal_metric_tensors(V, F, TRIANGLE, np.full((16, 16, 3), 0.7)) == 0.0)


def test_checker_is_nearly_isotropic():
    n = 64
    yy, xx = np.mgrid[0:n, 0:n]
    checker = (((xx // 4) + (yy // 4)) % 2).astype(float)
    uv = np.array([[[0.05, 0.05], [0.95, 0.05], [0.05, 0.95]]])
    V, F = _flat(uv, 1.0)
    g = np.linalg.eigvalsh(signal_metric_tensors(V, F, uv, checker, max_level=64)[0])
    assert g[0] > 0 and g[1] / g[0] < 1.03
    # A striped texture on the same triangle is strongly anisotropic: the ratio test can fail.
    stripes = ((xx // 4) % 2).astype(float)
    g = np.linalg.eigvalsh(signal_metric_tensors(V, F, uv, stripes, max_level=64)[0])
    assert g[0] < 1e-12 * g[1]


def test_metric_validation():
    V, F = _flat(TRIANGLE, 1.0)
    with pytest.raises(ValueError, match="texture"):
        signal_metric_tensors(V, F, TRIANGLE, np.zeros(5))
    with pytest.raises(ValueError, match="channels"):
        signal_metric_tensors(V, F, TRIANGLE, np.zeros((4, 4)), channels="red")
    with pytest.raises(ValueError, match="outside"):
        signal_metric_tensors(V[:2], F, TRIANGLE, np.zeros((4, 4)))


# --- expected stretch -----------------------------------------------------------------------------------------

def test_expected_stretch_by_hand():
    # Two triangles of area 1 and 2; densities diag(16, 1) rotated by 30 degrees, and 4 I.
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    Rt = np.array([[c, -s], [s, c]])
    area = np.array([1.0, 2.0])
    metric = np.stack([Rt @ np.diag([16.0, 1.0]) @ Rt.T, 2.0 * 4.0 * np.eye(2)])
    l1, l2, theta = expected_stretch(metric, area)
    # Unnormalised: sqrt(g) (g1 g2)^(-1/8): (4 / sqrt 2, 1 / sqrt 2) and (sqrt 2, sqrt 2); areas 2 and 4,
    # so c^2 = 3 / (2 * 1 + 2 * 2) = 1/2.
    cst = np.sqrt(0.5)
    np.testing.assert_allclose(l1, cst * np.array([4 / np.sqrt(2), np.sqrt(2)]))
    np.testing.assert_allclose(l2, cst * np.array([1 / np.sqrt(2), np.sqrt(2)]))
    assert theta[0] == pytest.approx(np.pi / 6)
    assert (l1 * l2 * area).sum() == pytest.approx(area.sum())
    with pytest.raises(ValueError, match="singular"):
        expected_stretch(np.stack([np.diag([1.0, 0.0]), np.eye(2)]), area)


# --- energy and solver ---------------------------------------------------------------------------------------

def _free_triangles(seed, m=4):
    """m disconnected triangles (each its own chart) with random SPD tensors."""
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(3 * m, 3))
    F = np.arange(3 * m).reshape(m, 3)
    uv = rng.normal(size=(m, 3, 2))
    _, area = _triangle_frames(V, F)
    Q = rng.normal(size=(m, 2, 2))
    return V, F, uv, (Q @ np.swapaxes(Q, 1, 2) + 0.1 * np.eye(2)) * area[:, None, None], area


def _lower_bound(metric, area):
    # Cauchy-Schwarz on (sum t^2 a_T)(sum b_T / t^2) with each triangle at its optimal shape G^(1/2):
    # E* = (sum sqrt(2) |T| (g1 g2)^(1/4))^2 / sum |T|.
    g = np.linalg.eigvalsh(metric / area[:, None, None])
    return (np.sqrt(2) * area * (g[:, 0] * g[:, 1]) ** 0.25).sum() ** 2 / area.sum()


def test_energy_of_an_isometric_map_is_the_integrated_squared_gradient():
    V, F, uv, metric, area = _free_triangles(0)
    X, _ = _triangle_frames(V, F)
    isometric = np.zeros_like(uv)
    isometric[:, 1, 0] = X[:, 0, 0]
    isometric[:, 2] = X[:, :, 1]
    expected = np.trace(metric, axis1=1, axis2=2).sum()
    assert ssp_energy(V, F, isometric, metric) == pytest.approx(expected, rel=1e-12)
    assert ssp_energy(V, F, 3.0 * isometric + 1.0, metric) == pytest.approx(expected, rel=1e-12)  # scale-free


def test_free_triangles_reach_the_analytic_optimum():
    V, F, uv, metric, area = _free_triangles(1)
    result = solve_ssp(V, F, uv, metric=metric, geometric_weight=0.0, tol=1e-13)
    assert result.converged and result.flipped == 0
    assert result.energy_history[-1] == pytest.approx(_lower_bound(metric, area), rel=1e-7)
    assert np.all(np.diff(result.energy_history) <= 1e-12 * result.energy_history[0])
    # The solved shapes are the expected stretch up to one common scale and a rotation per triangle.
    X, _ = _triangle_frames(V, F)
    U = np.stack([result.uv[:, 1] - result.uv[:, 0], result.uv[:, 2] - result.uv[:, 0]], axis=2)
    singular = np.linalg.svd(U @ np.linalg.inv(X), compute_uv=False)
    l1, l2, _ = expected_stretch(metric, area)
    ratio = singular / np.column_stack([l1, l2])
    np.testing.assert_allclose(ratio, ratio[0, 0], rtol=1e-5)
    # Orientation of every triangle is the input's; total UV area is the input's.
    assert np.all(np.sign(_uv_det(result.uv)) == np.sign(_uv_det(uv)))
    assert np.abs(_uv_det(result.uv)).sum() == pytest.approx(np.abs(_uv_det(uv)).sum())


def test_energy_derivatives_match_central_differences():
    # The solver's gradient is built from these per-triangle derivatives of the UV area and signal stretch.
    V, F, uv, metric, area = _free_triangles(2, m=1)
    from perceptual_uv.core import ssp as module

    X, _ = _triangle_frames(V, F)
    U = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)
    orientation = np.sign(_uv_det(uv))
    edge_metric = np.swapaxes(X, 1, 2) @ metric @ X
    _, _, d_area, d_stretch = module._energy_parts(U, orientation, edge_metric)
    h = 1e-6
    for i in range(2):
        for j in range(2):
            dU = np.zeros_like(U)
            dU[0, i, j] = h
            plus = module._energy_parts(U + dU, orientation, edge_metric)
            minus = module._energy_parts(U - dU, orientation, edge_metric)
            assert (plus[0] - minus[0])[0] / (2 * h) == pytest.approx(d_area[0, i, j], rel=1e-6, abs=1e-9)
            assert (plus[1] - minus[1])[0] / (2 * h) == pytest.approx(d_stretch[0, i, j], rel=1e-6, abs=1e-9)


def test_ssp_on_a_chart_moves_texels_to_the_detail_and_stays_flip_free():
    P, F, uv = _grid(8)
    n = 128
    _, xx = np.mgrid[0:n, 0:n]
    texture = np.where(xx < n // 2, 0.5 + 0.5 * np.sin(xx * 2 * np.pi / 6), 0.5)  # detail on the left only
    result = solve_ssp(P, F, uv, texture)
    before = ssp_energy(P, F, uv, result.metric)
    after = ssp_energy(P, F, result.uv, result.metric)
    assert after < 0.2 * before
    assert result.energy_history[0] == pytest.approx(before) and result.energy_history[-1] == pytest.approx(after)
    assert result.flipped == 0 and np.all(_uv_det(result.uv) > 0)
    # Cuts kept: one chart, corners of one vertex share their UV.
    topology = uv_topology(F, result.uv)
    assert topology.n_charts == 1 and topology.n_vertices == P.shape[0]
    # The textured half gets most of the UV area; the conforming map cannot beat the free-triangle bound.
    area = np.abs(_uv_det(result.uv)) / 2
    left = P[F].mean(axis=1)[:, 0] < 0.5
    assert area[left].sum() > 3 * area[~left].sum()
    _, surface = _triangle_frames(P, F)
    assert after >= _lower_bound(result.metric, surface) * (1 - 1e-9)


def test_solver_validation():
    V, F, uv, metric, _ = _free_triangles(3, m=2)
    with pytest.raises(ValueError, match="texture or a precomputed metric"):
        solve_ssp(V, F, uv)
    collapsed = uv.copy()
    collapsed[:] = [[0, 0], [1, 1], [2, 2]]
    with pytest.raises(ValueError, match="no triangle has both surface area and UV area"):
        solve_ssp(V, F, collapsed, metric=metric)


def test_a_triangle_without_uv_area_is_left_out_and_the_others_reach_their_optimum():
    # The input gives triangle 0 no UV area (its signal stretch is infinite there): it is left out, so the other
    # three are the free-triangle problem without it, whose optimum is the bound of those three alone.
    V, F, uv, metric, area = _free_triangles(1)
    uv[0] = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]
    result = solve_ssp(V, F, uv, metric=metric, geometric_weight=0.0, tol=1e-13)
    assert result.converged and result.flipped == 0
    assert result.energy_history[-1] == pytest.approx(_lower_bound(metric[1:], area[1:]), rel=1e-7)
    assert np.all(np.sign(_uv_det(result.uv[1:])) == np.sign(_uv_det(uv[1:])))
    # Its own chart has nothing to fit: it stays collapsed about its UV centroid.
    assert _uv_det(result.uv[:1])[0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(result.uv[0].mean(axis=0), [1.0, 1.0], atol=1e-12)


# --- SSPOP targets --------------------------------------------------------------------------------------------

def test_targets_are_the_expected_stretch_relative_to_the_input():
    V, F, uv, metric, area = _free_triangles(4)
    params, w_R, w_S = ssp_targets(V, F, uv, metric=metric, geometric_weight=0.0)
    assert np.all(w_R == 0) and np.all(w_S == 1) and np.all(params[:, 0] == 0)
    # phi = A_T A_in^-1 with A_T the optimal shape: the stretch S of phi times A_in must have the singular
    # values of the expected stretch (phi's rotation is free), up to the common normalisation.
    X, _ = _triangle_frames(V, F)
    U_in = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)
    _, S = jacobian(params)
    singular = np.linalg.svd(S @ U_in @ np.linalg.inv(X), compute_uv=False)
    l1, l2, _ = expected_stretch(metric, area)
    ratio = singular / np.column_stack([l1, l2])
    np.testing.assert_allclose(ratio, ratio[0, 0], rtol=1e-10)
    # Scaled into Eq. 14's box (0, 1].
    assert params[:, 1].max() == pytest.approx(1.0) and np.all(params[:, 2] <= params[:, 1])
    assert np.all(params[:, 2] > 0)


def test_sspop_through_the_mesh_wise_solver_matches_ssp_on_free_triangles():
    meshwise = pytest.importorskip("perceptual_uv.core.meshwise")
    V, F, uv, metric, area = _free_triangles(5)
    params, w_R, w_S = ssp_targets(V, F, uv, metric=metric, geometric_weight=0.0)
    result = meshwise.solve_meshwise(F, uv, params, w_R, w_S)
    assert result.flipped == 0
    assert ssp_energy(V, F, result.uv, metric) == pytest.approx(_lower_bound(metric, area), rel=1e-6)


# --- generator forms ------------------------------------------------------------------------------------------

def _steps(generator):
    """Every item ``generator`` yields, and what it returns."""
    steps = []
    result = run_generator(generator, lambda *item: steps.append(item))
    return steps, result


def test_generator_forms_hand_control_back_and_do_not_depend_on_the_slicing(monkeypatch):
    """Slices of 256 integration points and 640 texels (several per level of subdivision, several bands of
    rows) give, bit for bit, the tensors of a single slice per level and band, and the same targets.

    The targets are compared to 1e-12: the 2 x 2 eigen-decompositions that turn the tensors into targets vary
    in the last bit from one call to the next (with the same tensors and the same slicing, as they did when
    the computation was one call)."""
    V, F, uv = _grid(12)  # 288 faces
    uv = 0.1 + 0.8 * uv
    texture = np.random.default_rng(3).random((80, 64, 4))
    V = V + np.array([0.0, 0.0, 0.3]) * np.sin(3 * V[:, :1])  # curved, so the faces' frames differ
    monkeypatch.setattr(signal_metric, "_POINTS_PER_SLICE", 1 << 40)
    monkeypatch.setattr(signal_metric, "_TEXELS_PER_SLICE", 1 << 40)
    whole = {channels: (signal_metric_tensors(V, F, uv, texture, channels=channels),
                        ssp_targets(V, F, uv, texture, channels=channels)) for channels in ("all", "luma")}
    monkeypatch.setattr(signal_metric, "_POINTS_PER_SLICE", 256)
    monkeypatch.setattr(signal_metric, "_TEXELS_PER_SLICE", 640)
    for channels, (metric, targets) in whole.items():
        steps, sliced = _steps(iter_signal_metric_tensors(V, F, uv, texture, channels=channels))
        np.testing.assert_array_equal(sliced, metric)
        assert steps[:8] == [(0, 288)] * 8  # one per band of 10 rows, before the integration
        done = [item[0] for item in steps[8:]]
        assert len(done) > 10 and done == sorted(done) and done[-1] == 288
        steps, sliced = _steps(iter_ssp_targets(V, F, uv, texture, channels=channels))
        assert len(steps) > 10
        for got, expected in zip(sliced, targets):
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ssp_targets(V, F, uv, texture, channels=channels)[0], targets[0], rtol=0,
                                   atol=1e-12)
    # A precomputed metric leaves nothing to integrate: the generator returns without yielding.
    steps, given = _steps(iter_ssp_targets(V, F, uv, metric=whole["all"][0]))
    assert steps == []
    np.testing.assert_allclose(given[0], whole["all"][1][0], rtol=0, atol=1e-12)


def test_generator_forms_check_their_input_like_the_one_call_forms():
    with pytest.raises(ValueError, match="NaN"):
        run_generator(iter_ssp_targets(*_flat(TRIANGLE, 1.0), TRIANGLE, np.full((4, 4), np.nan)))
    with pytest.raises(ValueError, match="needs a texture"):
        run_generator(iter_ssp_targets(*_flat(TRIANGLE, 1.0), TRIANGLE))


# --- the bundled spot model -----------------------------------------------------------------------------------

SPOT = pathlib.Path(__file__).resolve().parent / "data" / "spot"


def _load_spot():
    """The spot mesh (:func:`core.mesh.read_obj`) and its PNG texture with row 0 at the bottom."""
    matplotlib_image = pytest.importorskip("matplotlib.image")
    V, F, uv = read_obj(SPOT / "spot_triangulated.obj")
    texture = matplotlib_image.imread(SPOT / "spot_texture.png")[::-1]
    return V, F, uv, np.ascontiguousarray(texture[..., :3], dtype=np.float64)


@pytest.mark.slow
def test_ssp_and_sspop_on_spot_lower_signal_stretch_flip_free():
    meshwise = pytest.importorskip("perceptual_uv.core.meshwise")
    V, F, uv, texture = _load_spot()
    metric = signal_metric_tensors(V, F, uv, texture)
    result = solve_ssp(V, F, uv, metric=metric, max_iterations=300)
    before = result.energy_history[0]
    assert result.flipped == 0 and np.all(np.sign(_uv_det(result.uv)) == np.sign(_uv_det(uv)))
    assert result.energy_history[-1] < 0.1 * before
    assert uv_topology(F, result.uv).n_charts == uv_topology(F, uv).n_charts
    params, w_R, w_S = ssp_targets(V, F, uv, metric=metric)
    sspop = meshwise.solve_meshwise(F, uv, params, w_R, w_S, max_iterations=100)
    assert sspop.flipped == 0
    assert ssp_energy(V, F, sspop.uv, result.metric) < 0.25 * before
