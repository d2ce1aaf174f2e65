"""The re-bake solved in nested-dissection order (core.multifrontal) against the band/envelope Cholesky and dense
solves: the same system, the same answer to rounding."""
import numpy as np
import pytest

from perceptual_uv.core import loss
from perceptual_uv.core.bake_lsq import DEFAULT_RIDGE
from perceptual_uv.core.deformation import jacobian
from perceptual_uv.core.gmsd import GMSD_C
from perceptual_uv.core.loss_stack import _deformed_ids, _evaluate_planes_kernel, _rebake_render_cells
from perceptual_uv.core.multifrontal import LEAF_TEXELS, _dissection_tree, _multifrontal_solve

from meshes import grid_mesh  # tests/ is on sys.path under pytest

IDENTITY = [0.0, 1.0, 1.0, 0.0]
NESTED = 0.0  # dissection_cost: every re-bake through core.multifrontal
DIRECT = np.inf  # never: band or envelope Cholesky
NO_PEEL = 2 ** 62  # peel_min_cells: every pixel goes to the solver (the peeling is tested in test_rebake_peel.py)


def lattice_blob(rng, size=40):
    """Cells ``(x, y)`` of a ring with a few holes, plus a separate island: irregular, two components."""
    y, x = np.mgrid[0:size, 0:size]
    r = np.hypot(x - size / 2, y - size / 2)
    ring = (r < size / 2 - 1) & (r > size / 8) & (rng.random(r.shape) < 0.97)
    island_y, island_x = np.mgrid[10:16, size + 5:size + 9]
    return np.concatenate([x[ring], island_x.ravel()]), np.concatenate([y[ring], island_y.ravel()])


def cell_system(rng, cell_x, cell_y, pixels_per_cell, n_planes):
    """Texel ids, pooled sums (the layout of loss_stack._rebake_render_cells) and the dense problem ``B``, ``t``
    of random pixels in the given cells; texel ids are shuffled so that no solver can rely on their order."""
    corners = {}
    cell_tex = np.empty((len(cell_x), 4), np.int64)
    for c, (x, y) in enumerate(zip(cell_x, cell_y)):
        for k in range(4):
            cell_tex[c, k] = corners.setdefault((x + (k & 1), y + (k >> 1)), len(corners))
    n_tex = len(corners)
    shuffle = rng.permutation(n_tex)
    cell_tex = shuffle[cell_tex]
    rows, targets = [], []
    acc = np.zeros((len(cell_x), 10 + 4 * n_planes))
    for c in range(len(cell_x)):
        for _ in range(pixels_per_cell):
            fx, fy = rng.random(2)
            w = np.array([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
            t = rng.random(n_planes)
            acc[c, :4] += w * w
            acc[c, 4] += w[0] * w[1]
            acc[c, 5] += w[0] * w[2]
            acc[c, 6] += w[0] * w[3]  # == w1 w2
            acc[c, 8] += w[1] * w[3]
            acc[c, 9] += w[2] * w[3]
            for q in range(n_planes):
                acc[c, 10 + 4 * q:14 + 4 * q] += w * t[q]
            row = np.zeros(n_tex)
            row[cell_tex[c]] = w
            rows.append(row)
            targets.append(t)
    return cell_tex, acc, n_tex, np.array(rows), np.array(targets)


def test_dissection_tree_eliminates_every_coupled_pair_along_the_tree():
    # Coupled texels (one cell apart) must lie on one root path: the later one's subtree holds the earlier one.
    rng = np.random.default_rng(0)
    xs, ys = lattice_blob(rng)
    tex = np.unique(np.concatenate([np.column_stack([xs + dx, ys + dy]) for dx in (0, 1) for dy in (0, 1)]), axis=0)
    perm, node_lo, node_sep, node_hi, n_children, postorder = _dissection_tree(tex[:, 0].copy(), tex[:, 1].copy(), 8)
    n = len(tex)
    np.testing.assert_array_equal(np.sort(perm), np.arange(n))
    position = np.empty(n, np.int64)
    position[perm] = np.arange(n)
    owner = np.empty(n, np.int64)  # the node eliminating each position
    for v in range(len(node_lo)):
        assert node_lo[v] <= node_sep[v] <= node_hi[v]
        owner[node_sep[v]:node_hi[v]] = v
    assert node_hi[postorder[-1]] == n and node_lo[postorder[-1]] == 0  # the root comes last
    # The children of a node tile the part of its range before its own texels and come before it.
    done = set()
    for v in postorder:
        inside = [u for u in range(len(node_lo)) if u != v and node_lo[v] <= node_lo[u] and node_hi[u] <= node_sep[v]]
        children = [u for u in inside if not any(w != u and node_lo[w] <= node_lo[u] and node_hi[u] <= node_sep[w]
                                                 for w in inside)]
        assert len(children) == n_children[v] and set(children) <= done
        assert sum(node_hi[u] - node_lo[u] for u in children) == node_sep[v] - node_lo[v]
        done.add(v)
    index = {tuple(p): i for i, p in enumerate(tex)}
    pairs = 0
    for i, (x, y) in enumerate(tex):
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                j = index.get((x + dx, y + dy))
                if j is None or position[j] <= position[i]:
                    continue
                v = owner[position[j]]
                assert node_lo[v] <= position[i] < node_hi[v]
                pairs += 1
    assert pairs > 3 * n  # about four per texel away from the edges


@pytest.mark.parametrize("pixels_per_cell", [1, 6])
def test_multifrontal_solve_matches_a_dense_solve(pixels_per_cell):
    # Six pixels per cell: every texel is determined, the texels themselves agree. One pixel per cell: fewer
    # pixels than texels, the ridge picks the answer; the renders agree (the texels only to the conditioning).
    rng = np.random.default_rng(pixels_per_cell)
    xs, ys = lattice_blob(rng)
    cell_tex, acc, n_tex, B, targets = cell_system(rng, xs, ys, pixels_per_cell, 3)
    ridge = DEFAULT_RIDGE
    expected = np.linalg.solve(B.T @ B + ridge * np.eye(n_tex), B.T @ targets)
    rhs = np.zeros((3, n_tex))
    for leaf in (1, 32, n_tex):  # a leaf of one texel, the default, no dissection at all
        _multifrontal_solve(cell_tex, acc, xs, ys, n_tex, ridge, rhs, leaf)
        np.testing.assert_allclose(B @ rhs.T, B @ expected, atol=1e-9)
        if pixels_per_cell > 1:
            np.testing.assert_allclose(rhs.T, expected, atol=1e-9)


def triangle_args(problem, params, planes=None):
    """Arguments of loss_stack._evaluate_planes_kernel for a problem, or the same-shaped ``planes`` of a stack."""
    planes = planes or [problem]
    return (np.atleast_2d(np.asarray(params, float)), problem.points, problem.pooled_index, problem.box,
            np.stack([p.reference for p in planes]), np.stack([p.reference_gradient for p in planes]),
            problem.centre, problem.ridge, GMSD_C, True)


def deformation(row):
    """``A = R(alpha) S(lambda1, lambda2, beta)`` row by row (Eq. 13), as the kernel takes it."""
    R, S = jacobian(row)
    A = R @ S
    return A[0, 0], A[0, 1], A[1, 0], A[1, 1]


def texels_read(problem, row):
    return len(_deformed_ids(problem.points, *deformation(row), *problem.centre)[2])


def assert_same_rebake(problem, params, planes=None, rtol=1e-9):
    """Renders (per pixel) and E of both solvers agree (every pixel solved: no peeling), and the cell path ran
    both times. The identity (first row) reads enough texels for a dissection several levels deep."""
    planes = planes or [problem]
    references = np.stack([p.reference for p in planes])
    assert texels_read(problem, params[0]) > 8 * LEAF_TEXELS
    for row in np.atleast_2d(params):
        rendered = {}
        for name, threshold in (("nested", NESTED), ("direct", DIRECT)):
            out = np.empty_like(references)
            assert _rebake_render_cells(problem.points, references, problem.box, *deformation(row), *problem.centre,
                                        problem.ridge, out, threshold, NO_PEEL)
            rendered[name] = out
        np.testing.assert_allclose(rendered["nested"], rendered["direct"], rtol=0, atol=1e-9 * np.abs(references).max())
    args = triangle_args(problem, params, planes)
    e_nested = _evaluate_planes_kernel(*args, NESTED, NO_PEEL)
    e_direct = _evaluate_planes_kernel(*args, DIRECT, NO_PEEL)
    np.testing.assert_allclose(e_nested, e_direct, rtol=rtol, atol=1e-12)
    return e_nested


def random_params(rng, k):
    lo = np.array([0.0, 0.05, 0.05, 0.0])
    hi = np.array([np.pi / 2, 1.0, 1.0, np.pi / 2])
    return lo + (hi - lo) * rng.random((k, 4))


PARAMS = np.vstack([IDENTITY, [0.3, 1.0, 0.1, 0.7], [1.1, 0.08, 0.9, 0.2], [0.0, 0.3, 0.3, 0.0],
                    random_params(np.random.default_rng(3), 4)])


@pytest.fixture(scope="module")
def grid():
    V, F, uv = grid_mesh()
    return V, F, uv, 36  # an interior face of the 6 x 6 grid


def test_grid_magnified_and_minified(grid):
    V, F, uv, face = grid
    rng = np.random.default_rng(4)
    # 160 x 160 texels, 80 across the grid: ~4 px per texel at the identity.
    problem = loss.triangle_problem(V, F, uv, rng.random((160, 160)), face)
    e = assert_same_rebake(problem, PARAMS)
    assert e[0, 0] < 1e-8 and e[1:].max() > 1e-3
    np.testing.assert_allclose(e[:, 0], loss._evaluate_reference(problem, PARAMS), rtol=1e-7, atol=1e-12)
    # 512 x 512 texels seen on 48 px: fewer pixels than texels, rank-deficient normal matrix held by the ridge.
    small = loss.triangle_problem(V, F, uv, rng.random((512, 512)), face, screen_pixels=48)
    e = assert_same_rebake(small, PARAMS)
    np.testing.assert_allclose(e[:, 0], loss._evaluate_reference(small, PARAMS), rtol=1e-7, atol=1e-12)


def test_stack_of_three_planes(grid):
    V, F, uv, face = grid
    rng = np.random.default_rng(5)
    stack = loss.triangle_problem(V, F, uv, [rng.random((192, 192)) for _ in range(3)], face)
    planes = list(stack.planes)
    e = assert_same_rebake(planes[0], PARAMS, planes)
    assert e.shape == (len(PARAMS), 3)
    np.testing.assert_allclose(e, stack.evaluate_planes(PARAMS), rtol=1e-9, atol=1e-12)


def test_sliver():
    # A flat panel cut into 40 strips of two triangles (aspect ratio ~80); the view of a strip is the panel.
    strips = 40
    y = np.linspace(0, 1, strips + 1)
    V = np.array([[x, yk, 0.0] for yk in y for x in (0.0, 1.0)])
    F = np.array([f for k in range(strips) for f in ([2 * k, 2 * k + 1, 2 * k + 3], [2 * k, 2 * k + 3, 2 * k + 2])],
                 dtype=np.int64)
    texture = np.random.default_rng(6).random((256, 256))
    problem = loss.triangle_problem(V, F, V[F][:, :, :2] * 0.4 + 0.3, texture, 40)
    e = assert_same_rebake(problem, PARAMS)
    np.testing.assert_allclose(e[:, 0], loss._evaluate_reference(problem, PARAMS), rtol=1e-7, atol=1e-12)


def test_footprint_across_the_texture_edge_wraps(grid):
    # UVs from 0.75 to 1.25 and the face at UV (1, 1): its view crosses the right and top edges of the texture,
    # its texels wrap (REPEAT) while the solve sees one unwrapped texel box.
    V, F, _, _ = grid
    texture = np.random.default_rng(7).random((144, 160))
    uv = (0.75 + 0.5 * V[:, :2])[F]
    face = int(np.argmin(np.linalg.norm(uv.mean(axis=1) - 1.0, axis=1)))
    problem = loss.triangle_problem(V, F, uv, texture, face)
    h, w = texture.shape
    assert problem.points[:, 0].min() < w < problem.points[:, 0].max()
    assert problem.points[:, 1].min() < h < problem.points[:, 1].max()
    e = assert_same_rebake(problem, PARAMS)
    np.testing.assert_allclose(e[:, 0], loss._evaluate_reference(problem, PARAMS), rtol=1e-7, atol=1e-12)


def test_one_ring_across_a_uv_seam_has_disconnected_texels(grid):
    # The right half of the grid moved far away in the atlas: a sparse texel box (hash lookup) whose texels fall
    # in two components, so the dissection meets empty separators.
    V, F, uv, _ = grid
    split = uv.copy() * 0.2
    right = V[F][:, :, 0].mean(axis=1) > 0.5
    split[right] += [0.6, 0.55]
    face = int(np.flatnonzero(right & (np.abs(V[F][:, :, 0].mean(axis=1) - 0.58) < 0.05)
                              & (np.abs(V[F][:, :, 1].mean(axis=1) - 0.5) < 0.1))[0])
    problem = loss.triangle_problem(V, F, split, np.random.default_rng(8).random((1024, 1024)), face)
    assert (np.linalg.norm(problem.points - problem.centre, axis=1) > 300).any()
    e = assert_same_rebake(problem, PARAMS)
    np.testing.assert_allclose(e[:, 0], loss._evaluate_reference(problem, PARAMS), rtol=1e-7, atol=1e-12)
