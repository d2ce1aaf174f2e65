# SPDX-License-Identifier: GPL-3.0-or-later
"""core.evaluation: dodecahedron cameras, E_iso (Eq. 24), q of Eq. 22 and pixel saving, against hand values."""
import itertools

import numpy as np
import pytest

from perceptual_uv.core.evaluation import (
    GOLDEN_RATIO,
    dodecahedron_cameras,
    dodecahedron_vertices,
    gmsd_by_region,
    perceptual_loss_of_views,
    pixel_saving,
    symmetric_dirichlet,
)

PHI = (1 + 5 ** 0.5) / 2


# --- dodecahedron -----------------------------------------------------------------------------------------

def test_dodecahedron_vertices_are_the_twenty_listed_points():
    P = dodecahedron_vertices()
    expected = set(itertools.product((-1, 1), repeat=3))
    for a, b in itertools.product((-1, 1), repeat=2):
        expected |= {(0, a / PHI, b * PHI), (a / PHI, b * PHI, 0), (a * PHI, 0, b / PHI)}
    assert P.shape == (20, 3)
    assert {tuple(np.round(p, 12)) for p in P} == {tuple(np.round(p, 12)) for p in expected}
    assert GOLDEN_RATIO == pytest.approx(PHI)


def test_dodecahedron_is_regular():
    P = dodecahedron_vertices()
    np.testing.assert_allclose(np.linalg.norm(P, axis=1), np.sqrt(3), rtol=1e-14)
    D = np.linalg.norm(P[:, None] - P[None], axis=2)
    np.fill_diagonal(D, np.inf)
    edge = 2 / PHI
    # Every vertex has exactly 3 neighbours at the edge length and none closer: 30 edges in all.
    np.testing.assert_allclose(D.min(axis=1), edge, rtol=1e-12)
    assert np.all(np.isclose(D, edge, rtol=1e-12).sum(axis=1) == 3)
    assert np.isclose(D, edge, rtol=1e-12).sum() == 2 * 30
    # The next distance on a dodecahedron is the face diagonal phi * edge = 2 (the pentagon's diagonal).
    second = np.sort(D, axis=1)[:, 3]
    np.testing.assert_allclose(second, 2.0, rtol=1e-12)


def test_cameras_frame_the_bounding_sphere():
    rng = np.random.default_rng(0)
    V = rng.normal(size=(200, 3)) * [3.0, 1.0, 0.5] + [10.0, -2.0, 4.0]
    cams = dodecahedron_cameras(V, distance_factor=3.0, margin=1.0)
    centre = 0.5 * (V.min(0) + V.max(0))
    radius = np.linalg.norm(V - centre, axis=1).max()
    np.testing.assert_allclose(cams.look_at, centre)
    assert cams.radius == pytest.approx(radius)
    assert len(cams) == 20
    np.testing.assert_allclose(np.linalg.norm(cams.positions - centre, axis=1), 3.0 * radius, rtol=1e-12)
    # Scaled dodecahedron: nearest neighbours at (2/phi) / sqrt(3) times the distance.
    D = np.linalg.norm(cams.positions[:, None] - cams.positions[None], axis=2)
    np.fill_diagonal(D, np.inf)
    np.testing.assert_allclose(D.min(axis=1), 2 / PHI / np.sqrt(3) * 3.0 * radius, rtol=1e-12)
    # Sphere of radius r seen from 3r: half-angle asin(1/3); with margin 1 the fov is exactly that cone.
    assert cams.fov_degrees == pytest.approx(2 * np.degrees(np.arcsin(1 / 3)))
    assert cams.ortho_scale == pytest.approx(2 * radius)
    assert cams.clip_start < 2 * radius and cams.clip_end > 4 * radius
    # Every vertex projects inside the frustum cone of half-angle fov/2.
    half = np.radians(cams.fov_degrees) / 2
    for eye in cams.positions:
        axis = (centre - eye) / np.linalg.norm(centre - eye)
        to_v = V - eye
        cos = (to_v @ axis) / np.linalg.norm(to_v, axis=1)
        assert np.all(cos >= np.cos(half) - 1e-12)


def test_camera_up_vectors_are_world_up_made_orthogonal():
    V = np.array([[-1.0, -1, -1], [1, 1, 1]])
    cams = dodecahedron_cameras(V)
    forward = cams.look_at - cams.positions
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    np.testing.assert_allclose(np.linalg.norm(cams.up, axis=1), 1.0)
    np.testing.assert_allclose((cams.up * forward).sum(axis=1), 0.0, atol=1e-14)
    # Up lies in the plane of world Z and the view direction, on Z's side.
    np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(forward, cams.up), np.cross(forward, [0, 0, 1.0])
                                         / np.linalg.norm(np.cross(forward, [0, 0, 1.0]), axis=1, keepdims=True)),
                               1.0, rtol=1e-12)
    assert np.all(cams.up[:, 2] > 0)
    # Default distance 2.5 radii gives Blender's ~50 degree lens with a 5 % margin.
    expected = 2 * np.degrees(np.arctan(1.05 * np.tan(np.arcsin(1 / 2.5))))
    assert cams.fov_degrees == pytest.approx(expected)


def test_view_along_world_up_gets_a_fallback_up():
    # World up along a dodecahedron vertex direction: the views from that vertex and its antipode are
    # parallel to it, and take the least aligned world axis instead.
    direction = np.array([0.0, 1 / PHI, PHI]) / np.sqrt(3)
    cams = dodecahedron_cameras(np.array([[-1.0, -1, -1], [1, 1, 1]]), world_up=direction)
    forward = -dodecahedron_vertices() / np.sqrt(3)
    parallel = np.abs(forward @ direction) > 0.9999
    assert parallel.sum() == 2
    np.testing.assert_allclose((cams.up * forward).sum(axis=1), 0.0, atol=1e-14)
    # The world axis least aligned with (0, 1/phi, phi) is X, already orthogonal to it: up = +-X.
    np.testing.assert_allclose(np.abs(cams.up[parallel]), [[1, 0, 0], [1, 0, 0]], atol=1e-14)


def test_camera_validation():
    with pytest.raises(ValueError, match="shape"):
        dodecahedron_cameras(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="zero extent"):
        dodecahedron_cameras(np.ones((4, 3)))
    with pytest.raises(ValueError, match="distance_factor"):
        dodecahedron_cameras(np.eye(3), distance_factor=1.0)


# --- symmetric Dirichlet ------------------------------------------------------------------------------------

def _tilted_square():
    """Two triangles of a 2 x 3 rectangle standing in 3D (rotated), and its unrolled isometric UVs."""
    V2 = np.array([[0, 0], [2, 0], [2, 3], [0, 3]], dtype=float)
    axis_u = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    axis_v = np.array([0.0, 0.0, 1.0])
    V = V2[:, :1] * axis_u + V2[:, 1:] * axis_v + [5.0, 1.0, -2.0]
    F = np.array([[0, 1, 2], [0, 2, 3]])
    return V, F, V2[F].copy()


def test_isometric_uv_gives_the_surface_area():
    V, F, uv = _tilted_square()
    # a_i (2 + 2) / 4 = a_i per triangle: total area 6.
    assert symmetric_dirichlet(V, F, uv, normalize=False) == pytest.approx(6.0, rel=1e-13)
    # Rigid motions and a mirror of the UVs change nothing.
    c, s = np.cos(0.7), np.sin(0.7)
    moved = uv @ np.array([[c, -s], [s, c]]).T + [0.3, -9.0]
    assert symmetric_dirichlet(V, F, moved, normalize=False) == pytest.approx(6.0, rel=1e-13)
    mirrored = uv * [-1.0, 1.0]
    assert symmetric_dirichlet(V, F, mirrored, normalize=False) == pytest.approx(6.0, rel=1e-13)


@pytest.mark.parametrize("s", [0.5, 2.0, 3.7])
def test_uniform_scale_closed_form_and_normalisation(s):
    V, F, uv = _tilted_square()
    # J = s I: (2 s^2 + 2 / s^2) / 4 per unit area.
    expected = (s ** 2 + 1 / s ** 2) / 2 * 6.0
    assert symmetric_dirichlet(V, F, s * uv, normalize=False) == pytest.approx(expected, rel=1e-13)
    energy, details = symmetric_dirichlet(V, F, s * uv, full=True)
    assert energy == pytest.approx(6.0, rel=1e-13)
    assert details["scale"] == pytest.approx(1 / s)
    assert details["area"] == pytest.approx(6.0)


def test_shear_by_hand():
    V, F, uv = _tilted_square()
    k = 0.5
    sheared = uv @ np.array([[1.0, k], [0.0, 1.0]]).T  # (u, v) -> (u + k v, v), area preserved
    # J = [[1, k], [0, 1]]: |J|^2 = 2 + k^2, det 1, |J^-1|^2 = 2 + k^2 -> a (4 + 2 k^2) / 4 = 6 * 1.125.
    assert symmetric_dirichlet(V, F, sheared) == pytest.approx(6.0 * (1 + k * k / 2), rel=1e-13)


def test_anisotropic_stretch_normalised_by_hand():
    V, F, uv = _tilted_square()
    # J = diag(4, 1) has area 4; normalised by 1/2: diag(2, 1/2): (4 + 1/4 + 1/4 + 4) / 4 = 2.125 per area.
    assert symmetric_dirichlet(V, F, uv * [4.0, 1.0]) == pytest.approx(6.0 * 2.125, rel=1e-13)


def test_degenerate_triangles_are_excluded_and_counted():
    V, F, uv = _tilted_square()
    V = np.vstack([V, V[:1]])  # vertex 4 duplicates vertex 0
    F = np.vstack([F, [[0, 4, 1]]])  # zero surface area
    uv = np.concatenate([uv, uv[:1]])
    energy, details = symmetric_dirichlet(V, F, uv, normalize=False, full=True)
    assert energy == pytest.approx(6.0)
    assert details["degenerate_3d"] == 1 and details["per_face"][2] == 0
    collapsed = uv.copy()
    collapsed[1] = [[0, 0], [1, 1], [2, 2]]  # UV area 0 but surface area 3
    energy, details = symmetric_dirichlet(V, F, collapsed, normalize=False, full=True)
    assert energy == pytest.approx(3.0) and details["degenerate_uv"] == 1
    # A sliver: 2 * area / longest^2 = 4e-8 / 8 = 5e-9, below the default 1e-6 ...
    collapsed[1] = [[0, 0], [1, 1 + 2e-8], [2, 2]]
    energy, details = symmetric_dirichlet(V, F, collapsed, normalize=False, full=True)
    assert energy == pytest.approx(3.0) and details["degenerate_uv"] == 1
    # ... and counted when the tolerance is below it, for exact coordinates (float32 could not hold it).
    energy, details = symmetric_dirichlet(V, F, collapsed, normalize=False, full=True, degenerate_tol=1e-9,
                                          uv_rounding=0.0)
    assert energy > 1e6 and details["degenerate_uv"] == 0


def test_a_uv_triangle_flat_but_for_float32_rounding_is_degenerate():
    V, F, uv = _tilted_square()
    V, F = np.vstack([V, V[:1]]), np.vstack([F, [[0, 1, 2]]])  # a third face, surface area 3
    # Its UVs: three points 1e-3 apart on a line at 0.3 rad, near (100, 100), rounded to float32. The rounding
    # (up to 2^-24 * 100 = 6e-6 per coordinate) lifts it to a relative height of about 1e-3, far above
    # 1e-6, but its |det| stays within 4 * 2^-24 * 100 * 2e-3 = 4.8e-8.
    line = 100.0 + np.outer([0.0, 1e-3, 2e-3], [np.cos(0.3), np.sin(0.3)])
    flat = line.astype(np.float32).astype(np.float64)
    det = np.cross(flat[1] - flat[0], flat[2] - flat[0])
    assert abs(det) > 1e-6 * 4e-6 and abs(det) <= 4 * 2.0 ** -24 * 100.01 * 2e-3
    energy, details = symmetric_dirichlet(V, F, np.concatenate([uv, [flat]]), normalize=False, full=True)
    assert details["degenerate_uv"] == 1 and energy == pytest.approx(6.0, rel=1e-12)
    # A real triangle of the same size there (height 1e-3) still counts.
    real = line.copy()
    real[2] = line[0] + [-1e-3 * np.sin(0.3), 1e-3 * np.cos(0.3)]
    _, details = symmetric_dirichlet(V, F, np.concatenate([uv, [real]]), normalize=False, full=True)
    assert details["degenerate_uv"] == 0 and details["per_face"][2] > 0


def test_dirichlet_validation():
    V, F, uv = _tilted_square()
    with pytest.raises(ValueError, match="uv must have shape"):
        symmetric_dirichlet(V, F, uv[:1])
    with pytest.raises(ValueError, match="outside"):
        symmetric_dirichlet(V, F + 10, uv)
    with pytest.raises(ValueError, match="zero area"):
        symmetric_dirichlet(V, F, np.zeros_like(uv))


# --- q and pixel saving ------------------------------------------------------------------------------------

def test_identical_views_have_zero_loss():
    rng = np.random.default_rng(1)
    views = [rng.random((32, 32, 4)) for _ in range(3)]
    assert perceptual_loss_of_views(views, [v.copy() for v in views]) == 0.0


def test_loss_is_the_mean_of_per_view_gmsd():
    from perceptual_uv.core.gmsd import gmsd

    rng = np.random.default_rng(2)
    reference = [rng.random((16, 16)), rng.random((16, 16))]
    blurred = [0.5 * (r + np.roll(r, 1, axis=1)) for r in reference]
    q, per_view = perceptual_loss_of_views(reference, blurred, full=True)
    expected = [gmsd(r, b) for r, b in zip(reference, blurred)]
    np.testing.assert_allclose(per_view, expected)
    assert q == pytest.approx(np.mean(expected)) and q > 0
    # RGBA: alpha is ignored, RGB compared in luma.
    rgba_ref = [np.dstack([r, r, r, np.ones_like(r)]) for r in reference]
    rgba = [np.dstack([b, b, b, np.zeros_like(b)]) for b in blurred]
    assert perceptual_loss_of_views(rgba_ref, rgba) == pytest.approx(q)


def test_views_validation():
    with pytest.raises(ValueError, match="reference views"):
        perceptual_loss_of_views([np.zeros((4, 4))], [])
    with pytest.raises(ValueError, match="shapes differ"):
        perceptual_loss_of_views([np.zeros((4, 4))], [np.zeros((4, 6))])


def test_gmsd_by_region_of_identical_views_is_zero():
    view = np.random.default_rng(0).random((16, 16, 3))
    np.testing.assert_array_equal(gmsd_by_region(view, view, np.zeros((8, 8), int), 2), [0.0, 0.0])


def test_gmsd_by_region_splits_a_mirror_symmetric_pair_in_halves():
    # Prewitt magnitudes and edge replication are mirror symmetric, so the two halves of a pair that is
    # symmetric left-right carry the same share: half of GMSD^2 each.
    rng = np.random.default_rng(1)
    half_reference, half_view = rng.random((16, 8)), rng.random((16, 8))
    reference = np.hstack([half_reference, half_reference[:, ::-1]])
    view = np.hstack([half_view, half_view[:, ::-1]])
    labels = np.repeat([[0] * 4 + [1] * 4], 8, axis=0)
    shares = gmsd_by_region(reference, view, labels, 3, channel_axis=None)
    total = perceptual_loss_of_views([reference], [view]) ** 2
    assert total > 1e-3
    np.testing.assert_allclose(shares, [total / 2, total / 2, 0.0], rtol=1e-12)


def test_gmsd_by_region_validation():
    view = np.zeros((8, 8))
    with pytest.raises(ValueError, match="shape"):
        gmsd_by_region(view, view, np.zeros((8, 8), int), 1, channel_axis=None)
    with pytest.raises(ValueError, match="count"):
        gmsd_by_region(view, view, np.full((4, 4), 2), 2, channel_axis=None)
    with pytest.raises(ValueError, match="even"):
        gmsd_by_region(np.zeros((7, 8)), np.zeros((7, 8)), np.zeros((3, 4), int), 1, channel_axis=None)


def test_pixel_saving_log_linear_by_hand():
    costs = [0.5, 0.1, 0.2, 0.3]
    q = [1e-3, 1e-2, 4e-3, 2e-3]
    # Target 2.8284e-3 = sqrt(4e-3 * 2e-3): halfway in log between c = 0.2 and 0.3 -> 0.25.
    result = pixel_saving(costs, q, np.sqrt(4e-3 * 2e-3))
    assert result.bracketed == "inside"
    assert result.relative_cost == pytest.approx(0.25)
    assert result.pixel_fraction == pytest.approx(0.5)
    # Exactly on a measured point.
    assert pixel_saving(costs, q, 4e-3).relative_cost == pytest.approx(0.2)


def test_pixel_saving_out_of_range_and_non_monotone():
    costs = [0.1, 0.2, 0.3, 0.5]
    q = [1e-3, 4e-3, 2e-3, 1e-3]
    # A dip at 0.1 is contradicted at 0.2: the answer lies between 0.2 and 0.3 (log midpoint 0.25).
    assert pixel_saving(costs, q, np.sqrt(8e-6)).relative_cost == pytest.approx(0.25)
    below = pixel_saving(costs, q, 5e-3)
    assert below.bracketed == "below" and below.relative_cost == 0.1
    above = pixel_saving(costs, q, 1e-4)
    assert above.bracketed == "above" and np.isnan(above.relative_cost)


def test_pixel_saving_validation():
    with pytest.raises(ValueError, match="positive"):
        pixel_saving([0.1, 0.2], [1e-3, 0.0], 1e-3)
    with pytest.raises(ValueError, match="distinct"):
        pixel_saving([0.1, 0.1], [1e-3, 2e-3], 1e-3)
