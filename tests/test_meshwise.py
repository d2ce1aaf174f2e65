import json
import pathlib

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from perceptual_uv.core.charts import uv_topology
from perceptual_uv.core.deformation import rotation
from perceptual_uv.core.mesh import read_obj
from perceptual_uv.core.progress import run_generator
from perceptual_uv.core.chart_orientation import orient_charts
from perceptual_uv.core.meshwise import flipped_triangles, iter_solve_meshwise, solve_meshwise
from perceptual_uv.core.meshwise_global import _Objective, _prepare, barrier
from perceptual_uv.core.meshwise_local import _local_update_kernel, _local_update_reference, fit_energy, local_step

HERE = pathlib.Path(__file__).resolve().parent
SPOT = HERE / "data" / "spot" / "spot_triangulated.obj"
SHARED_MODELS = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "models"


_COMPONENT = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}


def load_gltf_faces_and_uv(path):
    """Minimal glTF 2.0 reader (external .bin): triangle primitives with TEXCOORD_0, all meshes concatenated."""
    path = pathlib.Path(path)
    doc = json.loads(path.read_text())
    buffers = [(path.parent / b["uri"]).read_bytes() for b in doc["buffers"]]

    def accessor(index):
        acc = doc["accessors"][index]
        view = doc["bufferViews"][acc["bufferView"]]
        dtype = np.dtype(_COMPONENT[acc["componentType"]])
        width = _WIDTH[acc["type"]]
        item = dtype.itemsize * width
        stride = view.get("byteStride", item)
        offset = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        raw = np.frombuffer(buffers[view["buffer"]], dtype=np.uint8, count=stride * (acc["count"] - 1) + item,
                            offset=offset)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(acc["count"], item), strides=(stride, 1)).copy()
        return rows.view(dtype).reshape(acc["count"], width)

    faces, uvs, offset = [], [], 0
    for mesh in doc["meshes"]:
        for primitive in mesh["primitives"]:
            if primitive.get("mode", 4) != 4 or "TEXCOORD_0" not in primitive["attributes"]:
                continue
            texcoord = accessor(primitive["attributes"]["TEXCOORD_0"]).astype(np.float64)
            tris = accessor(primitive["indices"]).reshape(-1, 3).astype(np.int64)
            faces.append(tris + offset)
            uvs.append(texcoord[tris])
            offset += len(texcoord)
    return np.concatenate(faces), np.concatenate(uvs)


def random_box_targets(m, seed):
    rng = np.random.default_rng(seed)
    params = np.column_stack([rng.uniform(0, np.pi / 2, m), rng.uniform(0.05, 1, m), rng.uniform(0.05, 1, m),
                              rng.uniform(0, np.pi / 2, m)])
    return params, rng.uniform(0, 1, m), rng.uniform(0, 1, m)


@pytest.fixture(scope="module")
def spot():
    return read_obj(SPOT)[1:]


def polar(A):
    U, s, Vt = np.linalg.svd(A)
    return U @ Vt, Vt.T @ np.diag(s) @ Vt


# --- barrier ---------------------------------------------------------------------------------------------

def test_barrier_values_by_hand():
    # s = 1: g(t) = 1 - (1 - t)^3; d = 0.5 gives g = 0.875, B = 1/0.875 - 1 = 1/7.
    value, _, _ = barrier([0.5, 1.0, 2.0, 0.0, -1.0], [1.0] * 5)
    np.testing.assert_allclose(value[:3], [1 / 7, 0.0, 0.0], atol=1e-15)
    assert np.all(np.isinf(value[3:]))


def test_barrier_derivatives_match_finite_differences_and_vanish_at_threshold():
    d = np.array([0.01, 0.1, 0.3, 0.7, 0.95])
    s = np.full_like(d, 0.8)
    h = 1e-6
    value, first, second = barrier(d, s)
    np.testing.assert_allclose(first, (barrier(d + h, s)[0] - barrier(d - h, s)[0]) / (2 * h), rtol=1e-6)
    np.testing.assert_allclose(second, (barrier(d + h, s)[1] - barrier(d - h, s)[1]) / (2 * h), rtol=1e-5)
    # C2 at the threshold: value, first and second derivative go to 0 from below.
    # Near s with gap e: B ~ e^3, B' ~ e^2, B'' ~ 6 e / s^3 (from g(t) = 1 - (1 - t)^3).
    gap = 1e-6
    value, first, second = barrier([0.8 - gap], [0.8])
    assert value[0] < 1e-15 and abs(first[0]) < 1e-10
    np.testing.assert_allclose(second, 6 * gap / 0.8 ** 3, rtol=1e-4)


# --- local step ------------------------------------------------------------------------------------------

def test_local_step_without_fit_weights_recovers_polar_factors():
    R_true = rotation(np.array([0.3, 1.2, -2.0]))
    S_true = np.array([[[2.0, 0.3], [0.3, 0.5]], [[1.0, 0], [0, 1.0]], [[0.4, -0.1], [-0.1, 0.9]]])
    J = R_true @ S_true
    zeros = np.zeros(3)
    # Two sweeps from S = I (the theta update uses the previous S).
    S_prev = np.tile(np.eye(2), (3, 1, 1))
    for _ in range(30):
        k, R, S, energy = local_step(J, np.tile(np.eye(2), (3, 1, 1)), S_true, zeros, zeros, 1e-5, S_prev)
        S_prev = S
    np.testing.assert_allclose(R @ S, J, atol=1e-10)
    np.testing.assert_allclose(energy, 0.0, atol=1e-15)


def _random_local_problem(rng, m, *, shift):
    """Random Jacobians ``J`` (``shift * I`` added), target rotations ``R_bar`` and SPD targets ``S_bar``."""
    J = rng.normal(size=(m, 2, 2)) + shift * np.eye(2)
    R_bar = rotation(rng.uniform(0, 2 * np.pi, m))
    A = rng.normal(size=(m, 2, 2))
    return J, R_bar, A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(2)


def test_local_step_theta_and_stretch_minimize_their_blocks():
    rng = np.random.default_rng(1)
    m = 5
    J, R_bar, S_bar = _random_local_problem(rng, m, shift=2.0)
    S_prev = S_bar + 0.05
    w_R, w_S, w_rs = rng.uniform(0.1, 2, m), rng.uniform(0.1, 2, m), 0.7
    k, R, S, energy = local_step(J, R_bar, S_bar, w_R, w_S, w_rs, S_prev)
    grid = np.linspace(-np.pi, np.pi, 2001)
    for i in range(m):
        candidates = []
        for kk in range(4):
            turned = rotation(kk * np.pi / 2) @ R_bar[i]

            def block(t):
                Rt = rotation(t)
                return w_R[i] * np.sum((Rt - turned) ** 2) + w_rs * np.sum((J[i] - Rt @ S_prev[i]) ** 2)

            t0 = grid[np.argmin([block(t) for t in grid])]
            theta = minimize_scalar(block, bracket=(t0 - 0.01, t0 + 0.01), tol=1e-12).x
            Rk = rotation(theta)
            # Eq. 26 over symmetric S: least squares in (s11, s12, s22), the off-diagonal counted twice.
            rows, rhs = [], []
            for weight, M in ((w_S[i], S_bar[i]), (w_rs, Rk.T @ J[i])):
                sw = np.sqrt(weight)
                rows += [[sw, 0, 0], [0, sw, 0], [0, sw, 0], [0, 0, sw]]
                rhs += [sw * M[0, 0], sw * M[0, 1], sw * M[1, 0], sw * M[1, 1]]
            s11, s12, s22 = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0]
            Sk = np.array([[s11, s12], [s12, s22]])
            e = (w_R[i] * np.sum((Rk - turned) ** 2) + w_S[i] * np.sum((Sk - S_bar[i]) ** 2)
                 + w_rs * np.sum((J[i] - Rk @ Sk) ** 2))
            candidates.append((e, kk, Rk, Sk))
        e, kk, Rk, Sk = min(candidates, key=lambda c: c[0])
        assert k[i] == kk
        np.testing.assert_allclose(R[i], Rk, atol=1e-6)
        np.testing.assert_allclose(S[i], Sk, atol=1e-6)
        np.testing.assert_allclose(energy[i], e, rtol=1e-7)


def test_local_update_kernel_matches_numpy_reference():
    rng = np.random.default_rng(7)
    m = 200
    J, R_bar, S_bar = _random_local_problem(rng, m, shift=1.5)
    w_R, w_S = rng.uniform(0, 2, m), rng.uniform(0, 2, m)
    w_R[:20] = w_S[:20] = 0.0  # flat texture: no fit weight
    k = rng.integers(0, 4, m)
    R = rotation(rng.uniform(0, 2 * np.pi, m))
    S = S_bar + 0.1
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    expected = _local_update_reference(J, R_bar, S_bar, w_R, w_S, 1e-2, k, R, S)
    k2, R2, S2 = k.copy(), R.copy(), S.copy()
    energy = _local_update_kernel(J, R_bar, S_bar, w_R, w_S, 1e-2, k2, R2, S2)
    np.testing.assert_array_equal(k2, expected[0])
    np.testing.assert_allclose(R2, expected[1], atol=1e-12)
    np.testing.assert_allclose(S2, expected[2], atol=1e-12)
    np.testing.assert_allclose(energy, expected[3], rtol=1e-10, atol=1e-14)


def test_hessian_kernel_matches_numpy_reference_and_finite_differences(spot):
    F, uv = spot
    F, uv = F[:300], uv[:300]
    topology = uv_topology(F, uv)
    rng = np.random.default_rng(8)
    S_bar = np.tile(0.8 * np.eye(2), (len(F), 1, 1))
    problem = _prepare(topology, uv, S_bar, degenerate_tol=1e-10, barrier_threshold=0.5)
    x = topology.vertex_uv * [0.5, 0.45] + rng.normal(scale=1e-4, size=topology.vertex_uv.shape)
    J = problem.jacobians(x)
    det = np.linalg.det(J)
    assert np.all(det > 0) and np.any(det < problem.threshold)  # some barrier terms active
    objective = _Objective(problem, rotation(rng.uniform(0, 1, len(F))) @ S_bar, 0.3, 0.05, 0.0)
    grad, blocks = objective.gradient_and_blocks(J)
    grad_ref, blocks_ref = objective.gradient_and_blocks_reference(J)
    np.testing.assert_allclose(grad, grad_ref, rtol=1e-10, atol=1e-12 * np.abs(grad_ref).max())
    np.testing.assert_allclose(blocks, blocks_ref, rtol=1e-10, atol=1e-12 * np.abs(blocks_ref).max())
    # The gradient is the derivative of the objective (central differences along a random direction).
    direction = rng.normal(size=x.shape)
    direction[problem.free_index[: len(x)] < 0] = 0.0
    h = 1e-7
    numeric = (objective.value(problem.jacobians(x + h * direction))
               - objective.value(problem.jacobians(x - h * direction))) / (2 * h)
    reduced = np.concatenate([direction[:, 0], direction[:, 1]])[problem.free_index >= 0]
    np.testing.assert_allclose(grad @ reduced, numeric, rtol=1e-5)


def test_fit_energy_is_zero_for_a_quarter_turn_of_the_target():
    R_bar = rotation(np.array([0.4, 0.1]))
    S_bar = np.array([[[0.5, 0.1], [0.1, 0.3]], [[1.0, 0.0], [0.0, 0.2]]])
    J = rotation(np.array([np.pi / 2, np.pi])) @ R_bar @ S_bar
    for formulation in ("perceptual", "common"):
        energy, k = fit_energy(J, R_bar, S_bar, np.ones(2), np.ones(2), formulation=formulation)
        np.testing.assert_allclose(energy, 0.0, atol=1e-14)
        np.testing.assert_array_equal(k, [1, 2])


# --- solver on hand-sized meshes -------------------------------------------------------------------------

SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])
SQUARE_UV = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])


def test_square_follows_an_affine_target_exactly():
    A = np.array([[0.3, 0.1], [-0.05, 0.6]])  # det > 0
    R, S = polar(A)
    targets = (np.stack([R, R]), np.stack([S, S]))
    result = solve_meshwise(SQUARE_F, SQUARE_UV, targets, weights="identity")
    expected = SQUARE_UV @ A.T
    # Up to translation and a quarter turn (the solver picks the k nearest the input, here k = 0).
    new = result.uv - result.uv[0, 0] + expected[0, 0]
    np.testing.assert_allclose(new, expected, atol=1e-10)
    assert result.flipped == 0 and result.degenerate == 0


def test_degenerate_input_triangle_does_not_stop_the_solve():
    F = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    uv = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]], [[1, 0], [1, 0.5], [1, 1]]])  # collinear
    params = np.tile([0.2, 0.5, 0.8, 0.3], (3, 1))
    result = solve_meshwise(F, uv, params, weights="identity")
    assert result.degenerate == 1 and result.flipped == 0
    assert np.all(np.isfinite(result.uv))
    # The degenerate triangle's corners still follow their chart vertices.
    np.testing.assert_array_equal(result.uv[2, 0], result.uv[0, 1])
    # Vertex 4, touched by the degenerate triangle only, was halfway along the edge 1-2: the fit is one affine
    # map (uniform targets), which carries it to the middle of that edge, so the triangle stays degenerate.
    np.testing.assert_allclose(result.uv[2, 1], 0.5 * (result.uv[0, 1] + result.uv[0, 2]), atol=1e-12)


def test_generator_yields_progress_and_returns_the_result():
    params = np.tile([0.2, 0.5, 0.8, 0.3], (2, 1))
    generator = iter_solve_meshwise(SQUARE_F, SQUARE_UV, params, weights="identity", max_iterations=5)
    steps = []
    result = run_generator(generator, lambda *step: steps.append(step))
    # the set-up (repeated while the Hessian's pattern is built in a thread, on a loaded machine), then each iteration
    assert list(dict.fromkeys(steps)) == [(i, 5) for i in range(0, result.iterations + 1)]
    calls = []
    solve_meshwise(SQUARE_F, SQUARE_UV, params, weights="identity", max_iterations=5,
                   progress=lambda done, total: calls.append((done, total)))
    assert list(dict.fromkeys(calls)) == list(dict.fromkeys(steps))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({}, "needs w_R and w_S"),
        ({"weights": "unit"}, "weights must be"),
        ({"weights": "identity", "formulation": "frobenius"}, "formulation must be"),
        ({"weights": "identity", "w_rs": 0.0}, "w_rs must be positive"),
        ({"weights": "identity", "max_iterations": 0}, "at least 1"),
    ],
)
def test_bad_options_raise(kwargs, message):
    with pytest.raises(ValueError, match=message):
        solve_meshwise(SQUARE_F, SQUARE_UV, np.tile([0.0, 0.5, 0.5, 0.0], (2, 1)), **kwargs)


def test_bad_targets_raise():
    with pytest.raises(ValueError, match="params of shape"):
        solve_meshwise(SQUARE_F, SQUARE_UV, np.zeros((2, 3)), weights="identity")
    with pytest.raises(ValueError, match="positive definite"):
        solve_meshwise(SQUARE_F, SQUARE_UV, np.tile([0.0, -0.5, 0.5, 0.0], (2, 1)), weights="identity")
    with pytest.raises(ValueError, match="rotations"):
        solve_meshwise(SQUARE_F, SQUARE_UV, (np.tile(2 * np.eye(2), (2, 1, 1)), np.tile(np.eye(2), (2, 1, 1))),
                       weights="identity")


# --- chart orientation -----------------------------------------------------------------------------------

def _texel_jacobians(uv_in, uv_new, scale=(1.0, 1.0)):
    scale = np.asarray(scale)[:, None]
    old = np.stack([uv_in[:, 1] - uv_in[:, 0], uv_in[:, 2] - uv_in[:, 0]], axis=-1) * scale
    new = np.stack([uv_new[:, 1] - uv_new[:, 0], uv_new[:, 2] - uv_new[:, 0]], axis=-1) * scale
    return new @ np.linalg.inv(old)


def test_orient_charts_turns_rigidly_turned_charts_back_to_their_targets():
    # Chart 0 (the square) was turned by 0.3 and halved, chart 1 (a lone triangle) turned by 1.0; both want
    # their input orientation (alpha = 0), so they turn by -0.3 and -1.0 modulo a quarter turn.
    uv_in = np.concatenate([SQUARE_UV, [[[2.0, 0], [3, 0], [2, 2]]]])
    uv_new = uv_in.copy()
    uv_new[:2] = 0.5 * uv_in[:2] @ rotation(0.3).T
    uv_new[2] = uv_in[2] @ rotation(1.0).T + 5
    uv, angles = orient_charts(uv_in, uv_new, np.array([0, 0, 1]), np.zeros(3), np.ones(3))
    np.testing.assert_allclose(angles, [np.pi / 2 - 0.3, np.pi / 2 - 1.0], atol=1e-12)
    J = _texel_jacobians(uv_in, uv)
    np.testing.assert_allclose(J, np.stack([0.5 * rotation(np.pi / 2)] * 2 + [rotation(np.pi / 2)]), atol=1e-12)
    # Turned about the corners' mean, so the chart stays where it was.
    np.testing.assert_allclose(uv[2].mean(axis=0), uv_new[2].mean(axis=0), atol=1e-12)


def test_orient_charts_weighs_the_triangles_targets():
    # Both halves of the square keep the input map; their targets are 0 and 0.2 with weights 1 and 3 (equal
    # areas). Within a quarter turn the energy is 1 - cos(theta) + 3 (1 - cos(theta - 0.2)), least at
    # tan(theta) = 3 sin(0.2) / (1 + 3 cos(0.2)): theta = 0.15013.
    uv, angles = orient_charts(SQUARE_UV, SQUARE_UV, np.zeros(2, dtype=int), np.array([0.0, 0.2]), np.array([1.0, 3.0]))
    expected = np.arctan2(3 * np.sin(0.2), 1 + 3 * np.cos(0.2))
    assert abs(expected - 0.15013) < 1e-5
    np.testing.assert_allclose(angles, [expected], atol=1e-10)
    np.testing.assert_allclose(_texel_jacobians(SQUARE_UV, uv), rotation(np.full(2, expected)), atol=1e-12)
    # A quarter turn more in a target changes nothing (Eq. 16's symmetry).
    _, turned = orient_charts(SQUARE_UV, SQUARE_UV, np.zeros(2, dtype=int), np.array([np.pi / 2, 0.2 - np.pi]),
                              np.array([1.0, 3.0]))
    np.testing.assert_allclose(turned, angles, atol=1e-10)


def test_orient_charts_measures_angles_on_the_texel_grid():
    # A 2:1 texture: the chart was turned by 0.4 in texels, which is a shear in UV units.
    scale = np.array([2.0, 1.0])
    uv_new = (SQUARE_UV * scale) @ rotation(0.4).T / scale
    uv, angles = orient_charts(SQUARE_UV, uv_new, np.zeros(2, dtype=int), np.zeros(2), np.ones(2), texel_scale=scale)
    np.testing.assert_allclose(angles, [np.pi / 2 - 0.4], atol=1e-12)
    np.testing.assert_allclose(_texel_jacobians(SQUARE_UV, uv, scale), rotation(np.full(2, np.pi / 2)),
                               atol=1e-12)


def test_orient_charts_leaves_charts_without_rotation_weight_alone():
    uv_new = 0.5 * SQUARE_UV @ rotation(0.3).T
    uv, angles = orient_charts(SQUARE_UV, uv_new, np.zeros(2, dtype=int), np.array([0.1, 0.7]), np.zeros(2))
    np.testing.assert_array_equal(angles, [0.0])
    np.testing.assert_array_equal(uv, uv_new)


def test_flipped_triangles_compare_orientations_and_skip_degenerate_ones():
    flat = [[[0.0, 0], [1, 0], [2, 0]]]  # collinear: degenerate in the input, never counted
    uv_in = np.concatenate([SQUARE_UV, flat, SQUARE_UV[:1, ::-1]])  # the last one is clockwise
    uv_new = uv_in.copy()
    uv_new[1] = uv_in[1] * [-1, 1]  # mirrored: flipped
    uv_new[2] = [[0, 0], [1, 0], [0, 1]]
    uv_new[3] = 0.5 * uv_in[3]  # still clockwise, like its input
    np.testing.assert_array_equal(flipped_triangles(uv_in, uv_new), [False, True, False, False])
    uv_new[0, 1] = uv_new[0, 0]  # collapsed to zero area: counted
    assert flipped_triangles(uv_in, uv_new)[0]


@pytest.mark.parametrize("kwargs, message", [
    (dict(uv_new=np.zeros((2, 3))), "shape"),
    (dict(face_chart=np.array([0, -1])), "numbered from 0"),
    (dict(face_chart=np.zeros(2)), "numbered from 0"),
    (dict(alpha=np.array([0.0, np.nan])), "finite"),
    (dict(w_R=np.array([1.0, -1.0])), "non-negative"),
    (dict(texel_scale=(1.0, 0.0)), "texel_scale"),
    (dict(samples=0), "samples"),
])
def test_orient_charts_rejects_bad_input(kwargs, message):
    args = dict(uv_in=SQUARE_UV, uv_new=SQUARE_UV, face_chart=np.zeros(2, dtype=int), alpha=np.zeros(2),
                w_R=np.ones(2))
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        orient_charts(**args)


# --- real model (issue 4, must show 5) -------------------------------------------------------------------

def _chart_error_up_to_translation_and_quarter_turn(topology, new_uv, expected_uv):
    worst = 0.0
    for chart in range(topology.n_charts):
        faces = topology.chart_faces(chart)
        new = new_uv[faces].reshape(-1, 2)
        expected = expected_uv[faces].reshape(-1, 2)
        expected = expected - expected.mean(axis=0)
        errors = []
        for k in range(4):
            turned = expected @ rotation(k * np.pi / 2).T
            errors.append(np.linalg.norm(new - new.mean(axis=0) - turned) / np.linalg.norm(expected))
        worst = max(worst, min(errors))
    return worst


@pytest.mark.parametrize("formulation", ["perceptual", "common"])
def test_a_square_texture_solves_in_uv_units_bit_for_bit(spot, formulation):
    """``texel_scale=(w, w)`` is the solve in UV units (``texel_scale`` left out, as before it existed), bit for
    bit: the texel frame of a square texture is ``(1, 1)`` exactly, whatever ``w``."""
    F, uv = spot
    params, w_R, w_S = random_box_targets(len(F), 5)
    options = dict(formulation=formulation, max_iterations=8)
    reference = solve_meshwise(F, uv, params, w_R, w_S, **options)
    for w in (1024, 0.1):
        result = solve_meshwise(F, uv, params, w_R, w_S, texel_scale=(w, w), **options)
        np.testing.assert_array_equal(result.uv, reference.uv)
        np.testing.assert_array_equal(result.energy_history, reference.energy_history)
        np.testing.assert_array_equal(result.quarter_turns, reference.quarter_turns)
        assert result.fit_energy == reference.fit_energy
    np.testing.assert_array_equal(flipped_triangles(uv, reference.uv, texel_scale=(512, 512)),
                                  flipped_triangles(uv, reference.uv))


@pytest.mark.parametrize("formulation", ["perceptual", "common"])
def test_recovers_a_real_map_scaled_and_rotated_per_chart(spot, formulation):
    F, uv = spot
    topology = uv_topology(F, uv)
    assert -1 in topology.chart_orientation  # spot has a mirrored chart: it must be recovered as well
    # Per chart: half scale, a quarter turn and a chart-specific extra angle, so targets differ by chart.
    extra = 0.37 * np.arange(topology.n_charts)
    angle = np.pi / 2 + extra[topology.face_chart]
    m = len(F)
    params = np.column_stack([angle, np.full(m, 0.5), np.full(m, 0.5), np.zeros(m)])
    rng = np.random.default_rng(0)
    result = solve_meshwise(F, uv, params, rng.uniform(0.5, 2, m), rng.uniform(0.5, 2, m), formulation=formulation)
    expected = np.einsum("tij,tcj->tci", 0.5 * rotation(angle), uv)
    assert _chart_error_up_to_translation_and_quarter_turn(topology, result.uv, expected) <= 1e-6
    assert result.flipped == 0 and result.converged


def test_recovers_a_mirrored_copy_mirrored(spot):
    # Reflecting the input (u -> -u) and conjugating the targets must give the reflected solution.
    F, uv = spot
    m = len(F)
    params, w_R, w_S = random_box_targets(m, seed=4)
    from perceptual_uv.core.deformation import jacobian

    R_bar, S_bar = jacobian(params)
    P = np.diag([-1.0, 1.0])
    plain = solve_meshwise(F, uv, (R_bar, S_bar), w_R, w_S, max_iterations=15, tol=0)
    mirrored = solve_meshwise(F, uv @ P, (P @ R_bar @ P, P @ S_bar @ P), w_R, w_S, max_iterations=15, tol=0)
    assert mirrored.flipped == 0 and plain.flipped == 0
    assert _chart_error_up_to_translation_and_quarter_turn(plain.topology, mirrored.uv @ P, plain.uv) < 1e-8


@pytest.mark.parametrize("options", [{}, {"weights": "identity"}, {"formulation": "common"},
                                     {"newton_iterations": 3}])
def test_objective_never_increases_and_charts_keep_cuts_and_sharing(spot, options):
    F, uv = spot
    params, w_R, w_S = random_box_targets(len(F), seed=2)
    result = solve_meshwise(F, uv, params, w_R, w_S, max_iterations=30, **options)
    history = result.energy_history
    assert len(history) == result.iterations + 1 and result.iterations >= 3
    assert np.all(np.diff(history) <= 0), np.diff(history).max()
    assert history[-1] < history[0]
    assert result.flipped == 0
    # Same chart vertices (shared corners stay shared, seams stay seams) and same charts.
    before = uv_topology(F, uv)
    after = uv_topology(F, result.uv)
    np.testing.assert_array_equal(after.corner_vertex, before.corner_vertex)
    np.testing.assert_array_equal(after.face_chart, before.face_chart)
    np.testing.assert_array_equal(after.seam_edges, before.seam_edges)


def test_fit_improves_on_the_input_map(spot):
    F, uv = spot
    m = len(F)
    params, w_R, w_S = random_box_targets(m, seed=5)
    from perceptual_uv.core.deformation import jacobian

    R_bar, S_bar = jacobian(params)
    result = solve_meshwise(F, uv, params, w_R, w_S)
    area = np.abs(np.cross(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]))
    a = area / area.mean()
    at_input, _ = fit_energy(np.tile(np.eye(2), (m, 1, 1)), R_bar, S_bar, w_R, w_S)
    assert result.fit_energy < 0.5 * np.sum(a * at_input)


def _shared_models():
    if not SHARED_MODELS.is_dir():
        return []
    found = []
    for folder in sorted(p for p in SHARED_MODELS.iterdir() if p.is_dir()):
        files = sorted(folder.glob("*.gltf")) + sorted(folder.glob("*.obj"))
        if files:
            found.append(files[0])
    return found


@pytest.mark.slow
@pytest.mark.skipif(not SHARED_MODELS.is_dir(), reason="../shared/models is not available")
@pytest.mark.parametrize("path", _shared_models(), ids=lambda p: p.parent.name)
def test_no_flips_on_shared_models_with_random_box_targets(path):
    F, uv = load_gltf_faces_and_uv(path) if path.suffix == ".gltf" else read_obj(path)[1:]
    params, w_R, w_S = random_box_targets(len(F), seed=0)
    result = solve_meshwise(F, uv, params, w_R, w_S, max_iterations=30)
    assert result.flipped == 0
    assert np.all(np.diff(result.energy_history) <= 0)
    new_area = np.cross(result.uv[:, 1] - result.uv[:, 0], result.uv[:, 2] - result.uv[:, 0])
    old_area = np.cross(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0])
    valid = np.abs(old_area) > 1e-10 * np.max(np.sum(np.diff(uv[:, [0, 1, 2, 0]], axis=1) ** 2, axis=2), axis=1)
    assert np.all(np.sign(new_area[valid]) == np.sign(old_area[valid]))
