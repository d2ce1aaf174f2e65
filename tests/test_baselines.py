"""Tests of bridge.baselines on the bundled spot model: every baseline adds a packed UV map with the input cuts
and leaves the input UV map untouched."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from perceptual_uv.bridge import baselines  # noqa: E402
from perceptual_uv.core.chartfit import finish_charts  # noqa: E402
from perceptual_uv.bridge.mesh_io import import_model, read_mesh  # noqa: E402
from perceptual_uv.core.cost import uv_area  # noqa: E402
from perceptual_uv.core.evaluation import symmetric_dirichlet  # noqa: E402


@pytest.fixture(scope="module")
def spot(spot_obj):
    import_model(spot_obj)
    objects = [obj for obj in bpy.context.scene.objects if obj.type == "MESH"]
    uv = objects[0].data.uv_layers.active.name
    return objects, uv


def _check_packed(obj, name, source):
    before = read_mesh(obj, uv_name=source).uv
    uv = read_mesh(obj, uv_name=name).uv
    assert uv.min() >= -1e-6 and uv.max() <= 1 + 1e-6
    # the packed map fills a good part of the unit square and is not degenerate
    assert 0.2 < uv_area(uv) <= 1.0
    return before, uv


def test_repacked_input_is_a_similarity_per_island(spot):
    objects, source = spot
    from perceptual_uv.core.packing import IMAGE_ASPECTS, image_sizes

    original = read_mesh(objects[0], uv_name=source).uv.copy()
    report = baselines.repacked_input(objects, source_uv=source, name="T_Repacked")
    before, uv = _check_packed(objects[0], "T_Repacked", source)
    np.testing.assert_array_equal(before, original)  # input untouched
    V, F = read_mesh(objects[0]).V, read_mesh(objects[0]).F
    # cardinal rotations + translations + one common scale leave the normalised distortion unchanged, measured
    # in pixels of the image the map was packed for (in the unit square of a rectangle it is stretched); measured
    # 234.43 against 234.64: the stored float32 UVs of spot's smallest triangles
    (shape,) = [size for size in image_sizes(1024, IMAGE_ASPECTS) if size[0] / size[1] == report["aspect"]]
    assert symmetric_dirichlet(V, F, uv * shape) == pytest.approx(symmetric_dirichlet(V, F, before), rel=2e-3)


def test_a_baseline_reports_the_image_shape_its_texels_are_square_in(spot):
    # The input's islands moved by translations, quarter turns and one scale: in pixels of the image the packing
    # chose (aspect * h by h), each triangle is a similarity of itself in the input's 1024 px pixels, so its
    # Jacobian's singular values are equal; read in a square they would differ by the aspect.
    from perceptual_uv.core.packing import IMAGE_ASPECTS, image_sizes

    objects, source = spot
    report = baselines.repacked_input(objects, source_uv=source, name="T_Shape")
    shapes = {width / height: (width, height) for width, height in image_sizes(1024, IMAGE_ASPECTS)}
    assert report["aspect"] in shapes
    width, height = shapes[report["aspect"]]
    before = read_mesh(objects[0], uv_name=source).uv * 1024
    after = read_mesh(objects[0], uv_name="T_Shape").uv * (width, height)
    e_before = np.stack([before[:, 1] - before[:, 0], before[:, 2] - before[:, 0]], axis=2)
    e_after = np.stack([after[:, 1] - after[:, 0], after[:, 2] - after[:, 0]], axis=2)
    usable = np.abs(np.linalg.det(e_before)) > 1.0  # a texel or more: float32 UVs leave no doubt
    jacobian = e_after[usable] @ np.linalg.inv(e_before[usable])
    sigma = np.linalg.svd(jacobian, compute_uv=False)
    np.testing.assert_allclose(sigma[:, 0] / sigma[:, 1], 1.0, atol=1e-3)


def test_minimum_stretch_unwrap_lowers_distortion(spot):
    objects, source = spot
    baselines.blender_unwrap(objects, source_uv=source, method="MINIMUM_STRETCH", name="T_SLIM")
    before, uv = _check_packed(objects[0], "T_SLIM", source)
    V, F = read_mesh(objects[0]).V, read_mesh(objects[0]).F
    assert symmetric_dirichlet(V, F, uv) < symmetric_dirichlet(V, F, before)
    assert "T_SLIM" in objects[0].data.uv_layers and len(bpy.data.objects) == len(objects)


@pytest.mark.slow
def test_sspop_is_flip_free_and_packed(spot):
    objects, source = spot
    baselines.sspop_uv(objects, source_uv=source, name="T_SSPOP")
    _, uv = _check_packed(objects[0], "T_SSPOP", source)
    e = uv[:, 1] - uv[:, 0]
    f = uv[:, 2] - uv[:, 0]
    signed = e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]
    before = read_mesh(objects[0], uv_name=source).uv
    e0, f0 = before[:, 1] - before[:, 0], before[:, 2] - before[:, 0]
    signed0 = e0[:, 0] * f0[:, 1] - e0[:, 1] * f0[:, 0]
    keep = np.abs(signed0) > 1e-12
    assert np.all(np.sign(signed[keep]) == np.sign(signed0[keep]))


def test_triangle_targets_are_cached_per_mesh_texture_and_settings(spot, tmp_path, monkeypatch):
    from perceptual_uv.core.trianglewise import TrianglewiseResult

    objects, source = spot
    runs = []

    def fake_stage(V, F, uv, luma, **settings):  # stands in for the minutes of the real stage
        runs.append(settings["seed"])
        k = len(F)
        rng = np.random.default_rng(settings["seed"])
        return TrianglewiseResult(
            faces=np.arange(k), params=rng.random((k, 4)), loss=rng.random(k), w_R=rng.random(k), w_S=rng.random(k),
            evaluations=np.full(k, 7), feasible=np.ones(k, bool), is_constant=np.zeros(k, bool), epsilon=0.01,
            lambda_min=0.1, formulation="constrained", backend="fast")

    monkeypatch.setattr(baselines, "optimize_triangles", fake_stage)
    cache = tmp_path / "spot.npz"
    first, t_first = baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, cache=cache)
    again, t_again = baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, cache=cache)
    assert runs == [0] and t_again == t_first
    np.testing.assert_array_equal(again.params, first.params)
    np.testing.assert_array_equal(again.fit_weights()[1], first.fit_weights()[1])
    assert (again.epsilon, again.formulation, again.feasible.dtype) == (0.01, "constrained", np.bool_)
    # another seed is another result: run again and keep the new one
    baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, seed=3, cache=cache)
    baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, seed=3, cache=cache)
    assert runs == [0, 3]


def test_triangle_targets_cut_off_resume_from_the_faces_done(spot, tmp_path, monkeypatch):
    from perceptual_uv.core.trianglewise import TrianglewiseResult

    objects, source = spot
    calls = []

    def rows(faces):
        k = len(faces)
        return TrianglewiseResult(
            faces=np.asarray(faces), params=np.outer(faces, [1.0, 2.0, 3.0, 4.0]), loss=faces * 1e-3,
            w_R=np.ones(k), w_S=np.ones(k), evaluations=np.full(k, 7), feasible=np.ones(k, bool),
            is_constant=np.zeros(k, bool), epsilon=0.01, lambda_min=0.1, formulation="constrained", backend="fast")

    def stage_cut_off(V, F, uv, luma, *, known, checkpoint, **settings):
        calls.append(known)
        checkpoint(rows(np.arange(10)))
        raise KeyboardInterrupt  # the run is stopped after ten faces

    monkeypatch.setattr(baselines, "optimize_triangles", stage_cut_off)
    cache = tmp_path / "spot_eps0.01_n10.npz"
    with pytest.raises(KeyboardInterrupt):
        baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, cache=cache)
    partial = tmp_path / "spot_eps0.01_n10.partial.npz"
    assert calls == [None] and partial.is_file() and not cache.exists()

    def stage_resumed(V, F, uv, luma, *, known, checkpoint, **settings):
        calls.append(known)
        return rows(np.arange(len(F)))

    monkeypatch.setattr(baselines, "optimize_triangles", stage_resumed)
    # another seed does not take the ten faces
    baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, seed=1,
                               cache=tmp_path / "other.npz")
    assert calls[-1] is None
    result, _ = baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, cache=cache)
    np.testing.assert_array_equal(calls[-1].faces, np.arange(10))
    np.testing.assert_array_equal(calls[-1].params[3], [3.0, 6.0, 9.0, 12.0])
    assert cache.is_file() and not partial.exists()
    np.testing.assert_array_equal(result.params, rows(np.arange(len(result.faces))).params)
    # a file cut off (a full disk) counts as missing: the stage runs again, from nothing
    whole = cache.read_bytes()
    cache.write_bytes(whole[:len(whole) // 2])
    partial.write_bytes(whole[:len(whole) // 3])
    baselines.triangle_targets(objects, source_uv=source, epsilon=0.01, evaluations=10, cache=cache)
    assert calls[-1] is None and len(calls) == 4


# --- the post-processing every method gets (fold restore and chart turn, ``core.chartfit.finish_charts``) ---

def _charts(objects, source):
    from perceptual_uv.bridge.evaluate import mesh_arrays
    from perceptual_uv.core.charts import uv_topology

    _, F, uv = mesh_arrays(objects, source)
    chart = uv_topology(F, uv).face_chart
    return F, uv, chart


def _largest_chart(uv, chart):
    from perceptual_uv.core.charts import signed_uv_areas

    return int(np.argmax(np.bincount(chart, np.abs(signed_uv_areas(uv)))))


def _turned(uv, faces, theta):
    """``uv`` with the charts of ``faces`` turned rigidly by ``theta`` about their mean corner."""
    out = uv.copy()
    centre = uv[faces].reshape(-1, 2).mean(axis=0)
    c, s = np.cos(theta), np.sin(theta)
    out[faces] = (uv[faces] - centre) @ np.array([[c, -s], [s, c]]).T + centre
    return out


def _folded(uv, faces):
    """``uv`` with the chart of ``faces`` folded onto itself along the vertical line through its median u."""
    out = uv.copy()
    middle = np.median(uv[faces][..., 0])
    out[faces, :, 0] = middle - np.abs(uv[faces][..., 0] - middle)
    return out


def _fake_method(monkeypatch, method, transform):
    """Make ``method``'s solver return the input UVs changed by ``transform(uv) -> uv`` (per face corner)."""
    import types

    from perceptual_uv.bridge.mesh_io import read_mesh

    if method == "SSP":
        monkeypatch.setattr(baselines, "solve_ssp", lambda V, F, uv, texture, **kw: types.SimpleNamespace(
            uv=transform(np.asarray(uv))))
    elif method == "SSPOP":
        monkeypatch.setattr(baselines, "solve_meshwise", lambda F, uv, *a, **kw: types.SimpleNamespace(
            uv=transform(np.asarray(uv))))
    else:  # Blender's unwrap: per-loop UVs of each copy
        def on_copies(objects, uv_name, operator):
            out = []
            for obj in objects:
                arrays = read_mesh(obj, uv_name=uv_name)
                values = np.zeros((len(obj.data.loops), 2))
                values[arrays.tri_loops] = transform(arrays.uv)
                out.append(values)
            return out
        monkeypatch.setattr(baselines, "uv_operator_on_copies", on_copies)


def _make(method, objects, source, name):
    if method == "SSP":
        return baselines.ssp_uv(objects, source_uv=source, name=name)
    if method == "SSPOP":
        return baselines.sspop_uv(objects, source_uv=source, name=name)
    return baselines.blender_unwrap(objects, source_uv=source, method=method, name=name)


@pytest.mark.parametrize("method", ["SSP", "SSPOP", "CONFORMAL"])
def test_a_baseline_chart_turned_off_the_grid_is_turned_back(spot, monkeypatch, method):
    from perceptual_uv.bridge.evaluate import mesh_arrays
    from perceptual_uv.core.meshwise_local import _angle_of

    objects, source = spot
    _, uv, chart = _charts(objects, source)
    faces = chart == _largest_chart(uv, chart)
    _fake_method(monkeypatch, method, lambda corners: _turned(corners, faces, np.radians(30.0)))
    name = f"T_turn_{method}"
    report = _make(method, objects, source, name)
    _, _, out = mesh_arrays(objects, name)
    for obj in objects:
        obj.data.uv_layers.remove(obj.data.uv_layers[name])

    def edges(c):
        return np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]], axis=-1)

    # spot's texture is square: UV angles are texel-grid angles; the packer adds quarter turns only
    J = edges(out[faces]) @ np.linalg.inv(edges(uv[faces]))
    residue = np.degrees(np.mod(_angle_of(J) + np.pi / 4, np.pi / 2) - np.pi / 4)
    assert np.median(np.abs(residue)) < 0.5
    assert report["turned_charts"] >= 1 and report["restored_charts"] == 0


@pytest.mark.parametrize("method", ["SSPOP", "SSP"])
def test_a_folded_baseline_chart_gets_its_input_layout(spot, monkeypatch, method):
    from perceptual_uv.bridge.evaluate import mesh_arrays
    from perceptual_uv.core.overlap import shared_area_fractions

    objects, source = spot
    _, uv, chart = _charts(objects, source)
    largest = _largest_chart(uv, chart)
    faces = chart == largest
    n = int(chart.max()) + 1
    _fake_method(monkeypatch, method, lambda corners: _folded(corners, faces))
    assert shared_area_fractions(_folded(uv, faces), chart, n)[largest] > 0.1  # the fake does fold it
    name = f"T_fold_{method}"
    report = _make(method, objects, source, name)
    _, _, out = mesh_arrays(objects, name)
    for obj in objects:
        obj.data.uv_layers.remove(obj.data.uv_layers[name])
    assert shared_area_fractions(out, chart, n)[largest] <= shared_area_fractions(uv, chart, n)[largest] + 1e-6
    assert report["restored_charts"] == 1


def test_finish_charts_is_the_post_processing_of_ours(spot):
    """``fit_charts`` (ours) applies to each of its fits what ``finish_charts`` applies to a baseline."""
    from perceptual_uv.core.chartfit import fit_charts

    objects, source = spot
    F, uv, chart = _charts(objects, source)
    m = len(F)
    rng = np.random.default_rng(1)
    targets = np.column_stack([rng.uniform(-0.6, 0.6, m), np.full(m, 0.8), np.full(m, 1.2), np.zeros(m)])
    w_R, w_S = rng.uniform(0.5, 1.0, m), np.ones(m)
    # equal losses: every chart keeps the fit without rotation terms
    fit = fit_charts(F, uv, targets, w_R, w_S, measure=lambda fits: np.zeros((2, m)), max_iterations=3)
    assert not fit.rotation_fit.any()
    finished, restored, angles = finish_charts(uv, fit.fits[0].uv, chart, alpha=targets[:, 0], w_R=w_R)
    np.testing.assert_allclose(finished, fit.uv, atol=1e-12)
    np.testing.assert_array_equal(restored, fit.restored)
    assert np.count_nonzero(angles) > 0  # the targets do turn charts: the comparison is not vacuous


def test_without_targets_finish_charts_keeps_the_input_grid():
    """A baseline's charts are turned back to the input's texel grid (modulo quarter turns), at any size."""
    square = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], dtype=float)
    uv_in = np.concatenate([square * 0.3, square * 0.2 + 0.5])
    chart = np.array([0, 0, 1, 1])
    uv_new = _turned(_turned(uv_in * 1.7, np.array([True, True, False, False]), 0.4),
                     np.array([False, False, True, True]), np.pi / 2 + 0.2)
    out, restored, angles = finish_charts(uv_in, uv_new, chart)
    assert restored.size == 0
    for faces in (slice(0, 2), slice(2, 4)):
        e_in = uv_in[faces, 1:] - uv_in[faces, :1]
        e_out = out[faces, 1:] - out[faces, :1]
        ratio = (e_out[..., 0] + 1j * e_out[..., 1]) / (e_in[..., 0] + 1j * e_in[..., 1])
        residue = np.mod(np.angle(ratio) + np.pi / 4, np.pi / 2) - np.pi / 4
        np.testing.assert_allclose(residue, 0, atol=1e-6)
        np.testing.assert_allclose(np.abs(ratio), 1.7, rtol=1e-9)  # a turn: no stretch


# --- ours sees every map of the material, as the product's run does (issues 22 and 23) ---

DETAIL_FACES = 0.3  # the detail covers the texture where u < 0.3; the grid's UVs are 0.1 + 0.8 (x, y)


@pytest.fixture(params=["normal", "roughness"])
def detail_grid(request):
    """A 4 x 4 grid (``textured_grid``) whose base colour is flat and whose only detail, where u < 0.3, is in a
    tangent-space normal map (``"normal"``: ``bump_normal_map``) or in the roughness (green) channel of a packed
    occlusion-roughness-metallic image (``"roughness"``). Yields the object, its UV map, the faces whose UVs lie
    on the detail and those whose UVs lie where every map is flat (u >= 0.7); the data blocks it made are removed
    afterwards, so that the module's spot scene stays as it was."""
    from perceptual_uv.bridge.evaluate import mesh_arrays

    from test_bake_maps import add_normal_map, add_orm, new_image
    from test_joint_loss import bump_normal_map
    from test_robustness import textured_grid

    kinds = ("objects", "meshes", "materials", "images", "node_groups")
    before = {kind: set(getattr(bpy.data, kind)) for kind in kinds}
    size = 64
    detail = (np.arange(size) + 0.5) / size < DETAIL_FACES  # texel columns: u
    obj = textured_grid(f"detail_{request.param}", k=4, image=new_image("flat_base", size, np.full(3, 0.6),
                                                                          data=False))
    material = obj.material_slots[0].material
    if request.param == "normal":
        rgb = np.empty((size, size, 3))
        rgb[...] = (0.5, 0.5, 1.0)  # the flat tangent-space normal
        rgb[:, detail] = bump_normal_map(size)[:, detail]
        add_normal_map(material, new_image("detail_normal", size, rgb))
    else:
        y, x = np.mgrid[0:size, 0:size] + 0.5
        rgb = np.full((size, size, 3), 0.5)
        rgb[:, detail, 1] = (0.5 + 0.4 * np.sin(2 * np.pi * x / 8) * np.sin(2 * np.pi * y / 8))[:, detail]
        add_orm(material, new_image("detail_orm", size, rgb))
    _, _, uv = mesh_arrays([obj], "UVMap")
    on_detail = np.flatnonzero(uv[..., 0].max(axis=1) <= DETAIL_FACES + 1e-6)
    flat = np.flatnonzero(uv[..., 0].min(axis=1) >= 0.7 - 1e-6)
    assert len(on_detail) == len(flat) == 8  # a column of 4 quads each
    yield obj, "UVMap", on_detail, flat
    for kind in reversed(kinds):
        collection = getattr(bpy.data, kind)
        for block in set(collection) - before[kind]:
            collection.remove(block)


def test_ours_keeps_the_size_of_triangles_whose_detail_is_only_in_another_map(detail_grid):
    """The triangle-wise stage of the comparison sees the normal or roughness map (as the product's run): the
    triangles over the detail keep more than the smallest area, the flat ones shrink to it. With the base
    colour's luma alone (``ours_luma``, and the comparison before) every triangle shrinks to it."""
    from perceptual_uv.bridge.evaluate import mesh_arrays
    from perceptual_uv.core.loss import triangle_problem
    from perceptual_uv.core.trianglewise import LAMBDA_MIN

    obj, source, on_detail, flat = detail_grid
    faces = np.concatenate([on_detail, flat])
    planes = baselines.loss_planes([obj], source_uv=source)
    assert planes.names[0] == "base_color.luma" and len(planes) > 1  # the flat luma, and the detail's planes
    run = dict(source_uv=source, epsilon=0.01, evaluations=20, faces=faces)
    joint, _ = baselines.triangle_targets([obj], **run)
    area = joint.params[:, 1] * joint.params[:, 2]
    detail_rows, flat_rows = np.arange(len(on_detail)), np.arange(len(on_detail), len(faces))
    # Shrunk to the box's corner (lambda_min, lambda_min), a triangle over the detail has E above epsilon; the
    # result is feasible, so it is not at that corner: its area exceeds lambda_min^2, the least the box allows.
    V, F, uv = mesh_arrays([obj], source)
    for face in on_detail:
        assert triangle_problem(V, F, uv, planes, int(face)).evaluate([0.0, LAMBDA_MIN, LAMBDA_MIN, 0.0])[0] > 0.01
    assert joint.feasible[detail_rows].all() and not joint.is_constant[detail_rows].any()
    assert area[detail_rows].min() > LAMBDA_MIN ** 2
    np.testing.assert_allclose(area[flat_rows], LAMBDA_MIN ** 2, rtol=1e-9)
    assert area[detail_rows].min() > area[flat_rows].max()
    # the base colour's luma alone: constant under every view, every triangle at the smallest area
    luma = baselines.loss_planes([obj], source_uv=source, maps="luma")
    assert luma.names == ("base_color.luma",)
    alone, _ = baselines.triangle_targets([obj], planes=luma, **run)
    assert alone.is_constant.all()
    np.testing.assert_allclose(alone.params[:, 1] * alone.params[:, 2], LAMBDA_MIN ** 2, rtol=1e-9)


def test_the_triangle_cache_key_holds_every_plane_and_its_name(detail_grid, tmp_path, monkeypatch):
    """A triangle-wise result cached for the luma alone is never taken for the joint loss, nor the reverse."""
    from perceptual_uv.bridge.evaluate import mesh_arrays
    from perceptual_uv.core.loss_planes import PlaneStack
    from perceptual_uv.core.trianglewise import TrianglewiseResult

    obj, source, _, _ = detail_grid
    V, F, uv = mesh_arrays([obj], source)
    joint = baselines.loss_planes([obj], source_uv=source)
    luma = baselines.loss_planes([obj], source_uv=source, maps="luma")
    key = baselines._triangle_cache_key
    changed = joint[-1].copy()
    changed[0, 0] += 1e-3  # one texel of the last plane
    keys = {key(V, F, uv, joint, epsilon=0.01), key(V, F, uv, luma, epsilon=0.01),
            key(V, F, uv, PlaneStack(joint, ("renamed",) + joint.names[1:]), epsilon=0.01),
            key(V, F, uv, PlaneStack(joint[:-1] + (changed,), joint.names), epsilon=0.01)}
    assert len(keys) == 4
    assert key(V, F, uv, joint, epsilon=0.01) == key(V, F, uv, PlaneStack(list(joint), joint.names), epsilon=0.01)

    seen = []

    def fake_stage(V, F, uv, planes, **settings):  # stands in for the real stage: records what it saw
        seen.append(planes.names)
        k = len(F)
        return TrianglewiseResult(
            faces=np.arange(k), params=np.tile([0.0, 1.0, 1.0, 0.0], (k, 1)), loss=np.zeros(k), w_R=np.ones(k),
            w_S=np.ones(k), evaluations=np.ones(k, np.int64), feasible=np.ones(k, bool),
            is_constant=np.zeros(k, bool), epsilon=0.01, lambda_min=0.1, formulation="constrained", backend="fast")

    monkeypatch.setattr(baselines, "optimize_triangles", fake_stage)
    cache = tmp_path / "detail.npz"
    run = dict(source_uv=source, epsilon=0.01, evaluations=10, cache=cache)
    baselines.triangle_targets([obj], planes=luma, **run)
    baselines.triangle_targets([obj], **run)  # the default is the material's planes: not the luma's result
    baselines.triangle_targets([obj], **run)
    baselines.triangle_targets([obj], planes=luma, **run)
    assert seen == [luma.names, joint.names, luma.names]


def test_ours_gives_the_triangles_over_the_detail_more_of_the_image(detail_grid):
    """The mesh-wise stage of the comparison's ours takes the same planes (targets, the choice between the fits,
    the bound's fractions): after the fit and the packing every triangle over the detail covers more of the new
    image than any flat one, although all had the same UV area in the input."""
    from perceptual_uv.bridge.evaluate import mesh_arrays
    from perceptual_uv.core.charts import signed_uv_areas

    obj, source, on_detail, flat = detail_grid
    _, _, uv_in = mesh_arrays([obj], source)
    before = np.abs(signed_uv_areas(uv_in))
    np.testing.assert_allclose(before[on_detail], before[flat], rtol=1e-5)
    triangles, _ = baselines.triangle_targets([obj], source_uv=source, epsilon=0.01, evaluations=20)
    report = baselines.perceptual_uv([obj], source_uv=source, triangles=triangles, name="T_ours")
    _, _, uv = mesh_arrays([obj], "T_ours")
    obj.data.uv_layers.remove(obj.data.uv_layers["T_ours"])
    area = np.abs(signed_uv_areas(uv))
    assert area[on_detail].min() > area[flat].max()
    # the flat base colour alone textures nothing: the textured triangles are those the other map shows
    assert 0 < report["above_bound"]["textured_triangles"] < len(uv)
