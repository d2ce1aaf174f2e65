"""The loss passes: E of given deformations and new UV maps, each face's views prepared once for all rows."""
import numpy as np
import pytest

from perceptual_uv.core import loss_passes as lp
from perceptual_uv.core.deformation import jacobian
from perceptual_uv.core.loss import triangle_problem
from perceptual_uv.core.progress import run_generator

from meshes import grid_mesh  # tests/ is on sys.path under pytest
from test_trianglewise import SIZE, _smooth_texture, _stripes  # noqa: E402


def _count_preparations(monkeypatch):
    """A list that grows by the faces of each call of :func:`.loss.prepare_triangles` by the loss passes."""
    prepared = []
    prepare = lp.prepare_triangles

    def count(V, F, uv, luma, faces, **options):
        prepared.extend(faces)
        return prepare(V, F, uv, luma, faces, **options)

    monkeypatch.setattr(lp, "prepare_triangles", count)
    return prepared


def test_params_from_jacobians_round_trip():
    params = np.array([[0.3, 0.9, 0.2, 1.1], [1.2, 0.5, 0.5, 0.0], [-0.4, 1.5, 0.7, 0.3]])
    R, S = jacobian(params)
    recovered = lp._params_from_jacobians(R @ S)
    R2, S2 = jacobian(recovered)
    np.testing.assert_allclose(R2 @ S2, R @ S, atol=1e-12)
    np.testing.assert_allclose(np.sort(recovered[:, 1:3], axis=1), np.sort(params[:, 1:3], axis=1), atol=1e-12)


def test_losses_at_identity_is_zero_and_flips_are_infinite():
    V, F, uv = grid_mesh(cells=3)
    texture = _smooth_texture()
    np.testing.assert_allclose(lp.losses_at(V, F, uv, texture, uv), 0.0, atol=1e-9)
    flipped = uv.copy()
    flipped[4] = flipped[4][[0, 2, 1]]
    losses = lp.losses_at(V, F, uv, texture, flipped)
    assert np.isinf(losses[4]) and np.isfinite(np.delete(losses, 4)).all()


def test_losses_at_equals_problem_loss_of_the_jacobian():
    # New UVs = one triangle deformed by A about its barycentre: losses_at must evaluate E(A) for it.
    V, F, uv = grid_mesh(cells=3)
    texture = _smooth_texture()
    params = np.array([0.3, 0.8, 0.5, 0.7])
    R, S = jacobian(params)
    face = 7
    new_uv = uv.copy()
    centre = uv[face].mean(axis=0)
    new_uv[face] = (uv[face] - centre) @ (R @ S).T + centre  # square texture: texel and UV Jacobians agree
    got = lp.losses_at(V, F, uv, texture, new_uv, faces=[face])[0]
    expected = triangle_problem(V, F, uv, texture, face).evaluate(params)[0]
    assert got == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_several_maps_are_measured_in_one_pass_each_as_if_alone(monkeypatch):
    # The pipeline measures the fit's targets and both fits at once: every triangle is prepared once for all of
    # them, and each row is what its own pass gives, bit for bit (a flipped triangle in one map only: inf there).
    V, F, uv = grid_mesh(cells=3)
    planes = [_smooth_texture(), _stripes(4)]
    centre = uv.mean(axis=1, keepdims=True)
    maps = np.stack([centre + 0.6 * (uv - centre), centre + 0.9 * (uv - centre)[..., ::-1] * [1, -1]])
    maps[1, 4] = maps[1, 4][[0, 2, 1]]
    faces = [2, 4, 7]
    alone = np.stack([lp.losses_at(V, F, uv, planes, one, faces=faces) for one in maps])
    prepared = _count_preparations(monkeypatch)
    together = lp.losses_at(V, F, uv, planes, maps, faces=faces)
    assert sorted(prepared) == faces
    np.testing.assert_array_equal(together, alone)
    assert np.isinf(together[1, 1]) and np.isfinite(together[0]).all() and (together[0] > 0).all()
    params = np.stack([lp.deformation_params(uv, one, (SIZE, SIZE))[faces] for one in maps])
    np.testing.assert_array_equal(lp.losses_of(V, F, uv, planes, params, faces=faces), alone)
    np.testing.assert_array_equal(lp.losses_of(V, F, uv, planes, params[0], faces=faces), alone[0])


def test_triangles_spanning_many_texels_are_seen_at_one_pixel_per_texel():
    # Two triangles of the unit square over a whole 256 x 256 texture: sqrt(2) * 256 = 362 texels across App.
    # A's window, so the view grows to the 256 px maximum; losses_at must measure E on that view.
    V, F, uv = grid_mesh(cells=1, uv_low=0.0, uv_high=1.0)
    y, x = np.mgrid[0:256, 0:256] + 0.5
    texture = 0.5 + 0.25 * np.sin(2 * np.pi * x / 3.0) * np.cos(2 * np.pi * y / 5.0)
    params = np.array([0.0, 0.5, 0.5, 0.0])
    R, S = jacobian(params)
    new_uv = uv.copy()
    centre = uv[0].mean(axis=0)
    new_uv[0] = (uv[0] - centre) @ (R @ S).T + centre
    grown = lp.losses_at(V, F, uv, texture, new_uv, faces=[0])[0]
    fixed = lp.losses_at(V, F, uv, texture, new_uv, faces=[0], max_screen_pixels=64)[0]
    assert grown == pytest.approx(triangle_problem(V, F, uv, texture, 0, screen_pixels=256).evaluate(params)[0],
                                  rel=1e-9)
    assert fixed == pytest.approx(triangle_problem(V, F, uv, texture, 0).evaluate(params)[0], rel=1e-9)
    # Halving the texels of a 3-texel pattern blurs it: 1.1e-2 at 256 px. At 64 px the lookups skip most texels
    # and the re-bake reproduces that screen exactly (8e-17): the loss cannot see the detail go.
    assert fixed < 1e-9 and grown > 5e-3


def test_fit_losses_measure_targets_and_fits_in_one_pass_each_as_if_alone(monkeypatch):
    # The mesh-wise stage's measurement: the targets' E and each fit's E per face of the mesh, every face
    # prepared once for all of them; faces left out read 0 in the fits' rows.
    V, F, uv = grid_mesh(cells=3)
    planes = [_smooth_texture(), _stripes(4)]
    centre = uv.mean(axis=1, keepdims=True)
    fits = [centre + 0.6 * (uv - centre), centre + 0.8 * (uv - centre)]
    faces = [1, 5, 6]
    targets = np.array([[0.2, 0.7, 0.5, 0.3], [0.0, 1.0, 1.0, 0.0], [1.1, 0.4, 0.9, 0.6]])
    prepared = _count_preparations(monkeypatch)
    target_losses, fit_losses = run_generator(lp.iter_fit_losses(V, F, uv, planes, targets, fits, faces=faces))
    assert sorted(prepared) == faces
    monkeypatch.undo()
    np.testing.assert_array_equal(target_losses, lp.losses_of(V, F, uv, planes, targets, faces=faces))
    assert fit_losses.shape == (2, len(F))
    for fit, row in zip(fits, fit_losses):
        np.testing.assert_array_equal(row[faces], lp.losses_at(V, F, uv, planes, fit, faces=faces))
        assert not np.delete(row, faces).any()
    assert target_losses[1] == pytest.approx(0.0, abs=1e-9) and (np.delete(target_losses, 1) > 0).all()
