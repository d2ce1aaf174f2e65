"""Pixels the re-bake matches exactly (core.rebake_peel): hand-made cells, a naive peeling as reference, and the
loss kernel's renders checked against the least-squares optimality condition on the dense operator."""
import numpy as np
import pytest

from perceptual_uv.core import loss
from perceptual_uv.core.deformation import jacobian
from perceptual_uv.core.gmsd import GMSD_C
from perceptual_uv.core.loss_stack import _deformed_ids, _evaluate_planes_kernel, _rebake_render_cells
from perceptual_uv.core.rebake_peel import PEEL_MIN_WEIGHT, _core_cells, _peel_cells

from meshes import grid_mesh  # tests/ is on sys.path under pytest

ALWAYS = 0  # peel_min_cells: peel whatever the view's size
NO_PEEL = 2 ** 62
DIRECT = np.inf  # dissection_cost: band or envelope Cholesky
MULTI = [-1.0, 0.5, 0.5, 0.5]  # weight row of a cell holding several pixels (only the first entry marks it)


def test_two_cells_each_with_texels_of_their_own_both_peel():
    # Cells side by side on the lattice: texels 1 and 3 are shared, 0 and 2 belong to the first, 4 and 5 to the
    # second: 2 pixels, 6 texels, every pixel matched exactly.
    keep, kept = _peel_cells(np.array([[0, 1, 2, 3], [1, 4, 3, 5]]), np.full((2, 4), 0.25), 6)
    assert kept == 0 and not keep.any()


def test_peeling_cascades_and_stops_at_a_cell_of_several_pixels():
    # A owns texel 0; B shares 1, 2, 3 with A and 4 with C; C shares 5, 6, 7 with D, a cell of several pixels.
    # Only A peels at first; without A, B owns 1, 2, 3; without B, C owns 4; D is never peeled.
    cell_tex = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [4, 5, 6, 7], [5, 6, 7, 8]])
    weight = np.array([[0.25] * 4, [0.25] * 4, [0.25] * 4, MULTI])
    keep, kept = _peel_cells(cell_tex, weight, 9)
    assert kept == 1 and keep.tolist() == [False, False, False, True]


def test_a_texel_read_with_a_tiny_weight_does_not_match_its_pixel():
    # The same cells, but B reads texels 1, 2, 3 with weights below PEEL_MIN_WEIGHT: once A is gone B owns them,
    # yet matching B through them would need texel values of 1 / weight; B stays, so C keeps sharing texel 4.
    cell_tex = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [4, 5, 6, 7], [5, 6, 7, 8]])
    small = PEEL_MIN_WEIGHT / 2
    weight = np.array([[0.25] * 4, [small, small, small, 1.0 - 3 * small], [0.25] * 4, MULTI])
    keep, kept = _peel_cells(cell_tex, weight, 9)
    assert kept == 3 and keep.tolist() == [False, True, True, True]


def naive_peel(cell_tex, weight, n_tex):
    """Remove any cell of one pixel that reads a texel no other remaining cell reads (weight at least
    PEEL_MIN_WEIGHT), one at a time, until none is left: quadratic, in cell order."""
    keep = np.ones(len(cell_tex), bool)
    changed = True
    while changed:
        changed = False
        for c in np.flatnonzero(keep):
            if weight[c, 0] < 0:
                continue
            readers = np.bincount(cell_tex[keep].ravel(), minlength=n_tex)
            if any(readers[t] == 1 and w >= PEEL_MIN_WEIGHT for t, w in zip(cell_tex[c], weight[c])):
                keep[c] = False
                changed = True
    return keep


@pytest.mark.parametrize("seed", range(5))
def test_the_core_does_not_depend_on_the_cells_order(seed):
    # Random cells on a 12 x 12 lattice (about half of its cells, a tenth of them holding several pixels): the
    # numba peeling, on the cells in two orders, keeps what the naive one keeps.
    rng = np.random.default_rng(seed)
    x, y = np.nonzero(rng.random((12, 12)) < 0.5)
    cell_tex = np.stack([(y + dy) * 13 + x + dx for dy in (0, 1) for dx in (0, 1)], axis=1).astype(np.int64)
    weight = rng.dirichlet(np.ones(4), size=len(x))
    weight[rng.random(len(x)) < 0.1] = MULTI
    expected = naive_peel(cell_tex, weight, 13 * 13)
    assert 0 < expected.sum() < len(x)  # some peel, some stay: the case is not trivial
    keep, kept = _peel_cells(cell_tex, weight, 13 * 13)
    assert keep.tolist() == expected.tolist() and kept == expected.sum()
    order = rng.permutation(len(x))
    keep, _ = _peel_cells(cell_tex[order], weight[order], 13 * 13)
    assert keep.tolist() == expected[order].tolist()


def dense_operator(problem, A):
    """The render operator ``B`` (pixels x texels) of the deformation ``A``, dense."""
    ids, weights, texel = _deformed_ids(problem.points, *A.ravel(), *problem.centre)
    B = np.zeros((len(ids), len(texel)))
    np.add.at(B, (np.repeat(np.arange(len(ids)), 4), ids.ravel()), weights.ravel())
    return B


def render(problem, A, peel_min_cells):
    out = np.empty((1, len(problem.points)))
    assert _rebake_render_cells(problem.points, problem.reference[None], problem.box, *A.ravel(), *problem.centre,
                                problem.ridge, out, DIRECT, peel_min_cells)
    return out[0]


@pytest.fixture(scope="module")
def minified():
    """A 512 x 512 random texture seen on a 32 px view: 2-3 texels per pixel across (fewer pixels than texels)."""
    V, F, uv = grid_mesh()
    return loss.triangle_problem(V, F, uv, np.random.default_rng(4).random((512, 512)), 36, screen_pixels=32)


@pytest.mark.parametrize("lam", [1.0, 0.8])
def test_a_view_whose_pixels_all_own_texels_renders_its_reference_exactly(minified, lam):
    A = np.matmul(*jacobian(np.array([0.3, lam, lam, 0.2])))
    B = dense_operator(minified, A)
    # Independent check that every pixel can be matched: the dense least squares reproduces the reference.
    x = np.linalg.lstsq(B, minified.reference, rcond=None)[0]
    assert np.abs(B @ x - minified.reference).max() < 1e-10
    np.testing.assert_array_equal(render(minified, A, ALWAYS), minified.reference)
    e = _evaluate_planes_kernel(np.array([[0.3, lam, lam, 0.2]]), minified.points, minified.pooled_index,
                                minified.box, minified.reference[None], minified.reference_gradient[None],
                                minified.centre, minified.ridge, GMSD_C, True, DIRECT, ALWAYS)
    assert e[0, 0] == 0.0
    # Solved without peeling, the ridge leaves the render within 1e-6 of a pixel value of it.
    assert np.abs(render(minified, A, NO_PEEL) - minified.reference).max() < 1e-6


@pytest.mark.parametrize("texture_side, screen, lam", [(512, 64, 1.0), (512, 48, 0.8), (512, 48, 0.6),
                                                        (256, 32, 1.0), (256, 32, 0.8)])
def test_a_partly_peeled_render_is_a_least_squares_optimum(texture_side, screen, lam):
    # Some pixels peel, the rest are solved: the render r = B x must satisfy the optimality condition of the
    # re-bake, B^T (r - target) = -ridge x ~ 0 (relative to B^T target), as the render without peeling does.
    V, F, uv = grid_mesh()
    problem = loss.triangle_problem(V, F, uv, np.random.default_rng(4).random((texture_side, texture_side)), 36,
                                    screen_pixels=screen)
    A = np.matmul(*jacobian(np.array([0.3, lam, lam, 0.2])))
    B = dense_operator(problem, A)
    scale = np.abs(B.T @ problem.reference).max()
    peeled = render(problem, A, ALWAYS)
    exact = peeled == problem.reference
    assert 0 < exact.sum() < len(exact)
    for r in (peeled, render(problem, A, NO_PEEL)):
        assert np.abs(B.T @ (r - problem.reference)).max() < 1e-5 * scale


def test_the_core_keeps_its_cells_and_texels_in_order():
    # Cells 1 and 3 stay; of texels 0-9 they read 2, 3, 5, 6, 7, 9, which become 0-5 in that order; pixels of the
    # peeled cells 0 and 2 point nowhere.
    cell_tex = np.array([[0, 1, 2, 3], [2, 3, 5, 6], [1, 4, 8, 0], [6, 7, 9, 5]])
    acc = np.arange(4 * 11, dtype=float).reshape(4, 11)
    pix_cell = np.array([0, 1, 1, 2, 3, 3, 3])
    core_tex, core_acc, core_pos, n_core = _core_cells(np.array([False, True, False, True]), 2, cell_tex, acc,
                                                       np.array([10, 11, 12, 13]), 10, pix_cell)
    assert n_core == 6
    assert core_tex.tolist() == [[0, 1, 2, 3], [3, 4, 5, 2]]
    np.testing.assert_array_equal(core_acc, acc[[1, 3]])
    assert core_pos.tolist() == [11, 13]
    assert pix_cell.tolist() == [-1, 0, 0, -1, 1, 1, 1]
