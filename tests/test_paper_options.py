"""The paper as written, as keyword options: App. A's one-ring views (``view_faces="one_ring"``) next to the
project's window faces (the default), and the default path unchanged."""
import numpy as np
import pytest

from perceptual_uv.core import loss
from perceptual_uv.core import loss_passes as lp
from perceptual_uv.core import trianglewise as tw
from perceptual_uv.core.camera import MAX_SCREEN_PIXELS, triangle_cameras
from perceptual_uv.core.one_ring import one_ring_faces, window_faces
from perceptual_uv.core.progress import run_generator
from perceptual_uv.core.raster import rasterize

# Row heights of a flat grid three unit-wide cells across: square rows (well-shaped triangles, whose box is
# about their cell) around a band of 0.05-high rows (1:20 slivers, whose view draws a band of BOX_MARGIN = 1/8
# of the cell's width above and below them, i.e. into rows that share no vertex with them).
ROW_HEIGHTS = (1.0, 1.0, 0.05, 0.05, 0.05, 0.05, 0.05, 1.0, 1.0)
COLUMNS = 3


def banded_mesh():
    """Flat (z = 0) grid, cell ``(row, column)`` split into faces ``2 (row * COLUMNS + column) + {0, 1}``.

    Returns
    -------
    V : (n, 3) ndarray
    F : (m, 3) ndarray of int64
    uv : (m, 3, 2) ndarray
        An axis-aligned affine image of the positions inside ``[0.05, 0.95]^2``.
    """
    x = np.arange(COLUMNS + 1, dtype=np.float64)
    y = np.concatenate([[0.0], np.cumsum(ROW_HEIGHTS)])
    X, Y = np.meshgrid(x, y)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    F = []
    for i in range(len(ROW_HEIGHTS)):
        for j in range(COLUMNS):
            a = i * (COLUMNS + 1) + j
            F += [[a, a + 1, a + COLUMNS + 2], [a, a + COLUMNS + 2, a + COLUMNS + 1]]
    F = np.array(F, dtype=np.int64)
    uv = (0.05 + 0.9 * V[:, :2] / V[:, :2].max(axis=0))[F]
    return V, F, uv


def cell_faces(row, column):
    first = 2 * (row * COLUMNS + column)
    return first, first + 1


SLIVER = cell_faces(4, 1)[0]  # middle of the sliver band
OUTSIDE = cell_faces(6, 1)[0]  # two rows above: no shared vertex, but inside SLIVER's box
SQUARE = cell_faces(0, 1)[0]  # well-shaped: its box is about its own cell, its one-ring covers it


@pytest.fixture(scope="module")
def mesh():
    V, F, uv = banded_mesh()
    texture = np.random.default_rng(3).random((64, 64))
    return V, F, uv, texture


def _ring(F, V, face):
    offsets, neighbours = one_ring_faces(F, V=V)
    return set(neighbours[offsets[face]:offsets[face + 1]].tolist())


def _covering(V, F, face, draw, window="box"):
    """Faces that cover at least one pixel centre of ``face``'s 64 px view when ``draw`` is drawn."""
    raster = rasterize(V, F, draw, triangle_cameras(V, F, [face], screen_pixels=64, window=window))
    return set(np.unique(raster.face).tolist()), raster


def _window_draw(V, F, face):
    camera = triangle_cameras(V, F, [face], screen_pixels=64)
    return window_faces(V, F, one_ring_faces(F, V=V), face, origin=camera.origin[0], right=camera.right[0],
                        up=camera.up[0], normal=camera.normal[0], bounds=camera.bounds[0])


def test_the_mesh_has_a_face_outside_the_one_ring_inside_the_window(mesh):
    V, F, uv, _ = mesh
    assert OUTSIDE not in _ring(F, V, SLIVER)
    drawn = _window_draw(V, F, SLIVER)
    assert OUTSIDE in drawn.tolist()
    covering, _ = _covering(V, F, SLIVER, drawn)
    assert OUTSIDE in covering


def test_one_ring_option_draws_exactly_the_triangle_and_its_one_ring(mesh):
    V, F, uv, texture = mesh
    ring = _ring(F, V, SLIVER)
    # The paper's view is App. A's whole square, turned towards the first corner.
    ring_covering, ring_raster = _covering(V, F, SLIVER, sorted(ring), window="square")
    window_covering, window_raster = _covering(V, F, SLIVER, _window_draw(V, F, SLIVER))
    assert ring_covering <= ring and SLIVER in ring_covering
    assert window_covering - ring  # the window adds faces that cover pixels, OUTSIDE among them

    # The loss problem draws exactly those faces: its pixels are the one-ring's raster, and its texel points
    # are the raster's surface points in texels.
    paper = loss.triangle_problem(V, F, uv, texture, SLIVER, view_faces="one_ring")
    ours = loss.triangle_problem(V, F, uv, texture, SLIVER, view_faces="window")
    np.testing.assert_array_equal(np.sort(paper.pixel), np.sort(ring_raster.pixel))
    np.testing.assert_array_equal(np.sort(ours.pixel), np.sort(window_raster.pixel))
    assert len(paper.pixel) < len(ours.pixel)
    h, w = texture.shape
    order = np.argsort(ring_raster.pixel)
    expected = np.einsum("pk,pkd->pd", ring_raster.bary, uv[ring_raster.face]) * [w, h]
    np.testing.assert_allclose(paper.points[np.argsort(paper.pixel)], expected[order], rtol=0, atol=1e-9)

    # The reference render agrees: OUTSIDE's pixels are covered with the window and not with the one-ring (in
    # App. A's square, where the window faces would cover them too).
    outside_pixels = window_raster.pixel[window_raster.face == OUTSIDE]
    _, square_window_raster = _covering(V, F, SLIVER, _window_draw(V, F, SLIVER), window="square")
    outside_in_square = square_window_raster.pixel[square_window_raster.face == OUTSIDE]
    assert len(outside_pixels) and len(outside_in_square)
    _, ring_mask, _ = loss.render_reference(V, F, uv, texture, SLIVER, view_faces="one_ring")
    _, window_mask, _ = loss.render_reference(V, F, uv, texture, SLIVER)
    assert window_mask.reshape(-1)[outside_pixels].all()
    assert not ring_mask.reshape(-1)[outside_in_square].any()
    np.testing.assert_array_equal(np.flatnonzero(ring_mask), np.sort(ring_raster.pixel))


def test_well_shaped_triangle_one_ring_fills_app_a_square(mesh):
    V, F, uv, texture = mesh
    paper = loss.triangle_problem(V, F, uv, texture, SQUARE, view_faces="one_ring")
    ours = loss.triangle_problem(V, F, uv, texture, SQUARE)
    # The paper's view is App. A's square turned towards the first corner; for a well-shaped triangle the faces
    # reaching into it are its one-ring: the window faces would draw the same pixels there.
    _, square_window_raster = _covering(V, F, SQUARE, _window_draw(V, F, SQUARE), window="square")
    np.testing.assert_array_equal(np.sort(paper.pixel), np.sort(square_window_raster.pixel))
    # Ours draws the box. The drawn box of a right isosceles triangle with legs 1 is its hypotenuse sqrt(2)
    # (64 px) by half of it and an eighth above and below (48 px, area 1.5). Along the hypotenuse from its
    # bottom-left end (s) and across it towards the right angle (t, from -sqrt(2)/8 to 5 sqrt(2)/8), the mesh's
    # bottom edge y = 0 is t = s: the box below it, t > s, is a right triangle of legs 5 sqrt(2)/8, area 25/64,
    # off the mesh. On the mesh: (1 - (25/64) / 1.5) * 64 * 48 = 2272 pixels.
    assert abs(len(ours.pixel) - 2272) < 64


def test_default_is_the_window_path_bit_for_bit(mesh):
    V, F, uv, texture = mesh
    default = loss.prepare_triangles(V, F, uv, texture)
    explicit = loss.prepare_triangles(V, F, uv, texture, view_faces="window")
    for name in ("faces", "offsets", "centre", "pixel", "points", "reference", "reference_gradient", "uv_area",
                 "is_constant", "pooled_index", "box"):
        np.testing.assert_array_equal(getattr(default, name), getattr(explicit, name), err_msg=name)
    # ... and it still draws window_faces: every problem's pixels are that set's raster.
    for face in (SLIVER, SQUARE, OUTSIDE):
        _, raster = _covering(V, F, face, _window_draw(V, F, face))
        np.testing.assert_array_equal(np.sort(default[face].pixel), np.sort(raster.pixel))
    image, mask, _ = loss.render_reference(V, F, uv, texture, SLIVER)
    image_explicit, mask_explicit, _ = loss.render_reference(V, F, uv, texture, SLIVER, view_faces="window")
    np.testing.assert_array_equal(image, image_explicit)
    np.testing.assert_array_equal(mask, mask_explicit)


def test_unknown_view_faces_is_rejected(mesh):
    V, F, uv, texture = mesh
    with pytest.raises(ValueError, match="view_faces"):
        loss.prepare_triangles(V, F, uv, texture, [SLIVER], view_faces="whole_mesh")
    with pytest.raises(ValueError, match="view_faces"):
        tw.optimize_triangles(V, F, uv, texture, faces=[SLIVER], workers=1, view_faces="ring")
    with pytest.raises(ValueError, match="view_faces"):
        lp.losses_of(V, F, uv, texture, np.array([[0.0, 1.0, 1.0, 0.0]]), faces=[SLIVER], view_faces=None)


def test_fixed_64_pixel_views():
    # App. A's fixed 64 px view: max_screen_pixels = screen_pixels = 64 gives 64 px whatever the texel count.
    V, F, uv = banded_mesh()
    big = np.zeros((2048, 2048))
    state = run_generator(lp._iter_state(V, F, uv, big, np.arange(len(F)), 64, 64, {}, "one_ring"))
    assert np.all(state["view_pixels"] == 64)
    assert state["view_faces"] == "one_ring"
    grown = run_generator(lp._iter_state(V, F, uv, big, np.arange(len(F)), 64, MAX_SCREEN_PIXELS, {}))
    assert grown["view_pixels"].max() > 64 and grown["view_faces"] == "window"


def test_optimize_and_losses_take_the_paper_view_option(mesh):
    V, F, uv, texture = mesh
    faces = [SLIVER, cell_faces(3, 0)[1], cell_faces(5, 2)[0], SQUARE, cell_faces(8, 2)[1], cell_faces(1, 1)[1]]
    common = dict(evaluations=20, screen_pixels=64, max_screen_pixels=64, workers=1, seed=5, faces=faces,
                  formulation="barrier")
    ours = tw.optimize_triangles(V, F, uv, texture, **common)
    paper = tw.optimize_triangles(V, F, uv, texture, view_faces="one_ring", **common)
    default = tw.optimize_triangles(V, F, uv, texture, view_faces="window", **common)
    for name in ("params", "loss", "w_R", "w_S", "evaluations"):
        np.testing.assert_array_equal(getattr(ours, name), getattr(default, name), err_msg=name)
    assert paper.formulation == "barrier" and np.all(np.isfinite(paper.loss)) and paper.feasible.all()
    # Each search ran on its own view: E at each optimum is that view's problem's E there.
    for result, view_faces in ((paper, "one_ring"), (ours, "window")):
        for row, face in enumerate(faces):
            problem = loss.triangle_problem(V, F, uv, texture, face, view_faces=view_faces)
            assert result.loss[row] == pytest.approx(problem.evaluate(result.params[row])[0], rel=1e-9, abs=1e-15)

    # The losses of given deformations take the option the same way.
    params = np.tile([0.2, 0.6, 0.8, 0.1], (len(faces), 1))
    e_ours = lp.losses_of(V, F, uv, texture, params, faces=faces, max_screen_pixels=64)
    e_paper = lp.losses_of(V, F, uv, texture, params, faces=faces, max_screen_pixels=64, view_faces="one_ring")
    for row, face in enumerate(faces):
        for e, view_faces in ((e_paper, "one_ring"), (e_ours, "window")):
            problem = loss.triangle_problem(V, F, uv, texture, face, view_faces=view_faces)
            assert e[row] == pytest.approx(problem.evaluate(params[row])[0], rel=1e-9, abs=1e-15)
    assert e_paper[0] != e_ours[0]  # the sliver: other faces, another window
    new_uv = uv.copy()
    e_at = lp.losses_at(V, F, uv, texture, new_uv, faces=faces, max_screen_pixels=64, view_faces="one_ring")
    assert np.all(e_at < 1e-9)  # the input itself: E at the identity
