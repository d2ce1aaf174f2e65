"""Tangent-space normals through one tangent frame and back into another (core.tangent_frame), by hand."""
import numpy as np
import pytest

from perceptual_uv.core.tangent_frame import interpolate_frame, object_to_tangent, tangent_to_object

X, Y, Z = np.eye(3)
# (0.8, 0.5, 0.9) stores c = (0.6, 0, 0.8), a unit normal tilted along T
TILTED = np.array([[0.8, 0.5, 0.9]])


def frame(tangent, sign, normal):
    return np.array([tangent], dtype=float), np.array([sign], dtype=float), np.array([normal], dtype=float)


def test_the_same_frame_gives_the_stored_normal_back():
    source = frame(X, 1.0, Z)
    direction = tangent_to_object(TILTED, *source)
    np.testing.assert_allclose(direction, [[0.6, 0.0, 0.8]], atol=1e-12)
    np.testing.assert_allclose(object_to_tangent(direction, *source), TILTED, atol=1e-12)


def test_a_quarter_turn_of_the_uv_map_moves_the_tilt_to_the_bitangent():
    # target (u, v) = (1 - y, x): T = -y, B = N x T = z x (-y) = +x, so the tilt along x is along B: (0.5, 0.8, 0.9)
    direction = tangent_to_object(TILTED, *frame(X, 1.0, Z))
    np.testing.assert_allclose(object_to_tangent(direction, *frame(-Y, 1.0, Z)), [[0.5, 0.8, 0.9]], atol=1e-12)


def test_a_mirrored_uv_map_flips_the_bitangent():
    # c = (0, 0.6, 0.8) along +y with sign +1 (B = z x x = +y); written with sign -1 (B = -y): c = (0, -0.6, 0.8)
    direction = tangent_to_object([[0.5, 0.8, 0.9]], *frame(X, 1.0, Z))
    np.testing.assert_allclose(direction, [[0.0, 0.6, 0.8]], atol=1e-12)
    np.testing.assert_allclose(object_to_tangent(direction, *frame(X, -1.0, Z)), [[0.5, 0.2, 0.9]], atol=1e-12)
    # a negative interpolated sign counts as -1, whatever its size
    np.testing.assert_allclose(object_to_tangent(direction, *frame(X, -0.3, Z)), [[0.5, 0.2, 0.9]], atol=1e-12)


def test_the_frame_is_inverted_not_transposed():
    # T = (1, 0, 1) is not orthogonal to N = z; B = z x T = (0, 1, 0). x = 1 T + 0 B - 1 N, so c = (1, 0, -1) / sqrt 2
    # (projecting onto the axes, T.x = 1, B.x = 0, N.x = 0, would give (1, 0, 0))
    h = 0.5 / np.sqrt(2)
    np.testing.assert_allclose(object_to_tangent([X], *frame((1, 0, 1), 1.0, Z)), [[0.5 + h, 0.5, 0.5 - h]],
                               atol=1e-12)
    # the Normal Map node does not normalize the frame either: T = (2, 0, 0) takes c = (0.6, 0, 0.8) to
    # unit(1.2, 0, 0.8) = (3, 0, 2) / sqrt 13, not to (0.6, 0, 0.8)
    np.testing.assert_allclose(tangent_to_object(TILTED, *frame((2, 0, 0), 1.0, Z)),
                               [[3 / np.sqrt(13), 0.0, 2 / np.sqrt(13)]], atol=1e-12)


def test_strength_mixes_from_the_surface_normal():
    # an interpolated normal of length 2: the mix starts from its unit
    np.testing.assert_allclose(tangent_to_object(TILTED, *frame(X, 1.0, (0, 0, 2)), strength=0.0), [[0, 0, 1]],
                               atol=1e-12)
    # strength 0.5: unit(z + 0.5 ((0.6, 0, 0.8) - z)) = unit(0.3, 0, 0.9) = (1, 0, 3) / sqrt 10
    np.testing.assert_allclose(tangent_to_object(TILTED, *frame(X, 1.0, Z), strength=0.5),
                               [[1 / np.sqrt(10), 0.0, 3 / np.sqrt(10)]], atol=1e-12)


def test_a_singular_frame_writes_the_unperturbed_normal():
    np.testing.assert_allclose(object_to_tangent([[0.6, 0.0, 0.8]], *frame((0, 0, 0), 1.0, Z)), [[0.5, 0.5, 1.0]])
    assert object_to_tangent(np.empty((0, 3)), np.empty((0, 3)), np.empty(0), np.empty((0, 3))).shape == (0, 3)


def test_the_frame_is_the_barycentric_mix_of_the_corners():
    tangents = [[X, Y, -X]]
    normals = [[Z, Z, (0, 1, 0)]]
    tangent, sign, normal = interpolate_frame([[0.5, 0.25, 0.25]], tangents, [[1, 1, -1]], normals)
    np.testing.assert_allclose(tangent, [[0.25, 0.25, 0.0]])
    np.testing.assert_allclose(sign, [0.5])
    np.testing.assert_allclose(normal, [[0.0, 0.25, 0.75]])


@pytest.mark.parametrize("seed", [0, 1])
def test_a_round_trip_through_random_frames_keeps_unit_normals(seed):
    rng = np.random.default_rng(seed)
    count = 50
    normal = rng.normal(size=(count, 3))
    tangent = np.cross(normal, rng.normal(size=(count, 3)))
    sign = rng.choice([-1.0, 1.0], count)
    c = rng.normal(size=(count, 3))
    c[:, 2] = np.abs(c[:, 2])
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    stored = 0.5 * c + 0.5
    np.testing.assert_allclose(object_to_tangent(tangent_to_object(stored, tangent, sign, normal), tangent, sign,
                                                 normal), stored, atol=1e-10)
