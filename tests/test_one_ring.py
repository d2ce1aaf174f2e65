"""One-ring neighbourhoods (triangles sharing a vertex), with vertices welded by position."""
import numpy as np
import pytest

from perceptual_uv.core.one_ring import one_ring_faces, weld_vertices


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
