import pathlib

import numpy as np
import pytest

from perceptual_uv.core.charts import signed_uv_areas, texel_areas, uv_topology
from perceptual_uv.core.mesh import read_obj

SPOT = pathlib.Path(__file__).resolve().parent / "data" / "spot" / "spot_triangulated.obj"


SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])
SQUARE_UV = np.array([[[0.0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])


def test_glued_square_is_one_chart_of_four_vertices():
    topo = uv_topology(SQUARE_F, SQUARE_UV)
    assert (topo.n_vertices, topo.n_charts) == (4, 1)
    np.testing.assert_array_equal(topo.corner_vertex, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(topo.vertex_position, [0, 1, 2, 3])
    assert topo.seam_edges.shape == (0, 2)
    # Edge 2 of face 0 (corner 2 -> 0) is the diagonal, glued to edge 0 of face 1.
    np.testing.assert_array_equal(topo.edge_glued, [[False, False, True], [True, False, False]])
    assert not topo.edge_seam.any()
    np.testing.assert_array_equal(topo.chart_orientation, [1])


def test_cut_diagonal_gives_two_charts_and_one_seam():
    uv = SQUARE_UV.copy()
    uv[1] += [2.0, 0.0]  # second triangle moved away: the diagonal (0, 2) becomes a seam
    topo = uv_topology(SQUARE_F, uv)
    assert (topo.n_vertices, topo.n_charts) == (6, 2)
    np.testing.assert_array_equal(topo.face_chart, [0, 1])
    np.testing.assert_array_equal(topo.seam_edges, [[0, 2]])
    np.testing.assert_array_equal(topo.edge_seam, [[False, False, True], [True, False, False]])
    np.testing.assert_array_equal(np.sort(topo.vertex_position), [0, 0, 1, 2, 2, 3])


def _fan():
    # Centre vertex 0 with ring 1..4 on the unit diamond; four triangles (0, i, i+1).
    ring = np.array([[1.0, 0], [0, 1], [-1, 0], [0, -1]])
    F = np.array([[0, 1 + i, 1 + (i + 1) % 4] for i in range(4)])
    uv = np.array([[[0.0, 0], ring[i], ring[(i + 1) % 4]] for i in range(4)])
    return F, uv


def test_slit_ending_at_a_vertex_keeps_the_tip_shared():
    F, uv = _fan()
    uv[3, 2] = [1.0, -0.2]  # ring vertex 1 seen from the last triangle: the spoke (0, 1) is cut
    topo = uv_topology(F, uv)
    # Vertex 1 splits in two; the centre stays one chart vertex because it is glued around the other side.
    assert (topo.n_vertices, topo.n_charts) == (6, 1)
    assert len(set(topo.corner_vertex[:, 0])) == 1
    np.testing.assert_array_equal(topo.seam_edges, [[0, 1]])


def test_corners_touching_only_at_a_vertex_are_separate():
    F = np.array([[0, 1, 2], [0, 3, 4]])
    uv = np.array([[[0.0, 0], [1, 0], [0, 1]], [[0.0, 0], [-1, 0], [0, -1]]])  # same UV at vertex 0
    topo = uv_topology(F, uv)
    assert (topo.n_vertices, topo.n_charts) == (6, 2)
    assert topo.corner_vertex[0, 0] != topo.corner_vertex[1, 0]


def test_non_manifold_edge_glues_all_agreeing_faces():
    F = np.array([[0, 1, 2], [1, 0, 3], [1, 0, 4]])
    uv = np.array([[[0.0, 0], [1, 0], [0.5, 1]], [[1.0, 0], [0, 0], [0.5, -1]], [[1.0, 0], [0, 0], [0.2, -1]]])
    topo = uv_topology(F, uv)
    assert (topo.n_vertices, topo.n_charts) == (5, 1)


def test_mirrored_chart_has_negative_orientation():
    uv = SQUARE_UV * [-1.0, 1.0]
    topo = uv_topology(SQUARE_F, uv)
    np.testing.assert_array_equal(topo.face_orientation, [-1, -1])
    np.testing.assert_array_equal(topo.chart_orientation, [-1])
    np.testing.assert_allclose(signed_uv_areas(uv), [-0.5, -0.5])


def test_corner_uv_rebuilds_input_and_moves_shared_vertices_together():
    topo = uv_topology(SQUARE_F, SQUARE_UV)
    np.testing.assert_array_equal(topo.corner_uv(), SQUARE_UV)
    moved = topo.vertex_uv + [[0, 0], [0, 0], [5, 5], [0, 0]]
    new = topo.corner_uv(moved)
    np.testing.assert_array_equal(new[0, 2], [6.0, 6.0])
    np.testing.assert_array_equal(new[1, 1], [6.0, 6.0])


@pytest.mark.parametrize(
    "F, uv, message",
    [
        (np.zeros((2, 4), dtype=int), np.zeros((2, 3, 2)), "shape"),
        (SQUARE_F, np.zeros((2, 3, 3)), "uv must have shape"),
        (SQUARE_F.astype(float), SQUARE_UV, "integer"),
        (-SQUARE_F - 1, SQUARE_UV, "negative"),
        (SQUARE_F, SQUARE_UV * np.nan, "NaN"),
        (np.zeros((0, 3), dtype=int), np.zeros((0, 3, 2)), "no faces"),
    ],
)
def test_bad_input_raises_value_error(F, uv, message):
    with pytest.raises(ValueError, match=message):
        uv_topology(F, uv)


def test_spot_has_the_documented_thirteen_charts():
    _, F, uv = read_obj(SPOT)
    topo = uv_topology(F, uv)
    assert topo.n_charts == 13  # /work/shared/models/README.md
    np.testing.assert_array_equal(topo.corner_uv(), uv)
    # Every chart vertex belongs to exactly one 3D vertex and one chart; vertices only split across seams.
    for c in range(topo.n_charts):
        faces = topo.chart_faces(c)
        assert np.all(topo.vertex_chart[topo.corner_vertex[faces]] == c)
    split = np.bincount(topo.vertex_position) > 1
    on_seam = np.zeros(split.size, dtype=bool)
    on_seam[topo.seam_edges.ravel()] = True
    assert np.all(on_seam[split])
    # Seam edges are exactly the 3D edges whose two faces disagree in UV at an endpoint.
    edges = {}
    for f in range(len(F)):
        for j in range(3):
            a, b = F[f, j], F[f, (j + 1) % 3]
            edges.setdefault((min(a, b), max(a, b)), []).append({F[f, j]: tuple(uv[f, j]),
                                                                 F[f, (j + 1) % 3]: tuple(uv[f, (j + 1) % 3])})
    expected = sorted(e for e, sides in edges.items() if len(sides) == 2 and sides[0] != sides[1])
    np.testing.assert_array_equal(topo.seam_edges, np.array(expected))


def test_texel_areas_count_texels_of_both_orientations():
    # Legs 0.5 and 0.25 of the unit square on a 64 x 32 texture: 0.5 * 0.5 * 0.25 * 64 * 32 = 128 texels,
    # whichever way the corners run.
    uv = np.array([[[0, 0], [0.5, 0], [0, 0.25]], [[0, 0], [0, 0.25], [0.5, 0]]])
    np.testing.assert_allclose(texel_areas(uv, 64, 32), [128, 128])
