"""Random small meshes and UV layouts, degenerate ones included, through core validation and both stages.

Every case ends in one of two ways (issue 7, item 3): a ValueError with a message, raised by
:func:`perceptual_uv.core.validate.validate_inputs` before any stage runs, or a finite, flip-free result of the
triangle-wise and mesh-wise stages (every triangle with input UV area keeps its orientation, mirrored ones
included). No other exception, no NaN.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from perceptual_uv.core.charts import signed_uv_areas
from perceptual_uv.core.mesh import MeshArrays
from perceptual_uv.core.meshwise import solve_meshwise
from perceptual_uv.core.trianglewise import optimize_triangles
from perceptual_uv.core.validate import ValidatedInput, check_memory_budget, memory_estimate, validate_inputs

LAYOUTS = ("grid", "mirrored", "scattered", "outside")
COLLAPSED = ("point", "line")


def rarely(draw, one_in):
    """True about once in ``one_in`` draws (hypothesis favours the ends of ranges, so not ``integers == 0``)."""
    return draw(st.sampled_from([False] * (one_in - 1) + [True] + [False] * (one_in - 1)))
STAGES = dict(evaluations=10, screen_pixels=16, workers=1)


def grid_mesh(k):
    """k x k cells, two counter-clockwise triangles each."""
    xs = np.arange(k + 1, dtype=float) / k
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    a = (i * (k + 1) + j).ravel()
    b, c, d = a + k + 1, a + k + 2, a + 1  # (i+1, j), (i+1, j+1), (i, j+1): counter-clockwise
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return V, F


@st.composite
def cases(draw):
    """(V, F, uv, texture) of a small mesh, possibly with degenerate triangles, NaNs or a collapsed UV map."""
    k = draw(st.integers(1, 3))
    V, F = grid_mesh(k)
    m = len(F)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    V[:, 2] = draw(st.sampled_from([0.0, 0.3])) * rng.standard_normal(len(V))
    layout = draw(st.sampled_from(COLLAPSED if rarely(draw, 6) else LAYOUTS))
    uv = V[F][:, :, :2] * 0.8 + 0.1
    if layout == "mirrored":  # the right half reflected onto the left half: shared texels, clockwise triangles
        right = V[F][:, :, 0].mean(axis=1) > 0.5
        uv[right, :, 0] = 1.0 - uv[right, :, 0]
    elif layout == "scattered":  # every triangle its own island, random (possibly overlapping) corners
        uv = rng.random((m, 3, 2))
    elif layout == "outside":
        uv = uv * 3.0 - 1.0  # repeats the texture
    elif layout == "point":
        uv[:] = rng.random(2)
    elif layout == "line":
        uv[..., 1] = 0.5
    # Degenerate triangles: vertices moved onto others in 3D, UV corners made collinear.
    for vertex in draw(st.lists(st.integers(0, len(V) - 1), max_size=2)):
        V[vertex] = V[(vertex + 1) % len(V)]
    for face in draw(st.lists(st.integers(0, m - 1), max_size=2)):
        uv[face, 2] = 0.5 * (uv[face, 0] + uv[face, 1])
    if rarely(draw, 12):
        (V if draw(st.booleans()) else uv).flat[draw(st.integers(0, 5))] = draw(st.sampled_from([np.nan, np.inf]))
    h, w = (1, draw(st.sampled_from([1, 8]))) if rarely(draw, 10) else draw(st.sampled_from([(8, 8), (16, 8), (2, 16)]))
    c = draw(st.sampled_from([1, 3, 4]))
    texture = rng.random((h, w, c)).astype(np.float32) * draw(st.sampled_from([1.0, 2.5]))
    return V, F, uv, texture


def mesh_arrays(V, F, uv):
    m = len(F)
    return MeshArrays(V=V, F=F, uv=uv, tri_loops=np.arange(3 * m, dtype=np.int64).reshape(m, 3),
                      tri_polygons=np.arange(m, dtype=np.int64), material_index=np.zeros(m, np.int64),
                      object_index=np.zeros(m, np.int64), object_names=("random",), uv_name="UVMap")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_refused_with_a_message_or_flip_free(case):
    V, F, uv, texture = case
    try:
        checked = validate_inputs(mesh_arrays(V, F, uv), texture)
    except ValueError as error:
        message = str(error)
        assert len(message) > 20 and "\n" not in message
        event(f"refused: {message.split(':')[0][:60]}")
        return
    event(f"optimized, {int((~checked.optimize).sum())} skipped")
    assert isinstance(checked, ValidatedInput)
    assert np.all(np.isfinite(V)) and np.all(np.isfinite(uv)) and min(texture.shape[:2]) >= 2
    assert 0.0 <= checked.texture.min() and checked.texture.max() <= 1.0
    faces = checked.faces
    triangles = optimize_triangles(V, F, uv, checked.texture, faces=faces, **STAGES)
    assert np.all(np.isfinite(triangles.params)) and np.all(triangles.w_R >= 0) and np.all(triangles.w_S >= 0)
    params, w_R, w_S = checked.targets(triangles.params, triangles.w_R, triangles.w_S)
    result = solve_meshwise(F, uv, params, w_R, w_S, max_iterations=20)
    assert np.all(np.isfinite(result.uv))
    assert result.flipped == 0
    # Flip-free by our own count too: every triangle with UV area keeps the sign of its input area.
    before, after = signed_uv_areas(uv), signed_uv_areas(result.uv)
    proper = ~checked.zero_area_uv
    assert np.all(np.sign(after[proper]) == np.sign(before[proper]))
    np.testing.assert_array_equal(checked.mirrored_uv, (before < 0) & ~checked.zero_area_uv)


def small_mesh():
    V, F = grid_mesh(2)
    return V, F, V[F][:, :, :2] * 0.8 + 0.1


def test_zero_area_triangles_are_kept_but_not_optimized():
    V, F, uv = small_mesh()
    V[4] = V[3]  # the centre vertex onto its neighbour: the triangles between them collapse in 3D
    uv[0, 2] = 0.5 * (uv[0, 0] + uv[0, 1])
    checked = validate_inputs(mesh_arrays(V, F, uv), np.random.default_rng(0).random((8, 8, 3)))
    assert checked.mesh.n_faces == len(F)
    assert checked.zero_area_3d.sum() == 2 and checked.zero_area_uv.tolist() == [True] + [False] * (len(F) - 1)
    assert not checked.optimize[checked.zero_area_3d].any() and not checked.optimize[0]
    assert checked.faces.tolist() == np.flatnonzero(~(checked.zero_area_3d | checked.zero_area_uv)).tolist()
    assert any("zero area in 3D" in note for note in checked.notes)
    params, w_R, w_S = checked.targets(np.full((len(checked.faces), 4), 0.5), np.ones(len(checked.faces)),
                                       np.ones(len(checked.faces)))
    np.testing.assert_array_equal(params[0], [0.0, 1.0, 1.0, 0.0])
    assert w_R[0] == w_S[0] == 0 and np.all(w_R[checked.faces] == 1)


@pytest.mark.parametrize("layout, message", [("point", "collapsed to a point"), ("line", "collapsed to a line")])
def test_collapsed_uv_maps_are_refused(layout, message):
    V, F, uv = small_mesh()
    uv = np.full_like(uv, 0.3) if layout == "point" else np.stack([uv[..., 0], np.full_like(uv[..., 0], 0.3)], -1)
    with pytest.raises(ValueError, match=f"UV map 'UVMap' of 'random' is {message}.*Unwrap"):
        validate_inputs(mesh_arrays(V, F, uv), np.ones((4, 4)))


@pytest.mark.parametrize("shape", [(1, 1, 3), (1, 16), (16, 1, 4)])
def test_one_pixel_wide_textures_are_refused(shape):
    with pytest.raises(ValueError, match="at least 2 x 2 pixels"):
        validate_inputs(mesh_arrays(*small_mesh()), np.ones(shape))


def test_nan_in_arrays_changed_after_construction_is_refused():
    V, F, uv = small_mesh()
    mesh = mesh_arrays(V, F, uv)
    mesh.V[2, 1] = np.nan  # MeshArrays checks at construction; its arrays stay writable
    with pytest.raises(ValueError, match="1 vertices with NaN or infinite coordinates"):
        validate_inputs(mesh, np.ones((4, 4)))
    mesh = mesh_arrays(*small_mesh())
    texture = np.ones((4, 4, 3))
    texture[1, 2, 0] = np.inf
    with pytest.raises(ValueError, match="1 pixels with NaN or infinite values"):
        validate_inputs(mesh, texture)


def test_hdr_texture_is_clipped_and_said_so():
    texture = np.linspace(-0.5, 3.0, 48).reshape(4, 4, 3)
    checked = validate_inputs(mesh_arrays(*small_mesh()), texture, image_name="sky.exr")
    assert checked.texture.min() == 0.0 and checked.texture.max() == 1.0
    assert texture.max() == 3.0  # the input is not changed
    assert any("image 'sky.exr' has values outside [0, 1]" in note for note in checked.notes)


def test_triangles_not_showing_the_texture_are_skipped():
    V, F, uv = small_mesh()
    shows = np.ones(len(F), dtype=bool)
    shows[:3] = False
    checked = validate_inputs(mesh_arrays(V, F, uv), np.ones((4, 4)), shows_texture=shows)
    assert checked.faces.tolist() == list(range(3, len(F)))
    with pytest.raises(ValueError, match="nothing to optimize"):
        validate_inputs(mesh_arrays(V, F, uv), np.ones((4, 4)), shows_texture=np.zeros(len(F), dtype=bool))


def test_memory_budget_message_carries_the_estimate():
    total, parts = memory_estimate(100_000, 200_000, (8192, 8192, 4), workers=2, screen_pixels=64)
    assert total == sum(parts.values())
    assert parts["texture"] == 8192 * 8192 * (16 + 8 + 24) and parts["mesh-wise"] == 200_000 * 9_000
    with pytest.raises(ValueError, match=r"needs about 5\.\d\d GiB \(texture 3\.00 GiB, workers 1\.\d\d GiB.*"
                                         r"more than the memory budget of 4\.00 GiB"):
        check_memory_budget(100_000, 200_000, (8192, 8192, 4), workers=2, memory_budget=4 * 2**30)
