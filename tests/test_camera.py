"""App. A camera (Algorithm 1), checked against hand-computed frames and windows."""
import numpy as np
import pytest

from perceptual_uv.core.camera import (CLIP_FAR, CLIP_NEAR, EYE_DISTANCE, BOX_MARGIN, triangle_cameras,
                                       texel_matched_pixels)

# a = (0, 0, 0), b = (4, 0, 0), c = (1, 2, 0): barycentre C = (5/3, 2/3, 0), normal (b - a) x (c - a) = +z.
# Edges: ab = 4 (the longest), bc = sqrt(13), ca = sqrt(5). By hand: R along ab = (1, 0, 0), U = N x R =
# (0, 1, 0); corners about C: a (-5/3, -2/3), b (7/3, -2/3), c (-2/3, 4/3). The box is x in [-5/3, 7/3]
# (w = 4), y in [-2/3, 4/3] (h = 2); the square screen grows y by (4 - 2) / 2 on both sides, the drawn box by
# BOX_MARGIN * w = 0.5.
V_HAND = np.array([[0.0, 0, 0], [4, 0, 0], [1, 2, 0]])
F_HAND = np.array([[0, 1, 2]])
BOUNDS_HAND = [-5 / 3, 7 / 3, -5 / 3, 7 / 3]
BOX_HAND = [-5 / 3, 7 / 3, -2 / 3 - 0.5, 4 / 3 + 0.5]


def test_hand_triangle_frame_and_window():
    cam = triangle_cameras(V_HAND, F_HAND)
    np.testing.assert_allclose(cam.origin[0], [5 / 3, 2 / 3, 0])
    np.testing.assert_allclose(cam.normal[0], [0, 0, 1])
    np.testing.assert_allclose(cam.right[0], [1, 0, 0])
    np.testing.assert_allclose(cam.up[0], [0, 1, 0])
    np.testing.assert_allclose(cam.bounds[0], BOUNDS_HAND)
    np.testing.assert_allclose(cam.box[0], BOX_HAND)
    assert cam.screen_pixels == 64
    np.testing.assert_allclose(cam.size, [4.0])
    np.testing.assert_allclose(cam.half_extent, [2.0])
    np.testing.assert_allclose(cam.pixel_size, [4.0 / 64])
    # The window's centre is the box's: x (0 + 4) / 2, y (0 + 2) / 2.
    np.testing.assert_allclose(cam.view_centre[0], [2, 1, 0])
    np.testing.assert_allclose(cam.eye[0], [5 / 3, 2 / 3, EYE_DISTANCE])
    assert cam.valid[0]
    assert (EYE_DISTANCE, CLIP_NEAR, CLIP_FAR) == (500.0, 0.1, 1000.0)


def test_the_band_stops_at_the_square_and_does_not_depend_on_the_pixels():
    assert BOX_MARGIN == 0.125
    for pixels in (16, 24, 256):
        np.testing.assert_allclose(triangle_cameras(V_HAND, F_HAND, screen_pixels=pixels).box[0], BOX_HAND)
    # Equilateral, side 2, its first edge along x: height sqrt(3) = 1.732; the square grows it by 0.134 on each
    # side, less than the band's 0.25, so the drawn box is the whole square.
    V = np.array([[0.0, 0, 0], [2, 0, 0], [1, np.sqrt(3), 0]])
    cam = triangle_cameras(V, F_HAND)
    np.testing.assert_allclose(cam.box[0], cam.bounds[0])
    np.testing.assert_allclose(cam.bounds[0][3] - cam.bounds[0][2], 2.0)


def test_the_frame_follows_the_longest_edge_whichever_corner_comes_first():
    # The same triangle with its corners listed from c, then from b: the same frame up to the edge's direction.
    for order in ([2, 0, 1], [1, 2, 0]):
        cam = triangle_cameras(V_HAND, F_HAND[:, order])
        np.testing.assert_allclose(np.abs(cam.right[0] @ [1.0, 0, 0]), 1.0)
        np.testing.assert_allclose(cam.size, [4.0])
        box = cam.box[0]
        np.testing.assert_allclose([box[1] - box[0], box[3] - box[2]], [4, 3])
    # Stretched along y, the triangle's longest edge changes: the frame follows it, and the box stays wider than high.
    tall = triangle_cameras(V_HAND * [1, 4, 1], F_HAND)
    # Edges ab = 4, bc = (-3, 8) of length sqrt(73), ca = (-1, -8) of length sqrt(65): R along bc.
    np.testing.assert_allclose(tall.right[0], np.array([-3.0, 8, 0]) / np.sqrt(73))
    np.testing.assert_allclose(tall.size, [np.sqrt(73)])


def test_square_window_is_algorithm_1_as_written():
    # a = (2, 0, 0), b = (-1, 1, 0), c = (-1, -1, 0): barycentre at the origin, a - C along +x, normal +z.
    # Algorithm 1 by hand: R = (1, 0, 0), U = N x R = (0, 1, 0); projections a (2, 0), b (-1, 1), c (-1, -1);
    # bbox x in [-1, 2] (w = 3), y in [-1, 1] (h = 2); w > h so y grows by (3 - 2) / 2 on both sides, and the
    # whole square is drawn.
    V = np.array([[2.0, 0, 0], [-1, 1, 0], [-1, -1, 0]])
    cam = triangle_cameras(V, F_HAND, window="square")
    np.testing.assert_allclose(cam.right[0], [1, 0, 0])
    np.testing.assert_allclose(cam.up[0], [0, 1, 0])
    np.testing.assert_allclose(cam.bounds[0], [-1, 2, -1.5, 1.5])
    np.testing.assert_array_equal(cam.box[0], cam.bounds[0])
    # Taller than wide: stretch y by 4, projections a (2, 0), b (-1, 4), c (-1, -4); x grows by 2.5 each side.
    tall = triangle_cameras(V * [1, 4, 1], F_HAND, window="square")
    np.testing.assert_allclose(tall.bounds[0], [-3.5, 4.5, -4, 4])
    with pytest.raises(ValueError, match="window"):
        triangle_cameras(V, F_HAND, window="circle")


def test_pixel_centres_bottom_row_first():
    cam = triangle_cameras(V_HAND, F_HAND, screen_pixels=4)
    centres = cam.pixel_centres(0)
    step = 4.0 / 4
    # Row 0 is the bottom of the view (smallest U coordinate), column 0 the left (smallest R coordinate); in the
    # world, the square's corner (-5/3, -5/3) about C is (0, -1).
    np.testing.assert_allclose(centres[0, 0], [step / 2, -1 + step / 2, 0])
    np.testing.assert_allclose(centres[3, 0], [step / 2, 3 - step / 2, 0])
    np.testing.assert_allclose(centres[0, 3], [4 - step / 2, -1 + step / 2, 0])


def test_rigid_motion_moves_the_frame_with_the_triangle():
    rng = np.random.default_rng(0)
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))  # a rotation keeps the winding, hence the normal's side
    t = np.array([1.0, -2.0, 3.0])
    cam = triangle_cameras(V_HAND @ Q.T + t, F_HAND)
    np.testing.assert_allclose(cam.origin[0], Q @ [5 / 3, 2 / 3, 0] + t, atol=1e-14)
    np.testing.assert_allclose(cam.right[0], Q[:, 0], atol=1e-14)
    np.testing.assert_allclose(cam.up[0], Q[:, 1], atol=1e-14)
    np.testing.assert_allclose(cam.normal[0], Q[:, 2], atol=1e-14)
    np.testing.assert_allclose(cam.bounds[0], BOUNDS_HAND, atol=1e-14)
    np.testing.assert_allclose(cam.box[0], BOX_HAND, atol=1e-14)


def test_vectorized_rows_match_single_calls_and_select_faces():
    rng = np.random.default_rng(1)
    V = rng.standard_normal((30, 3))
    F = rng.integers(0, 30, (20, 3))
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    faces = [3, 0, 5]
    batch = triangle_cameras(V, F, faces)
    for row, f in enumerate(faces):
        single = triangle_cameras(V, F, [f])
        np.testing.assert_array_equal(batch.bounds[row], single.bounds[0])
        np.testing.assert_array_equal(batch.right[row], single.right[0])
    sub = batch[1]
    assert len(sub) == 1 and sub.faces[0] == 0
    # Frames are orthonormal and right-handed.
    frame = np.stack([batch.right, batch.up, batch.normal], axis=1)
    np.testing.assert_allclose(frame @ frame.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (3, 3, 3)),
                               atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(frame), 1.0)
    # The window is square and holds the box, which is as wide as the window.
    np.testing.assert_allclose(batch.bounds[:, 1] - batch.bounds[:, 0], batch.bounds[:, 3] - batch.bounds[:, 2])
    np.testing.assert_array_equal(batch.box[:, [0, 1]], batch.bounds[:, [0, 1]])
    assert (batch.box[:, 2] >= batch.bounds[:, 2] - 1e-12).all()
    assert (batch.box[:, 3] <= batch.bounds[:, 3] + 1e-12).all()


def test_degenerate_triangle_is_invalid_not_an_error():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    cam = triangle_cameras(V, F_HAND)
    assert not cam.valid[0]
    assert np.isnan(cam.bounds[0]).all() and np.isnan(cam.box[0]).all()


@pytest.mark.parametrize("kwargs, message", [
    (dict(V=np.zeros((3, 2)), F=F_HAND), "V must"),
    (dict(V=V_HAND, F=np.array([[0, 1, 3]])), "outside V"),
    (dict(V=V_HAND, F=F_HAND.astype(float)), "F must"),
    (dict(V=V_HAND, F=F_HAND, screen_pixels=0), "screen_pixels"),
    (dict(V=V_HAND, F=F_HAND, faces=[1]), "faces"),
])
def test_validation(kwargs, message):
    with pytest.raises(ValueError, match=message):
        triangle_cameras(**kwargs)


def test_texel_matched_pixels_by_hand():
    # Three copies of the right triangle with unit legs (surface area 1/2); App. A's window over it is the
    # hypotenuse sqrt(2) wide. UV legs 0.1, 0.25 and 0.03 of a 1024 x 1024 texture: 102.4, 256 and 30.72 texels
    # per unit length, so sqrt(2) times that across the window: 144.8 -> 146 (even), 362 -> 256 (the maximum),
    # 43.4 -> 64 (the minimum).
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]] * 3, dtype=float) + np.repeat(np.arange(3) * 2.0, 3)[:, None]
    F = np.arange(9).reshape(3, 3)
    legs = np.array([0.1, 0.25, 0.03])
    uv = legs[:, None, None] * np.array([[0, 0], [1, 0], [0, 1]], dtype=float)
    np.testing.assert_array_equal(texel_matched_pixels(V, F, uv, (1024, 1024)), [146, 256, 64])
    np.testing.assert_array_equal(texel_matched_pixels(V, F, uv, (1024, 1024), [2, 0]), [64, 146])
    # App. A's fixed size when the maximum does not exceed the minimum
    np.testing.assert_array_equal(texel_matched_pixels(V, F, uv, (1024, 1024), maximum=64), [64, 64, 64])
    # A 512 x 1024 (h x w) texture halves the texel area: 144.8 / sqrt(2) = 102.4 -> 104
    assert texel_matched_pixels(V, F, uv, (512, 1024, 3))[0] == 104
    # No UV area, or no surface: the minimum
    flat = uv.copy()
    flat[0, 2] = flat[0, 1]
    assert texel_matched_pixels(V, F, flat, (1024, 1024))[0] == 64
    V_line = V.copy()
    V_line[2] = V_line[1]
    assert texel_matched_pixels(V_line, F, uv, (1024, 1024))[0] == 64
