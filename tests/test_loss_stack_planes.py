"""The stack loss's all-planes-at-once kernels against their one-plane counterparts.

``core.loss_stack`` evaluates the planes of one shape together: the GMSD's fill of uncovered cells is planned
once (``gmsd._extension_plan``) and replayed per screen, and the band and envelope substitutions take every
plane's right-hand side in one pass. These must give what the one-plane kernels give: the GMSD bit for bit,
the substitutions to rounding.
"""
import numpy as np
import pytest

from perceptual_uv.core.bake_lsq import (_band_cholesky_solve, _band_factorize, _band_substitute_planes,
                                         _envelope_cholesky_solve, _envelope_factorize, _envelope_substitute_planes)
from perceptual_uv.core.gmsd import GMSD_C, _covered_gmsd_kernel, _covered_gmsd_planned, _extension_plan


def _screen(rng, m, coverage):
    size = m + 2
    counts = np.zeros(size * size)
    inner = (np.arange(size)[:, None] > 0) & (np.arange(size)[:, None] <= m)
    inner = (inner & inner.T).reshape(-1)
    covered = inner & (rng.random(size * size) < coverage)
    counts[covered] = rng.integers(1, 5, covered.sum())
    sums = counts * rng.random(size * size)
    return sums, counts


@pytest.mark.parametrize("coverage", [0.0, 0.02, 0.3, 1.0])
def test_planned_gmsd_is_the_searched_gmsd_bit_for_bit(coverage):
    rng = np.random.default_rng(3)
    m = 17
    size = (m + 2) ** 2
    for _ in range(5):
        sums, counts = _screen(rng, m, coverage)
        gradient = rng.random(m * m) * 0.3
        covered, inner, fill = _extension_plan(counts, m)
        for _ in range(3):  # one plan, many screens with the same covered cells
            screen = counts * rng.random(size)
            expected = _covered_gmsd_kernel(screen, counts, m, gradient, GMSD_C, np.empty(size),
                                            np.empty(size, np.int64))
            got = _covered_gmsd_planned(screen, counts, m, gradient, GMSD_C, np.empty(size), covered, inner, fill,
                                        np.empty(len(inner)))
            assert got == expected


def test_a_nan_cell_makes_both_gmsd_nan():
    """A NaN render makes E NaN: the fill tells reached cells by a flag, not by a NaN value, so a NaN cell is
    neither refilled from a neighbour nor queued twice (which would overrun the queue)."""
    rng = np.random.default_rng(4)
    m = 9
    size = (m + 2) ** 2
    sums, counts = _screen(rng, m, 0.5)
    sums[np.flatnonzero(counts)[3]] = np.nan
    gradient = rng.random(m * m)
    covered, inner, fill = _extension_plan(counts, m)
    expected = _covered_gmsd_kernel(sums, counts, m, gradient, GMSD_C, np.empty(size), np.empty(size, np.int64))
    got = _covered_gmsd_planned(sums, counts, m, gradient, GMSD_C, np.empty(size), covered, inner, fill,
                                np.empty(len(inner)))
    assert np.isnan(expected) and np.isnan(got)


def _spd_banded(rng, n, bandwidth):
    """A positive definite matrix with a ragged lower envelope inside ``bandwidth``."""
    A = np.zeros((n, n))
    for i in range(n):
        first = max(0, i - rng.integers(0, bandwidth + 1))
        A[i, first:i] = rng.normal(size=i - first) * 0.3
    A = A + A.T
    A[np.diag_indices(n)] = np.abs(A).sum(axis=1) + 1.0
    return A


def test_band_substitution_of_all_planes_matches_one_plane_at_a_time():
    rng = np.random.default_rng(5)
    n, bandwidth, planes = 60, 7, 4
    A = _spd_banded(rng, n, bandwidth)
    band = np.zeros((n, bandwidth + 1))
    for j in range(n):
        for d in range(min(bandwidth, n - 1 - j) + 1):
            band[j, d] = A[j + d, j]
    rhs = rng.normal(size=(planes, n))
    expected = rhs.copy()
    for q in range(planes):
        _band_cholesky_solve(band.copy(), expected[q], 1e-12)
    factor = band.copy()
    _band_factorize(factor, 1e-12)
    x = np.ascontiguousarray(rhs.T)
    _band_substitute_planes(factor, x)
    np.testing.assert_allclose(x.T, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(A @ x, rhs.T, rtol=1e-10, atol=1e-12)


def test_envelope_substitution_of_all_planes_matches_one_plane_at_a_time():
    rng = np.random.default_rng(6)
    n, planes = 50, 3
    A = _spd_banded(rng, n, 9)
    first = np.array([np.flatnonzero(A[i, :i + 1])[0] for i in range(n)], np.int64)
    offset = np.concatenate([[0], np.cumsum(np.arange(n) - first + 1)]).astype(np.int64)
    env = np.concatenate([A[i, first[i]:i + 1] for i in range(n)])
    rhs = rng.normal(size=(planes, n))
    expected = rhs.copy()
    for q in range(planes):
        _envelope_cholesky_solve(env.copy(), offset, first, expected[q], 1e-12)
    factor = env.copy()
    _envelope_factorize(factor, offset, first, 1e-12)
    x = np.ascontiguousarray(rhs.T)
    _envelope_substitute_planes(factor, offset, first, x)
    np.testing.assert_allclose(x.T, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(A @ x, rhs.T, rtol=1e-10, atol=1e-12)
