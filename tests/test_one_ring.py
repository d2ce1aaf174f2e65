"""One-ring neighbourhoods (triangles sharing a vertex), with vertices welded by position."""
import numpy as np
import pytest

from perceptual_uv.core.one_ring import one_ring_faces, weld_vertices, window_faces


def test_one_ring_by_hand():
    # 0: (0,1,2); 1: (1,3,2) shares an edge with 0; 2: (3,4,5) shares vertex 3 with 1 only; 3: (6,7,8) alone.
    F = np.array([[0, 1, 2], [1, 3, 2], [3, 4, 5], [6, 7, 8]])
    offsets, neighbours = one_ring_faces(F)
    ring = [list(neighbours[offsets[f]:offsets[f + 1]]) for f in range(len(F))]
    assert ring == [[0, 1], [0, 1, 2], [1, 2], [3]]


def test_welding_joins_a_seam():
    # Two triangles whose shared edge has duplicated vertices (a UV seam in a glTF/OBJ file).
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    F = np.array([[0, 1, 2], [3, 5, 4]])
    ids = weld_vertices(V)
    assert ids[1] == ids[3] and ids[2] == ids[4] and len(set(ids)) == 4
    offsets, neighbours = one_ring_faces(F)
    assert list(neighbours[offsets[0]:offsets[1]]) == [0]
    offsets, neighbours = one_ring_faces(F, V=V)
    assert list(neighbours[offsets[0]:offsets[1]]) == [0, 1]


def test_matches_brute_force_on_random_faces():
    rng = np.random.default_rng(0)
    F = rng.integers(0, 25, (60, 3))
    offsets, neighbours = one_ring_faces(F)
    for f in range(len(F)):
        expected = [g for g in range(len(F)) if set(F[f]) & set(F[g])]
        assert list(neighbours[offsets[f]:offsets[f + 1]]) == expected


def test_validation():
    with pytest.raises(ValueError, match="F must"):
        one_ring_faces(np.zeros((2, 2), int))
    with pytest.raises(ValueError, match="outside V"):
        one_ring_faces(np.array([[0, 1, 5]]), V=np.zeros((3, 3)))


def _grid(size):
    """Unit squares of a flat size x size grid in z = 0, two triangles each: square (i, j) -> faces 2k, 2k + 1."""
    x, y = np.meshgrid(np.arange(size + 1.0), np.arange(size + 1.0), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    index = np.arange((size + 1) ** 2).reshape(size + 1, size + 1)
    F = []
    for i in range(size):
        for j in range(size):
            a, b, c, d = index[i, j], index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F)


def test_window_faces_by_hand():
    V, F = _grid(10)
    # A wall on the grid's vertices (5, 5) and (5, 6) (a copy, welded by position) and a loose triangle, both
    # over the window [4, 6]^2.
    wall = len(V)
    V = np.vstack([V, [[5.0, 6.0, 0.0], [5.0, 5.5, 3.0]], [[4.5, 4.5, 0.1], [5.5, 4.5, 0.1], [5.0, 5.5, 0.1]]])
    F = np.vstack([F, [[60, wall, wall + 1]], [[wall + 2, wall + 3, wall + 4]]])
    adjacency = one_ring_faces(F, V=V)
    start = 2 * (4 * 10 + 4)  # in square (4, 4)
    frame = dict(origin=[5.0, 5.0, 0.0], right=[1.0, 0, 0], up=[0, 1.0, 0], normal=[0, 0, 1.0])
    got = window_faces(V, F, adjacency, start, bounds=[-1, 1, -1, 1], **frame)
    assert got[0] == start
    # Squares whose x and y ranges touch [4, 6]: i, j in 3..6, two triangles each; the wall rises 3 above the
    # plane (more than half the window's side 2) and the loose triangle shares no vertex with the grid.
    expected = {2 * (10 * i + j) + t for i in range(3, 7) for j in range(3, 7) for t in (0, 1)}
    assert set(got.tolist()) == expected and len(got) == 32
    assert list(window_faces(V, F, adjacency, start, bounds=[-1, 1, -1, 1], limit=5, **frame)) == list(got[:5])
    # A window of side 8 admits the wall (its top is 3 above the plane).
    assert len(F) - 2 in window_faces(V, F, adjacency, start, bounds=[-4, 4, -4, 4], **frame)
