import numpy as np
import pytest

from perceptual_uv.core.deformation import jacobian, rotation, stretch


def test_rotation_quarter_turn_maps_x_to_y():
    np.testing.assert_allclose(rotation(np.pi / 2) @ [1.0, 0.0], [0.0, 1.0], atol=1e-15)


def test_stretch_along_diagonal_by_hand():
    # beta = 45 deg: V = [[1,-1],[1,1]]/sqrt2, S = V diag(2,1) V^T = [[1.5, 0.5], [0.5, 1.5]].
    np.testing.assert_allclose(stretch(2.0, 1.0, np.pi / 4), [[1.5, 0.5], [0.5, 1.5]], atol=1e-15)


def test_quarter_turn_of_beta_swaps_eigenvalues():
    # S(l1, l2, beta + pi/2) = S(l2, l1, beta): the symmetry the paper uses to restrict beta to [0, pi/2).
    np.testing.assert_allclose(stretch(0.3, 0.8, 0.2 + np.pi / 2), stretch(0.8, 0.3, 0.2), atol=1e-15)


def test_jacobian_determinant_is_eigenvalue_product():
    params = np.array([[0.3, 0.5, 0.2, 1.0], [1.2, 1.0, 1.0, 0.0]])
    R, S = jacobian(params)
    np.testing.assert_allclose(np.linalg.det(R @ S), [0.1, 1.0])


def test_jacobian_rejects_wrong_width():
    with pytest.raises(ValueError, match="4 columns"):
        jacobian(np.zeros((2, 3)))


def test_inverse_2x2_by_hand_and_against_numpy():
    from perceptual_uv.core.deformation import inverse_2x2

    # [[2, 1], [1, 1]] has det 1 and inverse [[1, -1], [-1, 2]]
    np.testing.assert_array_equal(inverse_2x2(np.array([[2.0, 1.0], [1.0, 1.0]])), [[1.0, -1.0], [-1.0, 2.0]])
    # a rotation by 30 degrees times diag(2, 0.5): the inverse is diag(0.5, 2) times the rotation back
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    m = np.array([[c, -s], [s, c]]) @ np.diag([2.0, 0.5])
    np.testing.assert_allclose(inverse_2x2(m), np.diag([0.5, 2.0]) @ np.array([[c, s], [-s, c]]), atol=1e-15)
    batch = np.random.default_rng(0).normal(size=(3, 5, 2, 2))
    np.testing.assert_allclose(inverse_2x2(batch), np.linalg.inv(batch), rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError):
        inverse_2x2(np.eye(3))
