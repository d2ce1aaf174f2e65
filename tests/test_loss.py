"""The triangle-wise loss E (Sec. 4.1.1): identity, symmetry, constant detection, kernels vs numpy."""
import dataclasses
import pathlib
import pickle

import numpy as np
import pytest

from perceptual_uv.core import loss
from perceptual_uv.core.gmsd import luma
from perceptual_uv.core.mesh import read_obj
from perceptual_uv.core.one_ring import one_ring_faces
from perceptual_uv.core.raster import rasterize
from perceptual_uv.core.camera import BOX_MARGIN, triangle_cameras

SHARED = pathlib.Path(__file__).resolve().parents[1].parent / "shared"
IDENTITY = [0.0, 1.0, 1.0, 0.0]


def grid_mesh(cells=6, uv_scale=0.5, uv_offset=(0.2, 0.3)):
    """A flat (z = 0) grid of the unit square, UVs an affine image of the positions."""
    n = cells + 1
    y, x = np.mgrid[0:n, 0:n] / cells
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    quads = [(i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(cells)
             for j in range(cells)]
    F = np.array([[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads], dtype=np.int64)
    uv = V[F][:, :, :2] * uv_scale + np.asarray(uv_offset)
    return V, F, uv


def random_params(rng, k):
    lo = np.array([0.0, 0.1, 0.1, 0.0])
    hi = np.array([np.pi / 2, 1.0, 1.0, np.pi / 2])
    return lo + (hi - lo) * rng.random((k, 4))


@pytest.fixture(scope="module")
def textured():
    V, F, uv = grid_mesh()
    rng = np.random.default_rng(0)
    texture = rng.random((40, 56, 3))  # non-square: h = 40, w = 56; a triangle covers ~ 4 x 5 texels
    centre_face = 14  # interior: its one-ring is complete
    return V, F, uv, texture, centre_face


def test_identity_reproduces_the_reference(textured):
    V, F, uv, texture, face = textured
    problem = loss.triangle_problem(V, F, uv, texture, face)
    assert not problem.is_constant
    # An interior right isosceles triangle of a flat grid fills its drawn box: the hypotenuse (64 px) by half of it
    # (32 px) and a band of an eighth of it (8 px) above and below: 64 x 48 px.
    assert len(problem.pixel) == 64 * 48
    # Magnified (~10 px per texel): every texel read is determined, the re-bake returns the input texels.
    assert problem.evaluate(IDENTITY)[0] < 1e-9
    # A real shrink loses detail.
    assert problem.evaluate([0.0, 0.3, 0.3, 0.0])[0] > 1e-2


def test_ninety_degree_rotation_symmetry(textured):
    V, F, uv, texture, face = textured
    problem = loss.triangle_problem(V, F, uv, texture, face)
    params = random_params(np.random.default_rng(1), 6)
    rotated = params + [np.pi / 2, 0, 0, 0]
    e, e_rot = problem.evaluate(params), problem.evaluate(rotated)
    assert e.min() > 1e-4
    np.testing.assert_allclose(e_rot, e, rtol=1e-9, atol=1e-13)
    # S(lambda1, lambda2, beta + pi/2) = S(lambda2, lambda1, beta): the same deformation, the same E.
    swapped = params[:, [0, 2, 1, 3]] + [0, 0, 0, np.pi / 2]
    np.testing.assert_allclose(problem.evaluate(swapped), e, rtol=1e-9, atol=1e-13)


def test_fused_kernel_matches_numpy_reference(textured):
    V, F, uv, texture, face = textured
    problem = loss.triangle_problem(V, F, uv, texture, face)
    params = np.vstack([IDENTITY, random_params(np.random.default_rng(2), 5), [0.3, 0.05, 1.0, 1.2]])
    np.testing.assert_allclose(problem.evaluate(params), loss._evaluate_reference(problem, params),
                               rtol=1e-7, atol=1e-12)


def test_integer_uv_shift_changes_nothing(textured):
    # REPEAT wrapping: moving all UVs by whole texture periods reads the same texels.
    V, F, uv, texture, face = textured
    params = random_params(np.random.default_rng(3), 4)
    e = loss.triangle_problem(V, F, uv, texture, face).evaluate(params)
    shifted = loss.triangle_problem(V, F, uv + [1.0, -2.0], texture, face).evaluate(params)
    np.testing.assert_allclose(shifted, e, rtol=1e-7, atol=1e-12)


def test_uv_area_and_centre_by_hand():
    V, F, _ = grid_mesh(cells=1)
    uv = np.array([[[0.1, 0.2], [0.5, 0.2], [0.1, 0.7]], [[0.5, 0.2], [0.5, 0.7], [0.1, 0.7]]])
    problem = loss.triangle_problem(V, F, uv, np.random.default_rng(0).random((32, 48)), 0, screen_pixels=16)
    assert problem.uv_area == pytest.approx(0.5 * 0.4 * 0.5 * 32 * 48)
    # UV barycentre (0.2333, 0.3667) -> texel units (11.2, 11.73) -> nearest texel centre (11.5, 11.5).
    np.testing.assert_allclose(problem.centre, [11.5, 11.5])
    assert problem.texture_shape == (32, 48) and problem.screen_pixels == 16


def test_constant_detection_is_exact():
    V, F, uv = grid_mesh(uv_scale=0.25, uv_offset=(0.1, 0.1))  # UVs in [0.1, 0.35]^2 of a 64 x 64 texture
    face = 14
    texture = np.full((64, 64), 0.5)
    texture[60, 60] = 0.9  # far outside every disk the one-ring can reach
    problem = loss.triangle_problem(V, F, uv, texture, face)
    assert problem.is_constant
    params = random_params(np.random.default_rng(4), 5)
    np.testing.assert_array_equal(problem.evaluate(params), 0.0)
    # The numeric path agrees that nothing changes up to the ridge of the re-bake: what is left vanishes with the
    # ridge, about as its square (texels that only the drawn box's edge pixels read are held by the ridge).
    numeric = dataclasses.replace(problem, is_constant=False).evaluate(params)
    tenth = dataclasses.replace(problem, is_constant=False, ridge=problem.ridge / 10).evaluate(params)
    assert numeric.max() < 1e-10 and tenth.max() < numeric.max() / 50
    # One texel near the triangle that a shrink cannot reproduce: not constant, and E > 0 somewhere.
    cx, cy = (problem.centre - 0.5).astype(int)
    texture[cy + 1, cx] = 0.1
    problem = loss.triangle_problem(V, F, uv, texture, face)
    assert not problem.is_constant
    assert problem.evaluate([0.0, 0.2, 0.2, 0.0])[0] > 1e-3


def test_degenerate_triangle_is_constant():
    V, F, uv = grid_mesh(cells=1)
    V = V.copy()
    V[:, 1] = 0.0  # every triangle collapses onto a line
    problem = loss.triangle_problem(V, F, uv, np.random.default_rng(0).random((8, 8)), 0)
    assert problem.is_constant and len(problem.pixel) == 0
    np.testing.assert_array_equal(problem.evaluate([IDENTITY, [0.1, 0.5, 0.5, 0.1]]), 0.0)


def test_batch_matches_single_problems_and_pickles(textured):
    V, F, uv, texture, _ = textured
    adjacency = one_ring_faces(F, V=V)
    faces = [14, 3, 40]
    batch = loss.prepare_triangles(V, F, uv, texture, faces, adjacency=adjacency)
    assert len(batch) == 3 and list(batch.faces) == faces
    params = random_params(np.random.default_rng(5), 3)
    for i, face in enumerate(faces):
        single = loss.triangle_problem(V, F, uv, texture, face)
        np.testing.assert_array_equal(batch.evaluate(i, params), single.evaluate(params))
        assert batch.uv_area[i] == single.uv_area and batch.is_constant[i] == single.is_constant
    clone = pickle.loads(pickle.dumps(batch[1]))
    np.testing.assert_array_equal(clone.evaluate(params), batch[1].evaluate(params))
    assert len(pickle.dumps(batch[1])) < 200_000


def test_render_reference_is_the_problem_reference_in_luma(textured):
    V, F, uv, texture, face = textured
    image, mask, camera = loss.render_reference(V, F, uv, texture, face)
    # The drawn box (64 x 48 px, see test_identity_reproduces_the_reference) is centred in the square screen:
    # rows 8-55, every pixel of it covered, none outside.
    assert image.shape == (64, 64, 3) and len(camera) == 1
    assert mask[8:56].all() and not mask[:8].any() and not mask[56:].any()
    problem = loss.triangle_problem(V, F, uv, texture, face)
    np.testing.assert_allclose(luma(image), problem.reference_image(), atol=1e-14)


def test_render_reference_row_zero_is_the_bottom():
    # Triangle a = (0, 0, 0), b = (4, 0, 0), c = (1, 2, 0): camera right = +x, up = +y (test_camera).
    V = np.array([[0.0, 0, 0], [4, 0, 0], [1, 2, 0]])
    F = np.array([[0, 1, 2]])
    uv = ((V[F][:, :, :2] + 0.5) / 5.0)  # UV = affine in (x, y), inside [0, 1]
    rows = np.arange(64, dtype=np.float64)
    texture = np.repeat((rows / 63)[:, None], 64, axis=1)  # luma grows with the texture row (with v)
    image, mask, _ = loss.render_reference(V, F, uv, texture, 0)
    column = image[:, 16][mask[:, 16]]
    assert len(column) > 10 and np.all(np.diff(column) > 0)  # grows with the image row: row 0 at the bottom


def test_validation(textured):
    V, F, uv, texture, face = textured
    with pytest.raises(ValueError, match="uv"):
        loss.prepare_triangles(V, F, uv[:, :2], texture)
    with pytest.raises(ValueError, match="screen_pixels"):
        loss.prepare_triangles(V, F, uv, texture, [face], screen_pixels=63)
    with pytest.raises(ValueError, match="faces"):
        loss.prepare_triangles(V, F, uv, texture, [len(F)])
    problem = loss.triangle_problem(V, F, uv, texture, face, screen_pixels=16)
    with pytest.raises(ValueError, match="params"):
        problem.evaluate([[0.0, 1.0, 1.0]])
    with pytest.raises(ValueError, match="finite"):
        problem.evaluate([[0.0, np.nan, 1.0, 0.0]])


@pytest.mark.skipif(not (SHARED / "models" / "spot").is_dir(), reason="../shared/models/spot is absent")
def test_spot_identity_and_kernel_agreement():
    from skimage.io import imread

    spot = SHARED / "models" / "spot"
    V, F, uv = read_obj(spot / "spot_triangulated.obj")
    texture = np.ascontiguousarray(imread(spot / "spot_texture.png")[::-1, :, :3] / 255.0)
    faces = np.random.default_rng(6).choice(len(F), 12, replace=False)
    batch = loss.prepare_triangles(V, F, uv, texture, faces)
    work = [i for i in range(len(batch)) if not batch.is_constant[i]]
    assert 0 < len(work) < len(batch)  # spot has both kinds
    params = np.vstack([IDENTITY, random_params(np.random.default_rng(7), 3)])
    for i in work[:3]:
        e = batch.evaluate(i, params)
        assert e[0] < 1e-8
        np.testing.assert_allclose(e, loss._evaluate_reference(batch[i], params), rtol=1e-7, atol=1e-12)


def test_cell_path_and_pixel_path_agree(textured):
    # The fused kernel pools pixels by texel cell; the general path assembles per pixel. Same numbers.
    V, F, uv, texture, face = textured
    problem = loss.triangle_problem(V, F, uv, texture, face)
    params = np.vstack([IDENTITY, random_params(np.random.default_rng(8), 6)])
    args = (params, problem.points, problem.pooled_index, problem.box, problem.reference,
            problem.reference_gradient, problem.centre, problem.ridge, loss.GMSD_C)
    np.testing.assert_allclose(loss._evaluate_kernel(*args, True), loss._evaluate_kernel(*args, False),
                               rtol=1e-7, atol=1e-12)


def test_a_footprint_wider_than_the_texture_gets_texels_of_its_own(textured):
    # UVs 12 times the grid's: the view's points span ~21 x 17 texels of a 12 x 10 texture, more than one
    # period each way. The re-bake numbers texels by position without REPEAT wrapping, so E is the same as on
    # that texture tiled 8 x 8 (96 x 80) with UVs 8 times smaller: the same texel-space points, which stay
    # within one period there under every deformation of the box (at most the 27-texel diagonal across).
    # With wrapping, the 12 x 10 texture would make pixels a period apart share texels. Both must also
    # match the numpy reference.
    V, F, uv, _, face = textured
    texture = np.random.default_rng(9).random((10, 12))
    params = np.vstack([IDENTITY, random_params(np.random.default_rng(10), 5), [np.pi / 4, 1.0, 1.0, 0.0]])
    small = loss.triangle_problem(V, F, uv * 12.0, texture, face, screen_pixels=32)
    tiled = loss.triangle_problem(V, F, uv * 1.5, np.tile(texture, (8, 8)), face, screen_pixels=32)
    np.testing.assert_array_equal(small.points, tiled.points)
    np.testing.assert_array_equal(small.reference, tiled.reference)
    assert np.all(np.ptp(small.points, axis=0) > [12, 10])
    e = small.evaluate(params)
    np.testing.assert_allclose(e, tiled.evaluate(params), rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(e, loss._evaluate_reference(small, params), rtol=1e-7, atol=1e-12)


def _face_reaching_across_the_seam(V, F):
    """A face of the grid's column right of x = 0.5 whose box reaches across it: the faces ``(a, c, d)`` of a
    cell have their right angle at the top-left corner, so their box (on that side of the diagonal) reaches
    half a cell to the left; their barycentre is a third of a cell right of the seam."""
    centre = V[F].mean(axis=1)
    return int(np.flatnonzero((np.abs(centre[:, 0] - (0.5 + 1 / 18)) < 0.01) & (np.abs(centre[:, 1] - 0.5) < 0.1))[0])


def test_one_ring_across_a_uv_seam(textured):
    # Right half of the grid moved to a distant part of the atlas: the one-ring of a face at the seam reads two
    # islands far apart (sparse texel box: hash lookup, component ordering). Must match the numpy reference.
    V, F, uv, _, _ = textured
    texture = np.random.default_rng(11).random((1024, 1024))
    split = uv.copy() * 0.2
    right = V[F][:, :, 0].mean(axis=1) > 0.5
    split[right] += [0.6, 0.55]
    face = _face_reaching_across_the_seam(V, F)
    problem = loss.triangle_problem(V, F, split, texture, face)
    centre = problem.centre
    far = np.linalg.norm(problem.points - centre, axis=1) > 300
    assert far.any() and (~far).any()  # both islands are on screen
    params = np.vstack([IDENTITY, random_params(np.random.default_rng(12), 4)])
    e = problem.evaluate(params)
    assert e[0] < 1e-8
    np.testing.assert_allclose(e, loss._evaluate_reference(problem, params), rtol=1e-7, atol=1e-12)


def test_a_turned_view_across_the_atlas_takes_the_points_box(textured):
    # Two islands at opposite corners of a 128 x 128 atlas, on its diagonal: the drawn points' box is ~100 x 100
    # texels. Shrinking the diagonal by 4 and turning by 45 degrees maps the deformed corners of that box across
    # ~141 texels while the points themselves stay within ~35: the cell path's grid comes from the points' own
    # box, and the result agrees with the numpy reference.
    from perceptual_uv.core.deformation import jacobian
    from perceptual_uv.core.loss_stack import _rebake_render_cells

    V, F, uv, _, _ = textured
    texture = np.random.default_rng(11).random((128, 128))
    split = uv * 0.2
    right = V[F][:, :, 0].mean(axis=1) > 0.5
    split[right] += [0.75, 0.75]
    face = _face_reaching_across_the_seam(V, F)
    problem = loss.triangle_problem(V, F, split, texture, face)
    row = [np.pi / 4, 0.25, 1.0, np.pi / 4]
    R, S = jacobian(row)
    A = R @ S
    box = problem.box
    corners = np.array([[box[k & 1], box[2 + (k >> 1)]] for k in range(4)]) @ A.T
    assert np.ptp(corners[:, 0]) > 128 and np.ptp(problem.points @ A.T, axis=0).max() < 40
    rendered = np.empty((1, len(problem.points)))
    assert _rebake_render_cells(problem.points, problem.reference[None], box, *A.ravel(), *problem.centre,
                                problem.ridge, rendered)
    params = np.vstack([row, [np.pi / 4, 0.5, 1.0, np.pi / 4], IDENTITY])
    np.testing.assert_allclose(problem.evaluate(params), loss._evaluate_reference(problem, params),
                               rtol=1e-7, atol=1e-12)


def test_a_sliver_sees_the_panel_around_it():
    # A flat unit panel cut into 40 horizontal strips of two triangles each (aspect ratio ~40), with 64 x 64
    # noise mapped one to one.
    strips = 40
    y = np.linspace(0, 1, strips + 1)
    V = np.array([[x, yk, 0.0] for yk in y for x in (0.0, 1.0)])
    F = np.array([f for k in range(strips) for f in ([2 * k, 2 * k + 1, 2 * k + 3], [2 * k, 2 * k + 3, 2 * k + 2])],
                 dtype=np.int64)
    uv = V[F][:, :, :2]
    texture = np.random.default_rng(13).random((64, 64))
    face = 40  # strip 20; its window is the whole panel
    problem = loss.triangle_problem(V, F, uv, texture, face)
    offsets, neighbours = one_ring_faces(F, V=V)
    ring = rasterize(V, F, neighbours[offsets[face]:offsets[face + 1]],
                     triangle_cameras(V, F, [face], screen_pixels=problem.screen_pixels))
    # The strip's longest edge is its diagonal (about 1 long, 64 px), so its own box is 0.025 high (1.6 px); the
    # view draws it with a band of BOX_MARGIN = 1/8 of the panel (8 px) above and below: 17.6 px, 17 or 18 rows
    # of pixel centres, all on the panel. The one-ring is strips 19 and 20 and one triangle of strip 21 (the
    # other shares no vertex with face 40): 2.5 strips of 1.6 px of the 17.6.
    assert len(problem.pixel) in (64 * 17, 64 * 18)
    assert len(ring.pixel) / len(problem.pixel) == pytest.approx(2.5 * 1.6 / 17.6, abs=0.03)
    # Noise at half the texels per side loses most of its detail: far above epsilon = 0.01.
    assert problem.evaluate([0.0, 0.5, 0.5, 0.0])[0] > 0.05
