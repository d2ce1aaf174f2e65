import math

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import scipy.special

from perceptual_uv.core import bayesopt, gaussian_process
from perceptual_uv.core.bayesopt import minimize, minimize_constrained


def _random_problem(seed, n=12, c=7, d=4, periodic=(True, False, False, False)):
    rng = np.random.default_rng(seed)
    return rng.random((n, d)), rng.random((c, d)), np.exp(rng.uniform(-1.0, 1.5, d)), np.array(periodic)


def _full_factor(X, inv_length, periodic, noise):
    C = gaussian_process._matern52_numpy(X, X, inv_length, periodic) + noise * np.eye(len(X))
    return np.linalg.cholesky(C)


# --- kernels: numba against numpy references and against closed forms -------------------------------------


def test_matern52_numba_matches_numpy_reference():
    X, C, inv_length, periodic = _random_problem(0)
    np.testing.assert_allclose(gaussian_process._matern52_numba(X, C, inv_length, periodic),
                               gaussian_process._matern52_numpy(X, C, inv_length, periodic), rtol=1e-13)


def test_matern52_closed_form_and_periodic_wrap():
    # One dimension, length 1: k(r) = (1 + sqrt5 r + 5 r^2 / 3) exp(-sqrt5 r) at r = 0.5 by hand.
    r = 0.5
    expected = (1 + math.sqrt(5) * r + 5 * r * r / 3) * math.exp(-math.sqrt(5) * r)
    value = gaussian_process._matern52_numba(np.array([[0.1]]), np.array([[0.6]]), np.ones(1), np.zeros(1, bool))
    assert value[0, 0] == pytest.approx(expected, rel=1e-14)
    # Periodic (period 1): points 0.02 and 0.98 are 0.04 apart, as close as 0.50 and 0.54.
    periodic = np.ones(1, bool)
    across = gaussian_process._matern52_numba(np.array([[0.02]]), np.array([[0.98]]), np.ones(1), periodic)
    inside = gaussian_process._matern52_numba(np.array([[0.50]]), np.array([[0.54]]), np.ones(1), periodic)
    assert across[0, 0] == pytest.approx(inside[0, 0], rel=1e-12)


def test_cholesky_append_matches_full_factor_and_reference():
    X, _, inv_length, periodic = _random_problem(1)
    noise = 1e-4
    full = _full_factor(X, inv_length, periodic, noise)
    for append in (gaussian_process._cholesky_append_numba, gaussian_process._cholesky_append_numpy):
        L = np.zeros_like(full)
        for n in range(len(X)):
            k = gaussian_process._matern52_numpy(X[:n], X[n:n + 1], inv_length, periodic)[:, 0]
            append(L, n, k, 1.0 + noise)
        np.testing.assert_allclose(L, full, atol=1e-12)


def test_append_rows_numba_matches_reference_and_dense_solve():
    X, C, inv_length, periodic = _random_problem(2)
    L = _full_factor(X, inv_length, periodic, 1e-4)
    dense = scipy.linalg.solve_triangular(L, gaussian_process._matern52_numpy(X, C, inv_length, periodic), lower=True)
    for append in (gaussian_process._append_rows_numba, gaussian_process._append_rows_numpy):
        V, squares = np.empty((len(X), len(C))), np.zeros(len(C))
        # rows in two steps and columns in two blocks, as the search does
        append(V, squares, L, X, 0, 5, C, 0, 3, inv_length, periodic)
        append(V, squares, L, X, 5, len(X), C, 0, 3, inv_length, periodic)
        append(V, squares, L, X, 0, len(X), C, 3, len(C), inv_length, periodic)
        np.testing.assert_allclose(V, dense, atol=1e-12)
        np.testing.assert_allclose(squares, (dense ** 2).sum(0), atol=1e-12)


def test_posterior_from_rows_matches_textbook_formula():
    # mean = k*^T K^-1 y and variance 1 - k*^T K^-1 k*: recompute with dense solves.
    X, C, inv_length, periodic = _random_problem(3)
    noise = 1e-3
    y = np.sin(3 * X).sum(1)
    L = _full_factor(X, inv_length, periodic, noise)
    V, squares = np.empty((len(X), len(C))), np.zeros(len(C))
    gaussian_process._append_rows_numba(V, squares, L, X, 0, len(X), C, 0, len(C), inv_length, periodic)
    w = scipy.linalg.solve_triangular(L, y, lower=True)
    K = gaussian_process._matern52_numpy(X, X, inv_length, periodic) + noise * np.eye(len(X))
    Ks = gaussian_process._matern52_numpy(X, C, inv_length, periodic)
    np.testing.assert_allclose(gaussian_process._leading_dot_numba(V, w, len(C)), Ks.T @ np.linalg.solve(K, y),
                               atol=1e-10)
    np.testing.assert_allclose(squares, np.einsum("ij,ij->j", Ks, np.linalg.solve(K, Ks)), atol=1e-10)


def _scored_problem(seed, c=60):
    X, C, inv_length, periodic = _random_problem(seed, c=c)
    rng = np.random.default_rng(seed)
    mean, squares = rng.normal(size=c), rng.uniform(0, 0.999, c)
    cost, taken = rng.random(c), rng.random(c) < 0.1
    return mean, squares, cost, taken


@pytest.mark.parametrize("kind", [bayesopt._EI, bayesopt._LCB, bayesopt._FEASIBILITY,
                                  bayesopt._FEASIBLE_IMPROVEMENT])
def test_scores_numba_matches_numpy_reference(kind):
    mean, squares, cost, taken = _scored_problem(4)
    args = (mean, squares, 0.7, kind, -0.3, 0.01, cost, 0.6, taken)
    np.testing.assert_allclose(bayesopt._scores_numba(*args), bayesopt._scores_numpy(*args), rtol=1e-9,
                               atol=1e-12)


def test_expected_improvement_closed_form():
    # EI = (best - xi - m) Phi(z) + s phi(z), z = (best - xi - m) / s, at m = 0.2, s = sqrt(0.5 * 2), best = 0.
    m, signal = 0.2, 2.0
    s = math.sqrt(0.5 * signal)
    z = (0.0 - 0.01 - m) / s
    expected = (0.0 - 0.01 - m) * scipy.special.ndtr(z) + s * math.exp(-z * z / 2) / math.sqrt(2 * math.pi)
    score = bayesopt._scores_numba(np.array([m]), np.array([0.5]), signal, bayesopt._EI, 0.0, 0.01, np.zeros(1),
                                   0.0, np.zeros(1, bool))
    assert math.exp(score[0]) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("kind", [bayesopt._EI, bayesopt._FEASIBLE_IMPROVEMENT])
def test_select_batch_incremental_matches_dense_reference(kind):
    X, C, inv_length, periodic = _random_problem(9, n=10, c=80)
    noise, q = 1e-4, 4
    capacity = len(X) + q
    Xc, L = np.zeros((capacity, 4)), np.zeros((capacity, capacity))
    Xc[:len(X)] = X
    L[:len(X), :len(X)] = _full_factor(X, inv_length, periodic, noise)
    V, squares = np.empty((capacity, len(C))), np.zeros(len(C))
    gaussian_process._append_rows_numba(V, squares, L, Xc, 0, len(X), C, 0, len(C), inv_length, periodic)
    w = scipy.linalg.solve_triangular(L[:len(X), :len(X)], np.sin(4 * X[:, 0]), lower=True)
    mean = gaussian_process._leading_dot_numba(V, w, len(C))
    cost = np.random.default_rng(0).random(len(C))
    args = (mean, 0.8, inv_length, periodic, kind, 0.1, 0.01, cost, 0.7)
    reference = bayesopt._select_batch_numpy(q, Xc.copy(), L.copy(), len(X), noise, C, V.copy(), squares.copy(),
                                             *args)
    chosen = bayesopt._select_batch_numba(q, Xc, L, len(X), noise, C, V, squares, *args)
    np.testing.assert_array_equal(chosen, reference)
    assert len(set(chosen.tolist())) == q
    # the appended factor is the factor of the extended kernel matrix
    np.testing.assert_allclose(L, _full_factor(Xc, inv_length, periodic, noise), atol=1e-10)


def test_log_normal_cdf_deep_tail_matches_scipy():
    for z in (3.0, 0.0, -5.0, -29.0, -31.0, -60.0):
        assert bayesopt._log_normal_cdf_numba(z) == pytest.approx(scipy.special.log_ndtr(z), rel=1e-9)


def test_log_expected_improvement_ratio_deep_tail():
    # z Phi(z) + phi(z) = phi(z) (1 + z R(z)) with R = Phi/phi = sqrt(pi/2) erfcx(-z/sqrt2), independent of ours.
    for z in (1.0, -3.0, -19.0, -25.0, -40.0):
        ratio = 1 + z * math.sqrt(math.pi / 2) * scipy.special.erfcx(-z / math.sqrt(2))
        expected = -0.5 * z * z - 0.5 * math.log(2 * math.pi) + math.log(ratio)
        assert bayesopt._log_ei_ratio_numba(z) == pytest.approx(expected, rel=1e-6)


def test_log_likelihood_numba_matches_reference_and_finite_differences():
    X, _, _, periodic = _random_problem(5, n=15)
    y = np.sin(5 * X[:, 0]) + X[:, 1] ** 2
    y = (y - y.mean()) / y.std()
    log_length, log_noise = np.log([0.3, 0.5, 1.2, 0.8]), math.log(1e-3)
    value, gradient = gaussian_process._log_likelihood_numba(X, y, log_length, log_noise, periodic)
    ref_value, ref_gradient = gaussian_process._log_likelihood_numpy(X, y, log_length, log_noise, periodic)
    assert value == pytest.approx(ref_value, rel=1e-12)
    np.testing.assert_allclose(gradient, ref_gradient, rtol=1e-9)
    theta = np.append(log_length, log_noise)
    h = 1e-6
    for k in range(5):
        up, down = theta.copy(), theta.copy()
        up[k] += h
        down[k] -= h
        numeric = (gaussian_process._log_likelihood_numpy(X, y, up[:4], up[4], periodic)[0]
                   - gaussian_process._log_likelihood_numpy(X, y, down[:4], down[4], periodic)[0]) / (2 * h)
        assert gradient[k] == pytest.approx(numeric, rel=1e-5, abs=1e-7)


@pytest.mark.parametrize("seed", range(12))
def test_minimize_lbfgsb_gives_scipy_minimize_iterates_bit_for_bit(seed):
    # The GP's fit drives scipy's L-BFGS-B routine itself; scipy.optimize.minimize is the reference.
    rng = np.random.default_rng(seed)
    X, _, _, periodic = _random_problem(100 + seed, n=int(rng.integers(6, 50)))
    y = np.sin(6 * X[:, 0]) + X[:, 1] ** 2 + 0.1 * rng.standard_normal(len(X))
    y = (y - y.mean()) / y.std()

    def negative(theta):
        value, gradient = gaussian_process._log_likelihood_numba(X, y, theta[:-1], theta[-1], periodic)
        return -value, -gradient

    bounds = np.array([gaussian_process._LOG_LENGTH_BOUNDS] * 4 + [gaussian_process._LOG_NOISE_BOUNDS])
    start = rng.uniform(bounds[:, 0] - 0.5, bounds[:, 1] + 0.5)  # partly outside: both clip it
    for iterations in (1, 3, 20):
        expected = scipy.optimize.minimize(negative, start, jac=True, method="L-BFGS-B", bounds=bounds.tolist(),
                                           options={"maxiter": iterations}).x
        found = gaussian_process._minimize_lbfgsb(negative, start, bounds[:, 0], bounds[:, 1],
                                                  max_iterations=iterations)
        np.testing.assert_array_equal(found, expected)


def test_gaussian_process_incremental_factor_equals_refactor_after_fit():
    X, _, _, periodic = _random_problem(6, n=20)
    gp = gaussian_process._GaussianProcess(4, 30, periodic)
    for x in X[:12]:
        gp.add(x)
    gp.set_targets(np.sin(6 * X[:12, 0]))
    gp.fit()
    for x in X[12:]:
        gp.add(x)
    incremental = gp.L[:gp.n, :gp.n].copy()
    gp.refactor()
    np.testing.assert_allclose(incremental, gp.L[:gp.n, :gp.n], atol=1e-10)


@pytest.mark.parametrize("n", [1, 2, 7, 8, 9, 17, 64, 101, 130])
def test_gaussian_process_targets_standardized_by_numpy_mean_and_std_bit_for_bit(n):
    # The GP's offset and scale are numpy's mean and population standard deviation of the targets exactly (its
    # own reductions skip their wrappers), so runs do not depend on which of the two computed them.
    rng = np.random.default_rng(n)
    X = rng.random((n, 4))
    y = rng.standard_normal(n) * 10.0 ** rng.uniform(-4, 4) + rng.uniform(-3, 3)
    gp = gaussian_process._GaussianProcess(4, n, np.zeros(4, dtype=np.bool_))
    for x in X:
        gp.add(x)
    gp.set_targets(y)
    scale = float(np.std(y)) or 1.0  # a single target has no spread: it is only centred
    assert gp.offset == float(np.mean(y))
    assert gp.scale == scale
    standardized = (y - np.mean(y)) / scale
    np.testing.assert_allclose(gp.w, scipy.linalg.solve_triangular(gp.L[:n, :n], standardized, lower=True),
                               rtol=1e-12, atol=1e-12)


# --- optimization on functions with known minima ------------------------------------------------------------


def _branin(P):
    x, y = P[:, 0], P[:, 1]
    return (y - 5.1 / (4 * np.pi ** 2) * x ** 2 + 5 / np.pi * x - 6) ** 2 + 10 * (1 - 1 / (8 * np.pi)) * np.cos(x) + 10


def test_minimize_branin_reaches_global_minimum():
    # Global minimum 0.397887 at (-pi, 12.275), (pi, 2.275), (9.42478, 2.475).
    result = minimize(_branin, [[-5, 10], [0, 15]], evaluations=60, seed=0)
    assert result.fun < 0.397887 + 0.02
    assert result.evaluations == 60 and result.X.shape == (60, 2)
    assert _branin(result.x[None])[0] == pytest.approx(result.fun)


@pytest.mark.parametrize("acquisition", ["ei", "lcb"])
def test_minimize_4d_quadratic_finds_centre(acquisition):
    centre, weights = np.array([0.3, 0.7, 0.2, 0.55]), np.array([1.0, 3.0, 0.5, 2.0])
    result = minimize(lambda P: ((P - centre) ** 2 * weights).sum(1), [[0, 1]] * 4, evaluations=60,
                      acquisition=acquisition, seed=1)
    assert result.fun < 2e-3
    np.testing.assert_allclose(result.x, centre, atol=0.06)


def test_minimize_periodic_dimension_wraps_around():
    # Minimum at x0 = 0.01 (period 1) seen from both sides of the box edge.
    def f(P):
        return 1 - np.cos(2 * np.pi * (P[:, 0] - 0.01)) + (P[:, 1] - 0.5) ** 2

    result = minimize(f, [[0, 1], [0, 1]], evaluations=40, periodic=[True, False], seed=2)
    assert result.fun < 5e-3
    assert min(abs(result.x[0] - 0.01), abs(result.x[0] - 1.01)) < 0.03


def test_minimize_evaluates_x0_first_and_is_deterministic():
    quadratic = lambda P: ((P - 0.4) ** 2).sum(1)  # noqa: E731
    a = minimize(quadratic, [[0, 1]] * 3, evaluations=25, x0=[[0.9, 0.1, 0.5]], seed=7)
    b = minimize(quadratic, [[0, 1]] * 3, evaluations=25, x0=[[0.9, 0.1, 0.5]], seed=7)
    c = minimize(quadratic, [[0, 1]] * 3, evaluations=25, x0=[[0.9, 0.1, 0.5]], seed=8)
    np.testing.assert_array_equal(a.X[0], [0.9, 0.1, 0.5])
    np.testing.assert_array_equal(a.X, b.X)
    assert not np.array_equal(a.X, c.X)


def test_minimize_calls_objective_in_batches():
    sizes = []

    def f(P):
        sizes.append(len(P))
        return (P ** 2).sum(1)

    minimize(f, [[-1, 1]] * 2, evaluations=30, initial_points=10, batch_size=5, seed=0)
    assert sizes == [10, 5, 5, 5, 5]


def test_minimize_constrained_by_hand():
    # min x*y s.t. (1-x)^2 + (1-y)^2 <= 1/2 over [0.1,1]^2: on the circle x*y = 1 - r s + r^2 (s^2-1)/2 with
    # s = cos t + sin t, r = sqrt(1/2), minimal at s = sqrt2: x = y = 1/2, x*y = 1/4.
    def cost(P):
        return P[:, 0] * P[:, 1]

    def constraint(P):
        return (1 - P[:, 0]) ** 2 + (1 - P[:, 1]) ** 2

    result = minimize_constrained(cost, constraint, [[0.1, 1], [0.1, 1]], threshold=0.5, x0=[[1, 1]],
                                  evaluations=50, seed=0)
    assert result.feasible
    assert 0.25 - 1e-9 <= result.fun < 0.25 + 0.005
    # The cost is flat to second order along the circle near (1/2, 1/2); the constraint must be active.
    assert 0.45 <= constraint(result.x[None])[0] <= 0.5


def test_minimize_constrained_stops_at_known_lower_bound():
    # The cost's infimum over the box (corner 0.1 * 0.1) is feasible: the run stops right after x0.
    result = minimize_constrained(lambda P: P[:, 0] * P[:, 1], lambda P: np.zeros(len(P)), [[0.1, 1], [0.1, 1]],
                                  threshold=0.5, x0=[[1, 1], [0.1, 0.1]], cost_lower_bound=0.01, evaluations=50)
    assert result.evaluations == 2
    assert result.fun == pytest.approx(0.01)


def test_minimize_constrained_patience_counts_evaluations_without_a_cheaper_feasible_point():
    # Feasible only at x0 = (1, 1) (threshold 0 on a squared distance): x0 is evaluated alone, then the 9 points
    # of the Latin hypercube (initial_points = 10) find nothing: 9 evaluations without a cheaper feasible point.
    # With patience 8 the run stops after the design (1 + 9); with patience 12 after one round of 4 more.
    def run(patience):
        return minimize_constrained(lambda P: P[:, 0] * P[:, 1], lambda P: (1 - P[:, 0]) ** 2 + (1 - P[:, 1]) ** 2,
                                    [[0.1, 1], [0.1, 1]], threshold=0.0, x0=[[1, 1]], evaluations=50,
                                    patience=patience, seed=0)

    assert run(8).evaluations == 10
    assert run(12).evaluations == 14
    assert run(None).evaluations == 50
    assert run(12).fun == 1.0


def test_minimize_constrained_patience_stops_a_run_that_settled():
    # The circle problem of test_minimize_constrained_by_hand: the run with patience is the first part of the
    # run without, and it stops at the first round after which `patience` evaluations followed the cheapest
    # feasible point (checked between rounds of batch_size = 4).
    def run(patience):
        return minimize_constrained(lambda P: P[:, 0] * P[:, 1],
                                    lambda P: (1 - P[:, 0]) ** 2 + (1 - P[:, 1]) ** 2, [[0.1, 1], [0.1, 1]],
                                    threshold=0.5, x0=[[1, 1]], evaluations=100, patience=patience, seed=0)

    full, short = run(None), run(8)
    n = short.evaluations
    assert n < full.evaluations
    np.testing.assert_array_equal(short.X, full.X[:n])
    costs = full.X[:, 0] * full.X[:, 1]
    feasible = full.y <= 0.5
    cheapest = [int(np.argmin(np.where(feasible[:k], costs[:k], np.inf))) for k in range(1, n + 1)]
    since = [k - 1 - cheapest[k - 1] for k in range(1, n + 1)]
    assert since[-1] >= 8
    assert all(s < 8 for s in since[n - 5:n - 4])  # not settled at the previous round's end
    assert short.fun == costs[cheapest[-1]]


def test_minimize_constrained_min_improvement_settles_a_creeping_run():
    # The circle problem again. With min_improvement the run is still the first part of the run without
    # patience, and it stops at the first round's end n (rounds of batch_size = 4 after the 10-point design)
    # where the last 8 evaluations cut the cheapest feasible cost by less than a fifth:
    # cheapest(n) >= 0.8 * cheapest(n - 8), computed here from the whole run's costs.
    def run(patience, min_improvement=0.0):
        return minimize_constrained(lambda P: P[:, 0] * P[:, 1],
                                    lambda P: (1 - P[:, 0]) ** 2 + (1 - P[:, 1]) ** 2, [[0.1, 1], [0.1, 1]],
                                    threshold=0.5, x0=[[1, 1]], evaluations=100, patience=patience,
                                    min_improvement=min_improvement, seed=0)

    full, exact, creeping = run(None), run(8), run(8, 0.2)
    costs = full.X[:, 0] * full.X[:, 1]
    cheapest = np.minimum.accumulate(np.where(full.y <= 0.5, costs, np.inf))
    ends = list(range(10, 101, 4))
    settled = [n for n in ends if np.isfinite(cheapest[n - 9]) and cheapest[n - 1] >= 0.8 * cheapest[n - 9]]
    assert creeping.evaluations == settled[0] < exact.evaluations
    np.testing.assert_array_equal(creeping.X, full.X[:creeping.evaluations])
    assert creeping.fun == cheapest[creeping.evaluations - 1]


def test_minimize_constrained_patience_waits_for_a_feasible_point():
    result = minimize_constrained(lambda P: P[:, 0], lambda P: 1 + P[:, 0] ** 2, [[0, 1]], threshold=0.5,
                                  evaluations=15, patience=3, seed=0)
    assert result.evaluations == 15 and not result.feasible


def test_minimize_constrained_reports_infeasible():
    result = minimize_constrained(lambda P: P[:, 0], lambda P: 1 + P[:, 0] ** 2, [[0, 1]], threshold=0.5,
                                  evaluations=15, seed=0)
    assert not result.feasible
    assert result.x[0] < 0.2  # least violation


def test_validation_errors():
    with pytest.raises(ValueError, match="low < high"):
        minimize(_branin, [[1, 0]])
    with pytest.raises(ValueError, match="backend"):
        minimize(_branin, [[0, 1], [0, 1]], backend="gpyopt")
    with pytest.raises(ValueError, match="inside the bounds"):
        minimize(_branin, [[0, 1], [0, 1]], x0=[[2, 0]])
    with pytest.raises(ValueError, match="non-finite"):
        minimize(lambda P: np.full(len(P), np.inf), [[0, 1]], evaluations=5)
    with pytest.raises(ValueError, match="periodic"):
        minimize(_branin, [[0, 1], [0, 1]], periodic=[True])
    with pytest.raises(ValueError, match="patience"):
        minimize_constrained(lambda P: P[:, 0], lambda P: P[:, 0], [[0, 1]], threshold=0.5, patience=0)
    with pytest.raises(ValueError, match="min_improvement"):
        minimize_constrained(lambda P: P[:, 0], lambda P: P[:, 0], [[0, 1]], threshold=0.5, patience=4,
                             min_improvement=1.0)


def test_skopt_backend_same_budget_and_start():
    result = minimize(_branin, [[-5, 10], [0, 15]], evaluations=12, initial_points=5, x0=[[0.0, 0.0]],
                      backend="skopt", seed=0)
    assert result.evaluations == 12
    np.testing.assert_array_equal(result.X[0], [0.0, 0.0])
    assert result.fun == pytest.approx(_branin(result.X).min())
