import dataclasses
import math
import os
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from perceptual_uv.core import spawn
from perceptual_uv.core import textured as tex
from perceptual_uv.core import trianglewise as tw
from perceptual_uv.core.deformation import jacobian
from perceptual_uv.core.loss import triangle_problem
from perceptual_uv.core.progress import run_generator

from meshes import grid_mesh  # tests/ is on sys.path under pytest

CENTRE_FACE = 36  # inside the grid: its one-ring is complete
SIZE = 64


def _stripes(period_texels=2):
    columns = (np.arange(SIZE) // (period_texels // 2)) % 2
    return np.tile(columns[None, :].astype(np.float64), (SIZE, 1))


def _smooth_texture():
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    return 0.5 + 0.25 * np.sin(2 * np.pi * x / 9.0) * np.cos(2 * np.pi * y / 13.0) + 0.2 * np.sin(
        2 * np.pi * (x + y) / 23.0)


class AnalyticProblem:
    """Stand-in with a closed-form E, for the weights' arithmetic."""

    is_constant = False
    uv_area = 10.0

    def __init__(self, loss):
        self.loss = loss

    def evaluate(self, params):
        return self.loss(np.atleast_2d(params))


# --- objective pieces ----------------------------------------------------------------------------------------


def test_finite_barrier_matches_eq12_inside_and_continues_smoothly():
    eps = 0.01
    inside = np.array([0.0, 0.005, 0.0099])
    np.testing.assert_allclose(tw.finite_barrier(inside, eps), -np.log(eps - inside))
    delta = eps / 100
    joint = eps - delta
    h = 1e-9
    left = tw.finite_barrier([joint - h], eps)[0]
    right = tw.finite_barrier([joint + h], eps)[0]
    assert right - left == pytest.approx(2 * h / delta, rel=1e-3)  # continuous, same slope on both sides
    slope_right = (tw.finite_barrier([joint + 2 * h], eps)[0] - right) / h
    assert slope_right == pytest.approx(1 / delta, rel=1e-3)  # slope of -log(eps - x) at the joint
    values = tw.finite_barrier([0.02, 0.1, 0.5, 5.0], eps)
    assert np.all(np.isfinite(values)) and np.all(np.diff(values) > 0)
    assert values[-1] == pytest.approx(-math.log(delta) + math.log1p((5.0 - joint) / delta))


# --- weights (Eq. 17) ----------------------------------------------------------------------------------------


def test_rotation_weight_of_sin_squared_is_exact():
    # E = a sin^2(2 alpha): on [0, pi/2) the mean is 1/2 and E[sin^4] = 3/8, so Var = a^2 / 8; the 8-point
    # midpoint rule integrates these trigonometric polynomials exactly.
    a = 0.03
    problem = AnalyticProblem(lambda P: a * np.sin(2 * P[:, 0]) ** 2)
    w_R, w_S, used = tw.sensitivity_weights(problem, [0.4, 0.5, 0.6, 0.2])
    assert w_R == pytest.approx(a * a / 8, rel=1e-12)
    assert w_S == pytest.approx(0.0, abs=1e-20)  # E does not depend on (lambda1, lambda2, beta)
    assert used == tw.ROTATION_SAMPLES + tw.STRETCH_SAMPLES


def test_stretch_weight_of_linear_loss_near_uniform_variance():
    # E = b lambda1 with lambda1 ~ U[0.1, 1]: Var = b^2 0.9^2 / 12; 16 scrambled Sobol points get within 10 %.
    b = 0.02
    problem = AnalyticProblem(lambda P: b * P[:, 1])
    w_R, w_S, _ = tw.sensitivity_weights(problem, [0.4, 0.5, 0.6, 0.2])
    assert w_R == pytest.approx(0.0, abs=1e-20)  # E does not depend on alpha
    assert w_S == pytest.approx(b * b * 0.81 / 12, rel=0.1)


# --- optimization on real loss problems ----------------------------------------------------------------------


def test_constant_texture_skips_to_smallest_area():
    V, F, uv = grid_mesh()
    problem = triangle_problem(V, F, uv, np.full((SIZE, SIZE), 0.4), CENTRE_FACE)
    assert problem.is_constant
    found = tw.optimize_triangle(problem)
    np.testing.assert_array_equal(found.params, [0.0, tw.LAMBDA_MIN, tw.LAMBDA_MIN, 0.0])
    assert (found.loss, found.w_R, found.w_S, found.evaluations) == (0.0, 0.0, 0.0, 0)


def test_constant_texture_optimizer_reaches_box_minimum():
    # The same triangle with the skip disabled: E = 0 everywhere, so the optimizer must return area
    # lambda_min^2 (the first two evaluations already contain the corner) and zero weights.
    V, F, uv = grid_mesh()
    problem = triangle_problem(V, F, uv, np.full((SIZE, SIZE), 0.4), CENTRE_FACE)
    found = tw.optimize_triangle(dataclasses.replace(problem, is_constant=False))
    assert found.params[1] * found.params[2] == pytest.approx(tw.LAMBDA_MIN ** 2)
    assert found.loss == pytest.approx(0.0, abs=1e-12)
    assert found.w_R == pytest.approx(0.0, abs=1e-20) and found.w_S == pytest.approx(0.0, abs=1e-20)
    assert found.evaluations == 2 + tw.ROTATION_SAMPLES + tw.STRETCH_SAMPLES


def test_the_search_hands_over_to_the_bisection_once_the_feasible_boundary_is_settled():
    # Feasible only at the identity (E = 1 elsewhere). The identity and the corner come first (2 evaluations),
    # then 8 Latin-hypercube points: 9 evaluations after the identity without a smaller feasible area. Rounds of 4
    # take that to 13, 17, 21, 25 >= PATIENCE = 24: the search stops after 2 + 8 + 16 = 26. The bisection from
    # the identity then fails 6 times on each eigenvalue (12 evaluations, its whole share), and the weights add 24.
    def loss(P):
        return np.where(np.all(P == [0.0, 1.0, 1.0, 0.0], axis=1), 0.0, 1.0)

    assert tw.PATIENCE == 24
    settled = tw.optimize_triangle(AnalyticProblem(loss))
    whole = tw.optimize_triangle(AnalyticProblem(loss), patience=None)
    assert settled.evaluations == 26 + 12 + tw.ROTATION_SAMPLES + tw.STRETCH_SAMPLES
    assert whole.evaluations == 100 + tw.ROTATION_SAMPLES + tw.STRETCH_SAMPLES
    np.testing.assert_array_equal(settled.params, [0.0, 1.0, 1.0, 0.0])
    np.testing.assert_array_equal(whole.params, [0.0, 1.0, 1.0, 0.0])


def test_vertical_stripes_keep_resolution_across_and_shrink_along():
    # Columns alternate 0/1 (the texel frequency), constant along v. By hand: the new texels must keep the
    # x spacing and stay aligned with the stripes, or the 1-texel period aliases (a 5-degree turn already
    # gives E ~ 0.17 >> epsilon); along v the signal is constant, so that direction can shrink to lambda_min.
    # Hence grad phi = R(k pi/2) diag(1, s) with s small: A e_x of length 1 on a lattice axis, A e_y
    # perpendicular to it and short.
    V, F, uv = grid_mesh()
    problem = triangle_problem(V, F, uv, _stripes(2), CENTRE_FACE)
    found = tw.optimize_triangle(problem, seed=0)
    R, S = jacobian(found.params)
    A = R @ S
    across, along = A[:, 0], A[:, 1]
    assert found.loss <= 0.01
    assert np.linalg.norm(across) == pytest.approx(1.0, abs=0.03)
    angle = np.degrees(np.arctan2(across[1], across[0])) % 90
    assert min(angle, 90 - angle) < 2.0  # aligned with the texel grid
    assert np.linalg.norm(along) < 0.25
    assert abs(across @ along) < 0.05 * np.linalg.norm(along)
    # and alpha, beta themselves sit on the grid (0 or pi/2 up to the box's periodic ends)
    for angle in (found.params[0], found.params[3]):
        assert min(angle % (np.pi / 2), np.pi / 2 - angle % (np.pi / 2)) < np.radians(2.0)
    assert found.w_R > 0 and found.w_S > 0


def test_larger_epsilon_gives_no_larger_area():
    V, F, uv = grid_mesh()
    problem = triangle_problem(V, F, uv, _smooth_texture(), CENTRE_FACE)
    tight = tw.optimize_triangle(problem, epsilon=0.003, seed=3)
    loose = tw.optimize_triangle(problem, epsilon=0.03, seed=3)
    assert tight.loss <= 0.003 and loose.loss <= 0.03
    assert loose.params[1] * loose.params[2] <= tight.params[1] * tight.params[2]


def test_barrier_formulation_feasible_and_weights_nonnegative():
    V, F, uv = grid_mesh()
    problem = triangle_problem(V, F, uv, _smooth_texture(), CENTRE_FACE)
    # Expected improvement on the barrier leaves the identity on this problem for 2 of seeds 0-7 (1 and 7), even
    # with 100 evaluations; one reason the constrained form is the default.
    found = tw.optimize_triangle(problem, formulation="barrier", evaluations=40, seed=0)
    assert found.feasible and found.loss <= 0.01
    assert found.params[1] * found.params[2] < 1.0
    assert found.w_R >= 0 and found.w_S >= 0
    # the reported loss is the loss at the reported parameters
    assert problem.evaluate(found.params)[0] == pytest.approx(found.loss, abs=1e-12)


def test_option_validation():
    V, F, uv = grid_mesh()
    with pytest.raises(ValueError, match="epsilon"):
        tw.optimize_triangles(V, F, uv, _stripes(), epsilon=0.0)
    with pytest.raises(ValueError, match="skopt backend"):
        tw.optimize_triangles(V, F, uv, _stripes(), backend="skopt", formulation="constrained")
    with pytest.raises(ValueError, match="faces"):
        tw.optimize_triangles(V, F, uv, _stripes(), faces=[len(F)])
    with pytest.raises(ValueError, match="uv must have shape"):
        tw.optimize_triangles(V, F, uv[:-1], _stripes())


# --- many triangles ------------------------------------------------------------------------------------------


def _small_run(**options):
    V, F, uv = grid_mesh(cells=3)
    texture = _smooth_texture()
    return tw.optimize_triangles(V, F, uv, texture, evaluations=20, **options)


def test_optimize_triangles_rows_follow_faces_and_are_deterministic():
    first = _small_run(faces=[5, 2, 7], workers=1, seed=4, chunk_size=2)
    again = _small_run(faces=[5, 2, 7], workers=1, seed=4, chunk_size=1)
    np.testing.assert_array_equal(first.faces, [5, 2, 7])
    for name in ("params", "loss", "w_R", "w_S", "evaluations"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    assert np.all(first.w_R >= 0) and np.all(first.w_S >= 0)
    assert np.all(first.loss[first.feasible] <= 0.01)
    other_seed = _small_run(faces=[5, 2, 7], workers=1, seed=5)
    assert not np.array_equal(first.params, other_seed.params)


def test_iter_optimize_triangles_yields_progress_then_result():
    V, F, uv = grid_mesh(cells=2)
    stage = tw.iter_optimize_triangles(V, F, uv, _smooth_texture(), evaluations=10, workers=1, chunk_size=3)
    progress = []
    result = run_generator(stage, lambda *step: progress.append(step))
    # the start, the workers' shared state (one step between the view sizes and the one-rings), then each chunk
    # (3, 3 and 2 faces, in the chunks' order)
    assert progress[:2] == [(0, 8), (0, 8)] and progress[-1] == (8, 8) and len(progress) == 5
    assert sorted(b[0] - a[0] for a, b in zip(progress[1:], progress[2:])) == [2, 3, 3]
    assert result.params.shape == (8, 4) and result.evaluations.shape == (8,)
    calls = []
    tw.optimize_triangles(V, F, uv, _smooth_texture(), evaluations=10, workers=1, chunk_size=4,
                          progress=lambda done, total: calls.append((done, total)))
    assert calls == [(0, 8), (0, 8), (4, 8), (8, 8)]


def test_a_run_cut_off_resumes_from_its_checkpoint_to_the_uninterrupted_result(monkeypatch):
    V, F, uv = grid_mesh(cells=3)
    texture = _smooth_texture()
    options = dict(evaluations=10, workers=1, chunk_size=4, seed=2)
    whole = tw.optimize_triangles(V, F, uv, texture, **options)
    monkeypatch.setattr(tw, "CHECKPOINT_SECONDS", 0.0)  # a checkpoint after every chunk
    optimized = []
    original_chunk = tw._optimize_chunk
    monkeypatch.setattr(tw, "_optimize_chunk", lambda state, faces: optimized.append(list(faces)) or
                        original_chunk(state, faces))
    kept = []
    stage = tw.iter_optimize_triangles(V, F, uv, texture, checkpoint=kept.append, **options)
    for done, total in stage:
        if len(kept) == 2:  # cut off after two chunks of the 18 faces (chunks of 4, 4, 4, 4 and 2, in any order)
            stage.close()
            break
    first_two = sorted(sum(optimized, []))
    assert [list(partial.faces) for partial in kept] == [sorted(optimized[0]), first_two]
    optimized.clear()
    progress = []
    resumed = run_generator(tw.iter_optimize_triangles(V, F, uv, texture, known=kept[-1], checkpoint=kept.append,
                                                       **options), lambda *step: progress.append(step))
    assert sorted(sum(optimized, [])) == sorted(set(range(18)) - set(first_two))  # only the faces not done
    assert progress[0] == (len(first_two), 18) and progress[-1] == (18, 18)
    # a checkpoint holds the known faces too; none has every face done
    assert [list(partial.faces) for partial in kept[2:]] == [sorted(first_two + sum(optimized[:k], []))
                                                            for k in range(1, len(optimized))]
    for field in dataclasses.fields(tw.TrianglewiseResult):
        np.testing.assert_array_equal(getattr(resumed, field.name), getattr(whole, field.name))
    everything = run_generator(tw.iter_optimize_triangles(V, F, uv, texture, known=whole, **options))
    assert len(optimized) == 3 and np.array_equal(everything.params, whole.params)  # nothing left to optimize
    with pytest.raises(ValueError, match="known results were made with"):
        run_generator(tw.iter_optimize_triangles(V, F, uv, texture, known=whole, epsilon=0.02, **options))


def test_python_executable_found_when_running_inside_blender(monkeypatch):
    monkeypatch.setattr(sys, "executable", "/opt/blender/blender")
    found = spawn._python_executable()
    assert found is not None and os.path.basename(found).startswith("python") and os.path.isfile(found)


def test_package_parents_cover_the_package_chain():
    parents = spawn._package_parents()
    names = [name for name, _ in parents]
    assert names == ["perceptual_uv"]
    assert pathlib.Path(parents[0][1], "core", "trianglewise.py").is_file()


@pytest.mark.slow
def test_worker_processes_give_identical_results_even_under_a_blender_style_package_name(tmp_path):
    # A child interpreter imports the package as bl_ext.user_default.perceptual_uv (as Blender does, with
    # parents that are not importable from disk) and pretends sys.executable is Blender; the spawned workers
    # must still start, and their results must equal the in-process ones.
    package_dir = pathlib.Path(tw.__file__).resolve().parents[1]
    script = tmp_path / "run.py"
    script.write_text(textwrap.dedent(f"""
        import importlib, importlib.util, sys, types
        import numpy as np
        for name in ("bl_ext", "bl_ext.user_default"):
            module = types.ModuleType(name)
            module.__path__ = []
            sys.modules[name] = module
        spec = importlib.util.spec_from_file_location(
            "bl_ext.user_default.perceptual_uv", {str(package_dir / "__init__.py")!r},
            submodule_search_locations=[{str(package_dir)!r}])
        package = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = package
        spec.loader.exec_module(package)
        tw = importlib.import_module("bl_ext.user_default.perceptual_uv.core.trianglewise")
        sys.path.insert(0, {str(pathlib.Path(__file__).parent)!r})
        from test_trianglewise import grid_mesh, _smooth_texture
        sys.executable = "/opt/blender/blender"
        V, F, uv = grid_mesh(cells=3)
        kwargs = dict(evaluations=15, seed=2, chunk_size=3)
        pooled = tw.optimize_triangles(V, F, uv, _smooth_texture(), workers=2, **kwargs)
        local = tw.optimize_triangles(V, F, uv, _smooth_texture(), workers=1, **kwargs)
        assert np.array_equal(pooled.params, local.params), (pooled.params, local.params)
        assert np.array_equal(pooled.w_S, local.w_S)
        print("OK", len(pooled.faces))
    """))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().endswith("OK 18")


# --- weights handed to the mesh-wise stage ---------------------------------------------------------------------

def _result_with_weights(w_R, w_S, *, epsilon):
    k = len(w_S)
    return tw.TrianglewiseResult(
        faces=np.arange(k), params=np.tile([0.0, tw.LAMBDA_MIN, tw.LAMBDA_MIN, 0.0], (k, 1)), loss=np.zeros(k),
        w_R=np.asarray(w_R, float), w_S=np.asarray(w_S, float), evaluations=np.zeros(k, int),
        feasible=np.ones(k, bool), is_constant=np.zeros(k, bool), epsilon=epsilon, lambda_min=tw.LAMBDA_MIN,
        formulation="constrained", backend="fast")


def test_fit_weights_floor_the_stretch_weight_at_a_tenth_of_w_rs_whatever_the_bound_and_scale_rotation():
    for epsilon in (0.002, 0.02):
        result = _result_with_weights([0.0, 2e-3], [0.0, 1e-3], epsilon=epsilon)
        w_R, w_S = result.fit_weights()
        np.testing.assert_array_equal(w_R, [0.0, 2e-3])  # Eq. 16 as written: Eq. 17's rotation weight, no floor
        np.testing.assert_allclose(w_S, [1e-6, 1e-3 + 1e-6], rtol=1e-12)  # 0.1 * w_rs = 1e-6
        np.testing.assert_array_equal(result.fit_weights(floor=0.0)[1], [0.0, 1e-3])
        np.testing.assert_array_equal(result.fit_weights(rotation_scale=0.0)[0], [0.0, 0.0])
        np.testing.assert_array_equal(result.fit_weights(rotation_scale=0.5)[0], [0.0, 1e-3])
    with pytest.raises(ValueError, match="floor"):
        result.fit_weights(floor=-1.0)
    with pytest.raises(ValueError, match="rotation_scale"):
        result.fit_weights(rotation_scale=-1.0)


def _hand_placed_targets():
    """A 16 x 16 texture, random in columns 0-7 and 0.5 in columns 8-15; four triangles by hand, in texels,
    with their triangle-wise params: texture, uv, params, result."""
    texture = np.full((16, 16), 0.5)
    texture[:, :8] = np.random.default_rng(0).random((16, 8))
    corners = np.array([[(1, 1), (5, 1), (1, 5)],  # 8 texels, textured: floor sqrt(2 / 8) = 0.5
                        [(11, 11), (13, 11), (11, 13)],  # reads columns 10-13 only: flat, left alone
                        [(2, 10), (3, 10), (2, 11)],  # 0.5 texels: floor sqrt(2 / 0.5) = 2, capped at 1
                        [(0.5, 0.5), (8.5, 0.5), (0.5, 8.5)]], float)  # 32 texels: floor 0.25
    params = np.array([[0.3, 0.1, 0.5, 0.2], [0.0, 0.1, 0.1, 0.0], [0.0, 0.1, 0.3, 0.0], [0.1, 0.6, 0.9, 0.4]])
    result = dataclasses.replace(_result_with_weights(np.zeros(4), np.zeros(4), epsilon=0.01), params=params)
    return texture, corners / 16, params, result


def test_fit_targets_raise_the_stretches_of_textured_triangles_to_the_texel_floor():
    texture, uv, params, result = _hand_placed_targets()
    np.testing.assert_allclose(result.fit_targets(uv, texture, min_texels=2.0),
                               [[0.3, 0.5, 0.5, 0.2], [0.0, 0.1, 0.1, 0.0], [0.0, 1.0, 1.0, 0.0],
                                [0.1, 0.6, 0.9, 0.4]], rtol=1e-12)
    np.testing.assert_allclose(result.fit_targets(uv, texture, min_texels=0.5)[0], [0.3, 0.25, 0.5, 0.2])
    np.testing.assert_array_equal(result.fit_targets(uv, texture, min_texels=0.0), params)
    # rows follow result.faces: the same two triangles as faces 2 and 0 of a larger mesh
    subset = dataclasses.replace(result, faces=np.array([2, 0]), params=params[[0, 1]],
                                 unevaluated=result.unevaluated[[2, 0]])
    np.testing.assert_allclose(subset.fit_targets(uv[[1, 1, 0]], texture, min_texels=2.0),
                               [[0.3, 0.5, 0.5, 0.2], [0.0, 0.1, 0.1, 0.0]], rtol=1e-12)
    with pytest.raises(ValueError, match="min_texels"):
        result.fit_targets(uv, texture, min_texels=-1.0)
    with pytest.raises(ValueError, match="uv"):
        subset.fit_targets(uv[:2], texture)


def test_fit_targets_test_texels_a_slice_of_faces_per_step(monkeypatch):
    # The four triangles of the texel-floor test, slices of 3 faces: two slices, (3, 4) then (4, 4), then one step
    # per plane's texel areas, (1, 2) for one plane, and the floored targets of the test above; with a second plane
    # two more texel-test steps count up to 8 and the areas up to 3.
    texture, uv, params, result = _hand_placed_targets()
    monkeypatch.setattr(tex, "TEXTURED_SLICE", 3)
    steps = []
    targets = run_generator(result.iter_fit_targets(uv, texture, min_texels=2.0), lambda *step: steps.append(step))
    assert steps == [(3, 4), (4, 4), (1, 2)]
    np.testing.assert_allclose(targets, [[0.3, 0.5, 0.5, 0.2], [0.0, 0.1, 0.1, 0.0], [0.0, 1.0, 1.0, 0.0],
                                         [0.1, 0.6, 0.9, 0.4]], rtol=1e-12)
    steps = list(result.iter_fit_targets(uv, [texture, texture], min_texels=2.0))
    assert steps == [(3, 8), (4, 8), (7, 8), (8, 8), (1, 3), (2, 3)]
    # Given the texel test's answer, the targets are the same and nothing is tested (the areas' step only).
    textured = tex.textured_triangles(uv[result.faces], texture, per_plane=True)
    steps = []
    given = run_generator(result.iter_fit_targets(uv, texture, min_texels=2.0, textured=textured),
                          lambda *step: steps.append(step))
    assert steps == [(1, 2)]
    np.testing.assert_array_equal(given, targets)
    with pytest.raises(ValueError, match="textured must have shape"):
        result.fit_targets(uv, texture, min_texels=2.0, textured=textured[:, :2])


def test_fit_targets_draw_textured_areas_towards_signal_stretch_geometrically():
    """The triangles of the texel-floor test, no floor. Own areas a = lambda1 lambda2: 0.05, (flat), 0.03, 0.54;
    signal-stretch areas b: 0.04, (flat), 0.01, 0.18. a / b over the textured rows: 1.25, 3, 3, median s = 3,
    so s b = 0.12, 0.03, 0.54: rows 2 and 3 already agree, row 0's area becomes 0.05^(1 - w) 0.12^w, both its
    stretches scaled by (0.12 / 0.05)^(w / 2) = 2.4^(w / 2)."""
    texture, uv, params, result = _hand_placed_targets()
    signal = np.array([[0.0, 0.2, 0.2, 0.0], [0.0, 0.5, 0.5, 0.0], [0.0, 0.1, 0.1, 0.0], [0.0, 0.3, 0.6, 0.7]])

    def targets(weight, signal=signal):
        return result.fit_targets(uv, texture, min_texels=0.0, signal_targets=signal, signal_weight=weight)

    for weight in (0.5, 1.0):
        expected = params.copy()
        expected[0, 1:3] *= 2.4 ** (weight / 2)
        np.testing.assert_allclose(targets(weight), expected, rtol=1e-12)
    np.testing.assert_array_equal(targets(0.0), params)
    np.testing.assert_array_equal(result.fit_targets(uv, texture, min_texels=0.0), params)
    # b = 1 on row 0: a / b = 0.05, 3, 3, s b = 3 on row 0, stretches scaled by sqrt(60): 0.5 sqrt(60) is capped at 1.
    np.testing.assert_allclose(targets(1.0, np.where(np.arange(4)[:, None] == 0, [0.0, 1.0, 1.0, 0.0], signal))[0],
                               [0.3, 0.1 * np.sqrt(60), 1.0, 0.2], rtol=1e-12)
    with pytest.raises(ValueError, match="signal_weight"):
        targets(1.5)
    with pytest.raises(ValueError, match="signal_targets"):
        targets(0.5, signal[:3])
    with pytest.raises(ValueError, match="signal_targets"):
        targets(0.5, np.where(np.arange(4)[:, None] == 2, 0.0, signal))


def test_rotation_targets_that_disagree_bend_a_chart_only_when_weighted():
    """Two triangles of one chart want half their size (lambda = 0.5) and rotations pi/8 apart. Without rotation
    targets a similarity meets both stretch targets exactly: singular values 0.5 and 0.5. With
    Eq. 16's rotation weights no conforming map can turn the two by different angles without shearing them."""
    from perceptual_uv.core.meshwise import solve_meshwise

    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
    result = dataclasses.replace(_result_with_weights([1e-3, 1e-3], [1e-3, 1e-3], epsilon=0.01),
                                 params=np.array([[0.0, 0.5, 0.5, 0.0], [np.pi / 8, 0.5, 0.5, 0.0]]))

    def singular_values(rotation_scale):
        new = solve_meshwise(F, uv, result.params, *result.fit_weights(rotation_scale=rotation_scale)).uv
        edges = lambda t: np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]], axis=-1)  # noqa: E731
        return np.linalg.svd(edges(new) @ np.linalg.inv(edges(uv)), compute_uv=False)

    np.testing.assert_allclose(singular_values(0.0), 0.5, atol=1e-6)
    bent = singular_values(1.0)
    assert np.all(bent[:, 0] / bent[:, 1] > 1.1)


def test_constant_triangles_shrink_to_their_target_only_with_the_floor():
    """A chart whose loss never reacts (Eq. 17 weights 0) keeps its size under Eq. 19 as written; with the
    floor it reaches its smallest-area target, a uniform scale by lambda_min (area ratio lambda_min^2)."""
    from perceptual_uv.core.meshwise import solve_meshwise

    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
    result = _result_with_weights([0.0, 0.0], [0.0, 0.0], epsilon=0.01)

    def area_ratio(w_R, w_S):
        new = solve_meshwise(F, uv, result.params, w_R, w_S).uv
        area = lambda t: 0.5 * np.abs(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])).sum()  # noqa: E731
        return area(new) / area(uv)

    assert area_ratio(result.w_R, result.w_S) == pytest.approx(1.0, abs=1e-9)
    assert area_ratio(*result.fit_weights()) == pytest.approx(tw.LAMBDA_MIN ** 2, rel=0.02)
