"""The joint loss over a stack of maps (core.loss_planes, core.loss_stack): E is the largest plane's GMSD."""
import math

import numpy as np
import pytest

from perceptual_uv.core import loss, loss_stack
from perceptual_uv.core import textured as tex
from perceptual_uv.core import loss_passes as lp
from perceptual_uv.core import trianglewise as tw
from perceptual_uv.core.deformation import jacobian
from perceptual_uv.core.loss_planes import (NORMAL_LIGHTS, PlaneStack, StackProblem, conjugate_params, loss_planes,
                                            normal_shading, texture_planes)
from perceptual_uv.core.progress import run_generator

from meshes import grid_mesh  # tests/ is on sys.path under pytest

CENTRE_FACE = 36  # inside the 6 x 6 grid: its one-ring is complete


def random_params(rng, k):
    lo = np.array([0.0, 0.1, 0.1, 0.0])
    hi = np.array([np.pi / 2, 1.0, 1.0, np.pi / 2])
    return lo + (hi - lo) * rng.random((k, 4))


def bump_normal_map(size=64, period=8.0, strength=0.6):
    """Tangent-space normal map (RGB in [0, 1]) of the height field ``sin(2 pi x / P) sin(2 pi y / P)``."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    k = 2 * np.pi / period
    dx = strength * np.cos(k * x) * np.sin(k * y)
    dy = strength * np.sin(k * x) * np.cos(k * y)
    n = np.stack([-dx, -dy, np.ones_like(dx)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return 0.5 * (n + 1.0)


@pytest.fixture(scope="module")
def scene():
    V, F, uv = grid_mesh()
    rng = np.random.default_rng(0)
    detail = rng.random((64, 64))
    other = rng.random((64, 64))
    params = random_params(rng, 12)
    return V, F, uv, detail, other, params


def alone(V, F, uv, plane, params):
    return loss.triangle_problem(V, F, uv, plane, CENTRE_FACE).evaluate(params)


# --- one plane: the single-map path, unchanged ---------------------------------------------------------------


def test_one_plane_in_a_list_is_the_single_map_path_bit_for_bit(scene):
    V, F, uv, detail, _, params = scene
    single = loss.prepare_triangles(V, F, uv, detail, [CENTRE_FACE, 3])
    listed = loss.prepare_triangles(V, F, uv, [detail], [CENTRE_FACE, 3])
    assert type(single) is type(listed) is loss.TriangleBatch
    for i in range(2):
        np.testing.assert_array_equal(single[i].evaluate(params), listed[i].evaluate(params))
    colour = np.dstack([detail] * 3)  # grey RGB: luma equals the plane up to rounding of the weights
    assert texture_planes(colour)[0].shape == (64, 64) and len(texture_planes(colour)) == 1
    # A stack of that one plane (as a caller may build it) is that plane too, one column.
    stacked = StackProblem((single[0],))
    np.testing.assert_array_equal(stacked.evaluate_planes(params), single[0].evaluate(params)[:, None])


# --- (1) a flat plane adds nothing, in either order ---------------------------------------------------------


def test_flat_plane_beside_a_detailed_one_leaves_e_unchanged_in_either_order(scene):
    V, F, uv, detail, _, params = scene
    flat = np.full((64, 64), 0.4)
    expected = alone(V, F, uv, detail, params)
    assert expected.max() > 0.05
    for planes, active in (([flat, detail], (1,)), ([detail, flat], (0,))):
        problem = loss.triangle_problem(V, F, uv, planes, CENTRE_FACE)
        assert isinstance(problem, StackProblem)
        assert problem.active_planes == active
        np.testing.assert_array_equal(problem.evaluate(params), expected)


# --- (2) E of a stack is the largest plane's E alone --------------------------------------------------------


def test_stack_e_is_the_max_of_each_planes_e_alone(scene):
    V, F, uv, detail, other, params = scene
    smooth = 0.5 + 0.3 * np.sin(np.arange(64) * 2 * np.pi / 9.0)[None, :] * np.ones((64, 1))
    planes = [detail, smooth, other]
    problem = loss.triangle_problem(V, F, uv, planes, CENTRE_FACE)
    each = np.column_stack([alone(V, F, uv, p, params) for p in planes])
    # The three planes share one operator assembly and factorization (core.loss_stack): same E as alone.
    np.testing.assert_allclose(problem.evaluate_planes(params), each, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(problem.evaluate(params), each.max(axis=1), rtol=1e-12, atol=1e-15)
    # Each plane binds somewhere: the smooth one is the smallest, the random ones trade places.
    assert np.all(each[:, 1] <= each.max(axis=1))


def test_stack_batch_matches_its_problems_and_pickles(scene):
    import pickle

    V, F, uv, detail, other, params = scene
    batch = loss.prepare_triangles(V, F, uv, [detail, other], [CENTRE_FACE, 5, 20])
    assert isinstance(batch, loss.StackBatch) and len(batch) == 3
    np.testing.assert_array_equal(batch.faces, [CENTRE_FACE, 5, 20])
    copy = pickle.loads(pickle.dumps(batch))
    for i in range(3):
        np.testing.assert_array_equal(batch.evaluate(i, params[:3]), copy[i].evaluate(params[:3]))


# --- (3) tangent-space normal maps through their shading ----------------------------------------------------


def test_flat_normal_map_shades_constant_and_gives_zero_loss(scene):
    V, F, uv, _, _, params = scene
    flat = np.zeros((32, 32, 3))
    flat[..., :2] = 0.5
    flat[..., 2] = 1.0
    shading = normal_shading(flat)
    assert shading.shape == (3, 32, 32)
    np.testing.assert_allclose(shading, math.sin(math.radians(30)), rtol=1e-15)
    problem = loss.triangle_problem(V, F, uv, list(shading), CENTRE_FACE)
    assert problem.is_constant and problem.active_planes == ()
    np.testing.assert_array_equal(problem.evaluate(params), 0.0)
    # loss_planes keeps one plane of an all-constant material, so the stack is never empty
    assert len(loss_planes([("normal", flat)])) == 1


def test_normal_map_lights_span_the_normal_and_ignore_the_green_convention():
    assert NORMAL_LIGHTS.shape == (3, 3)
    np.testing.assert_allclose(np.linalg.norm(NORMAL_LIGHTS, axis=1), 1.0)
    assert abs(np.linalg.det(NORMAL_LIGHTS)) > 0.1  # n . l determines n when unclamped
    bump = bump_normal_map(16)
    flipped = bump.copy()
    flipped[..., 1] = 1.0 - flipped[..., 1]  # DirectX convention: green points down
    # Mirroring y maps the light at 120 degrees onto the one at 240: the same planes, two swapped.
    np.testing.assert_allclose(normal_shading(flipped), normal_shading(bump)[[0, 2, 1]], atol=1e-12)


def test_bumpy_normal_map_keeps_area_where_a_flat_one_shrinks():
    V, F, uv = grid_mesh()
    flat_colour = np.full((64, 64, 3), 0.6)
    flat_normal = np.zeros((64, 64, 3))
    flat_normal[..., :2] = 0.5
    flat_normal[..., 2] = 1.0
    bumpy = loss_planes([("color", flat_colour), ("normal", bump_normal_map())])
    plain = loss_planes([("color", flat_colour), ("normal", flat_normal)])
    assert bumpy.names == ("color0.luma", "normal1.light0", "normal1.light1", "normal1.light2")[1:]
    assert len(plain) == 1  # every plane constant: the first is kept
    problem = loss.triangle_problem(V, F, uv, bumpy, CENTRE_FACE)
    assert problem.evaluate([0.0, 0.3, 0.3, 0.0])[0] > 0.01
    options = dict(faces=[CENTRE_FACE], evaluations=40, workers=1, seed=0)
    with_bumps = tw.optimize_triangles(V, F, uv, bumpy, **options)
    without = tw.optimize_triangles(V, F, uv, plain, **options)
    assert without.is_constant[0] and without.params[0, 1] * without.params[0, 2] == pytest.approx(0.01)
    assert not with_bumps.is_constant[0] and with_bumps.feasible[0]
    assert with_bumps.params[0, 1] * with_bumps.params[0, 2] > 0.1


# --- (4) planes at their own resolution -----------------------------------------------------------------------


def test_half_resolution_plane_in_a_stack_equals_that_plane_alone_at_its_own_size(scene):
    V, F, uv, detail, other, params = scene
    half = np.ascontiguousarray(other[::2, ::2])  # a 2x smaller data map: (32, 32)
    problem = loss.triangle_problem(V, F, uv, [detail, half], CENTRE_FACE)
    assert problem.planes[1].texture_shape == (32, 32)
    np.testing.assert_array_equal(problem.evaluate_planes(params)[:, 1], alone(V, F, uv, half, params))
    np.testing.assert_array_equal(problem.evaluate(params),
                                  np.maximum(alone(V, F, uv, detail, params), alone(V, F, uv, half, params)))


def test_plane_of_another_aspect_sees_the_same_uv_map(scene):
    V, F, uv, detail, other, params = scene
    wide = np.ascontiguousarray(np.hstack([other, other[:, ::-1]]))  # (64, 128): twice as wide in texels
    problem = loss.triangle_problem(V, F, uv, [detail, wide], CENTRE_FACE)
    # A = R S in the first plane's texels is D A D^-1, D = diag(2, 1), in the wide plane's.
    np.testing.assert_allclose(problem.evaluate_planes(params)[:, 1],
                               alone(V, F, uv, wide, conjugate_params(params, 2.0)), rtol=1e-9, atol=1e-12)
    converted = conjugate_params(params, 2.0)
    for row, new in zip(params, converted):
        R, S = jacobian(row)
        R2, S2 = jacobian(new)
        np.testing.assert_allclose(R2 @ S2, np.diag([2.0, 1.0]) @ R @ S @ np.diag([0.5, 1.0]), atol=1e-12)


# --- (5) a constant plane is not rendered ---------------------------------------------------------------------


def test_planes_rendered_are_exactly_the_active_ones(scene, monkeypatch):
    V, F, uv, detail, other, params = scene
    flat = np.full((64, 64), 0.25)
    calls = {"single": 0, "stacked": []}
    single, stacked = loss.TriangleProblem.evaluate, loss_stack._evaluate_planes_kernel

    def count_single(self, p):
        calls["single"] += 1
        return single(self, p)

    def count_stacked(*args):
        calls["stacked"].append(args[4].shape[0])  # the references: one row per plane rendered
        return stacked(*args)

    monkeypatch.setattr(loss.TriangleProblem, "evaluate", count_single)
    monkeypatch.setattr(loss_stack, "_evaluate_planes_kernel", count_stacked)
    problem = loss.triangle_problem(V, F, uv, [flat, detail, flat, other, flat], CENTRE_FACE)
    assert problem.active_planes == (1, 3)
    values = problem.evaluate_planes(params)
    assert calls == {"single": 0, "stacked": [2]}  # one shared render of the two detailed planes
    np.testing.assert_array_equal(values[:, [0, 2, 4]], 0.0)
    calls["stacked"].clear()
    problem = loss.triangle_problem(V, F, uv, [flat, detail], CENTRE_FACE)
    problem.evaluate(params)
    assert calls == {"single": 1, "stacked": []}
    # outside the box (lambda > 1) a constant plane is rendered, as the single-map path does: both planes share
    # one operator
    calls["single"] = 0
    problem.evaluate([0.0, 1.5, 1.0, 0.0])
    assert calls == {"single": 0, "stacked": [2]}


# --- the stack through the triangle-wise stage -----------------------------------------------------------------


def test_textured_triangles_and_above_bound_take_any_plane():
    V, F, uv = grid_mesh()
    left = np.zeros((64, 64))
    left[:, 16:26] = np.arange(10) % 2  # detail under the left part of the UV square (texels 16-47) only
    right = np.zeros((64, 64))
    right[:, 38:48] = np.arange(10) % 2
    either = tex.textured_triangles(uv, [left, right])
    np.testing.assert_array_equal(either, tex.textured_triangles(uv, left) | tex.textured_triangles(uv, right))
    assert tex.textured_triangles(uv, left).any() and tex.textured_triangles(uv, right).any()
    assert not either.all()
    assert not tex.textured_triangles(uv, [np.zeros((8, 8)), np.ones((4, 4))]).any()
    losses = np.where(either, 0.02, 0.0)
    assert tex.above_bound(uv, [left, right], 0.01, fit=losses) == {"textured_triangles": int(either.sum()),
                                                                     "fit": 1.0}
    per_plane = tex.textured_triangles(uv, [left, right], per_plane=True)
    np.testing.assert_array_equal(per_plane, [tex.textured_triangles(uv, left), tex.textured_triangles(uv, right)])
    # A mask given by the caller is taken as it is: the planes are not read.
    assert tex.above_bound(uv, None, 0.01, textured=~either, fit=losses) == {
        "textured_triangles": int((~either).sum()), "fit": 0.0}


def test_the_texel_test_hands_control_back_after_each_slice_of_faces_of_each_plane(monkeypatch):
    V, F, uv = grid_mesh()
    planes = [np.arange(64.0).reshape(8, 8), np.zeros((4, 4))]
    monkeypatch.setattr(tex, "TEXTURED_SLICE", len(uv) // 2 + 1)
    steps = []
    textured = run_generator(tex.iter_textured_triangles(uv, planes), lambda *step: steps.append(step))
    m = len(uv)
    assert steps == [(m // 2 + 1, 2 * m), (m, 2 * m), (m + m // 2 + 1, 2 * m), (2 * m, 2 * m)]
    np.testing.assert_array_equal(textured, tex.textured_triangles(uv, planes[0]))


def test_losses_of_a_stack_are_the_max_of_each_planes(scene):
    V, F, uv, detail, other, params = scene
    faces = np.array([CENTRE_FACE, 7, 50])
    rows = params[:3]
    options = dict(faces=faces, max_screen_pixels=64)
    each = [lp.losses_of(V, F, uv, p, rows, **options) for p in (detail, other[::2, ::2])]
    stacked = lp.losses_of(V, F, uv, [detail, np.ascontiguousarray(other[::2, ::2])], rows, **options)
    np.testing.assert_allclose(stacked, np.maximum(*each), rtol=1e-12)
    new_uv = uv.copy()
    new_uv[:, :, 0] = 0.5 + 0.5 * (uv[:, :, 0] - 0.5)  # a shrink along u
    at = lp.losses_at(V, F, uv, [detail, other], new_uv, **options)
    np.testing.assert_allclose(at, np.maximum(lp.losses_at(V, F, uv, detail, new_uv, **options),
                                              lp.losses_at(V, F, uv, other, new_uv, **options)), rtol=1e-12)


def test_fit_targets_floor_counts_texels_of_the_densest_textured_plane():
    V, F, uv = grid_mesh()
    faces = np.array([CENTRE_FACE])
    flat, coarse, fine = np.zeros((64, 64)), np.random.default_rng(1).random((32, 32)), np.zeros((128, 128))
    result = tw.TrianglewiseResult(faces, np.array([[0.0, 0.1, 0.1, 0.0]]), np.zeros(1), np.zeros(1), np.zeros(1),
                                   np.zeros(1, np.int64), np.ones(1, bool), np.zeros(1, bool), 0.01, 0.1,
                                   "constrained", "fast")
    area_64 = 0.5 * (0.5 / 6) ** 2 * 64 * 64  # the triangle's area in texels of a 64 x 64 map
    # only the 32 x 32 plane is textured: the floor counts its texels (a quarter of the 64 x 64 count)
    target = result.fit_targets(uv, [flat, coarse, fine], min_texels=2.0)
    assert target[0, 1] == pytest.approx(math.sqrt(2.0 / (area_64 / 4)))
    assert np.array_equal(result.fit_targets(uv, [flat, fine], min_texels=2.0), result.params)  # nothing textured


def test_optimize_triangles_on_a_stack_in_workers_matches_one_process(scene):
    V, F, uv, detail, other, _ = scene
    planes = [detail, np.ascontiguousarray(other[::2, ::2])]
    options = dict(faces=[CENTRE_FACE, 8], evaluations=10, seed=3, chunk_size=1)
    here = tw.optimize_triangles(V, F, uv, planes, workers=1, **options)
    there = tw.optimize_triangles(V, F, uv, planes, workers=2, **options)
    np.testing.assert_array_equal(here.params, there.params)
    np.testing.assert_array_equal(here.loss, there.loss)


# --- building planes from maps ---------------------------------------------------------------------------------


def test_loss_planes_roles_channels_and_names():
    rng = np.random.default_rng(2)
    colour = rng.random((8, 8, 4))
    orm = np.dstack([np.ones((4, 4)), rng.random((4, 4)), rng.random((4, 4))])  # occlusion unused (all 1)
    stack = loss_planes([("color", colour), {"role": "data", "pixels": orm, "name": "orm"},
                         ("data", orm, (2,)), ("normal", bump_normal_map(16))])
    assert isinstance(stack, PlaneStack)
    assert stack.names == ("color0.luma", "color0.alpha", "orm.1", "orm.2", "data2.2", "normal3.light0",
                           "normal3.light1", "normal3.light2")
    np.testing.assert_array_equal(stack[0], loss.texture_luma(colour))
    np.testing.assert_array_equal(stack[1], colour[..., 3])
    np.testing.assert_array_equal(stack[3], orm[..., 2])
    assert [p.shape for p in stack] == [(8, 8)] * 2 + [(4, 4)] * 3 + [(16, 16)] * 3
    assert texture_planes(stack) is stack
    assert len(loss_planes([("data", orm)], drop_constant=False)) == 3
    with pytest.raises(ValueError, match="role"):
        loss_planes([("albedo", colour)])
    with pytest.raises(ValueError, match="channel"):
        loss_planes([("data", orm, (3,))])
    with pytest.raises(ValueError, match="normal map"):
        normal_shading(np.zeros((4, 4)))


# --- the kernel's call ---------------------------------------------------------------------------------------


def test_each_evaluation_enters_the_compiled_kernel_without_numba_matching_types_in_python(scene, monkeypatch):
    # numba's dispatcher matches a call that leaves out an argument with a default in Python
    # (Dispatcher._compile_for_args), about 0.1 ms a call, a third of an evaluation of a 64 px view
    V, F, uv, detail, other, params = scene
    single = loss.triangle_problem(V, F, uv, detail, CENTRE_FACE)
    stacked = loss.triangle_problem(V, F, uv, [detail, other], CENTRE_FACE)
    expected = single.evaluate(params[:1]), stacked.evaluate(params[:1])  # compiled or loaded from the cache
    kernel = loss_stack._evaluate_planes_kernel
    matched_in_python = []

    def record(*args, **kwargs):
        matched_in_python.append(len(args))
        return type(kernel)._compile_for_args(kernel, *args, **kwargs)

    monkeypatch.setattr(kernel, "_compile_for_args", record)
    again = single.evaluate(params[:1]), stacked.evaluate(params[:1])
    assert matched_in_python == []
    np.testing.assert_array_equal(again[0], expected[0])
    np.testing.assert_array_equal(again[1], expected[1])


def test_a_stack_rasters_each_view_once_for_all_its_planes(scene, monkeypatch):
    V, F, uv, detail, other, _ = scene
    half = detail[::2, ::2].copy()
    faces = [CENTRE_FACE, 3]
    alone = [loss.prepare_triangles(V, F, uv, plane, faces) for plane in (detail, other, half)]
    rastered = []
    raster = loss._rasterize_kernel

    def count(*args):
        rastered.append(args[2].shape[0])
        return raster(*args)

    monkeypatch.setattr(loss, "_rasterize_kernel", count)
    stack = loss.prepare_triangles(V, F, uv, [detail, other, half], faces)
    assert len(rastered) == len(faces)
    for batch, single in zip(stack.planes, alone):  # each plane as if prepared on its own
        for field in ("pixel", "points", "reference", "reference_gradient", "centre", "is_constant", "box"):
            np.testing.assert_array_equal(getattr(batch, field), getattr(single, field))
