"""The render H (Eq. 8-9): ray cast, barycentrics, texel coordinates and bilinear weights."""
import numpy as np
import pytest

from perceptual_uv.core.camera import triangle_cameras
from perceptual_uv.core.raster import (_rasterize_reference, bilinear_weights, deform_points, rasterize,
                                       sample_bilinear, screen_operator, texel_coordinates)

V_FLAT = np.array([[2.0, 0, 0], [-1, 1, 0], [-1, -1, 0]])
F_FLAT = np.array([[0, 1, 2]])
UV_FLAT = np.array([[[0.1, 0.2], [0.8, 0.3], [0.3, 0.9]]])


def _bilinear_by_hand(texture, u, v):
    """Eq. 9 written out: texel centres at integers of (u w - 0.5, v h - 0.5), REPEAT wrap."""
    h, w = texture.shape
    x, y = u * w - 0.5, v * h - 0.5
    i, j = int(np.floor(x)), int(np.floor(y))
    a, b = x - i, y - j
    t = lambda ii, jj: texture[jj % h, ii % w]  # noqa: E731
    return (1 - a) * (1 - b) * t(i, j) + a * (1 - b) * t(i + 1, j) + (1 - a) * b * t(i, j + 1) + a * b * t(i + 1, j + 1)


def test_flat_triangle_matches_direct_bilinear_sampling():
    rng = np.random.default_rng(0)
    texture = rng.random((8, 16))  # non-square: h = 8, w = 16
    cam = triangle_cameras(V_FLAT, F_FLAT, screen_pixels=16)
    raster = rasterize(V_FLAT, F_FLAT, [0], cam)
    values = sample_bilinear(texture, texel_coordinates(UV_FLAT, raster.face, raster.bary, texture.shape))
    centres = cam.pixel_centres(0).reshape(-1, 3)
    # Barycentrics of each pixel centre by solving P = a + s (b - a) + t (c - a) in the plane z = 0.
    a, b, c = V_FLAT
    M = np.stack([b - a, c - a], axis=1)[:2]
    st = np.linalg.solve(M, (centres[:, :2] - a[:2]).T).T
    bary = np.column_stack([1 - st.sum(1), st])
    inside = (bary > 1e-9).all(1)
    border = (bary > -1e-9).all(1) & ~inside
    covered = np.zeros(len(centres), bool)
    covered[raster.pixel] = True
    assert covered[inside].all() and not covered[~inside & ~border].any()
    assert inside.sum() > 60  # the triangle covers a good part of the 16 x 16 screen
    np.testing.assert_allclose(raster.bary, bary[raster.pixel], atol=1e-12)
    uv = bary[raster.pixel] @ UV_FLAT[0]
    expected = [_bilinear_by_hand(texture, u, v) for u, v in uv]
    np.testing.assert_allclose(values, expected, atol=1e-14)


def test_affine_texture_is_reproduced_exactly():
    # Bilinear interpolation reproduces an affine function of the texel indices: T[iy, ix] = 0.01 ix + 0.02 iy
    # read at continuous coordinates (x, y) = (u w - 0.5, v h - 0.5) gives 0.01 x + 0.02 y (no wrap inside).
    h, w = 32, 24
    iy, ix = np.mgrid[0:h, 0:w]
    texture = 0.01 * ix + 0.02 * iy
    points = np.array([[3.7, 5.2], [10.5, 10.5], [1.0, 30.0], [23.4, 0.6]])
    np.testing.assert_allclose(sample_bilinear(texture, points),
                               0.01 * (points[:, 0] - 0.5) + 0.02 * (points[:, 1] - 0.5), atol=1e-14)


def test_bilinear_weights_by_hand():
    texels, weights = bilinear_weights([[2.5, 1.5], [2.0, 2.0], [0.25, 0.5]], (4, 8))
    # A texel centre reads only that texel (ix 2, iy 1 -> flat 1 * 8 + 2).
    assert texels[0, 0] == 10 and weights[0, 0] == 1.0 and np.all(weights[0, 1:] == 0)
    # A texel corner reads its four texels equally.
    np.testing.assert_array_equal(texels[1], [9, 10, 17, 18])
    np.testing.assert_allclose(weights[1], 0.25)
    # Left of the first texel centre, REPEAT wraps to the last column: x = -0.25 -> 0.25 of ix 7, 0.75 of ix 0.
    np.testing.assert_array_equal(texels[2], [7, 0, 15, 8])  # y = 0 exactly: row 1 has weight 0
    np.testing.assert_allclose(weights[2], [0.25, 0.75, 0, 0])


def test_nearest_surface_wins_and_far_plane_clips():
    # The centre triangle at z = 0; a copy at z = 0.5 in front (towards the eye at z = 500); one at z = 600
    # behind the eye (outside near/far of Algorithm 1), which must not be drawn.
    V = np.vstack([V_FLAT, V_FLAT + [0, 0, 0.5], V_FLAT * 3 + [0, 0, 600]])
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    cam = triangle_cameras(V, F, [0], screen_pixels=16)
    raster = rasterize(V, F, [0, 2, 1], cam)
    assert len(raster.pixel) > 60
    assert np.all(raster.face == 1)


@pytest.fixture(scope="module")
def bumpy_mesh():
    rng = np.random.default_rng(5)
    n = 9
    y, x = np.mgrid[0:n, 0:n] / (n - 1.0)
    V = np.column_stack([x.ravel(), y.ravel(), 0.15 * rng.standard_normal(n * n)])
    quads = [(i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(n - 1)
             for j in range(n - 1)]
    F = np.array([[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads])
    uv = V[F][:, :, :2] * 0.9 + 0.05
    return V, F, uv


def test_numba_raster_matches_numpy_reference(bumpy_mesh):
    V, F, _ = bumpy_mesh
    for face in (0, 30, 70, 100):
        cam = triangle_cameras(V, F, [face], screen_pixels=32)
        draw = np.arange(len(F))
        fast = rasterize(V, F, draw, cam)
        ref = _rasterize_reference(V, F, draw, cam)
        np.testing.assert_array_equal(fast.pixel, ref.pixel)
        np.testing.assert_array_equal(fast.face, ref.face)
        np.testing.assert_allclose(fast.bary, ref.bary, atol=1e-12)
        # Only the box is drawn, and the bumpy grid covers most of it.
        centres = cam.pixel_centres(0).reshape(-1, 3) - cam.origin[0]
        x, y = centres @ cam.right[0], centres @ cam.up[0]
        box = cam.box[0]
        in_box = np.flatnonzero((x >= box[0] - 1e-12) & (x <= box[1] + 1e-12) & (y >= box[2] - 1e-12)
                                & (y <= box[3] + 1e-12))
        assert np.isin(fast.pixel, in_box).all() and len(fast.pixel) > len(in_box) // 2
        assert len(in_box) < 32 * 32


def test_screen_operator_is_the_render(bumpy_mesh):
    V, F, uv = bumpy_mesh
    rng = np.random.default_rng(2)
    texture = rng.random((20, 12, 3))
    cam = triangle_cameras(V, F, [40], screen_pixels=16)
    raster = rasterize(V, F, np.arange(len(F)), cam)
    points = texel_coordinates(uv, raster.face, raster.bary, texture.shape)
    H = screen_operator(raster, points, texture.shape)
    assert H.shape == (16 * 16, 20 * 12)
    np.testing.assert_allclose(np.asarray(H.sum(axis=1)).ravel()[raster.pixel], 1.0)
    rendered = H @ texture.reshape(-1, 3)
    np.testing.assert_allclose(rendered[raster.pixel], sample_bilinear(texture, points), atol=1e-14)


def test_deform_points_fixes_the_centre():
    points = np.array([[1.0, 2.0], [3.0, -1.0]])
    A = np.array([[0.0, -0.5], [0.5, 0.0]])
    out = deform_points(points, A, [1.0, 2.0])
    np.testing.assert_allclose(out, [[1.0, 2.0], [1.0 + 1.5, 2.0 + 1.0]])


def test_rasterize_validation():
    cam = triangle_cameras(V_FLAT, F_FLAT)
    with pytest.raises(ValueError, match="draw"):
        rasterize(V_FLAT, F_FLAT, [1], cam)
    with pytest.raises(ValueError, match="length 1"):
        rasterize(V_FLAT, F_FLAT, [0], triangle_cameras(V_FLAT, np.vstack([F_FLAT, F_FLAT])))
