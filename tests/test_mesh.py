# SPDX-License-Identifier: GPL-3.0-or-later
"""core.mesh.read_obj: a hand-written two-triangle OBJ, hand-checked spot corners, and the refusals."""
import pathlib

import numpy as np
import pytest

from perceptual_uv.core.mesh import read_obj

SPOT = pathlib.Path(__file__).resolve().parent / "data" / "spot" / "spot_triangulated.obj"

# A unit square in z = 0 split along its diagonal; the second face's corners carry normals (a/ta/na), and the
# vt lines are listed in another order than the v lines.
SQUARE_OBJ = """\
# two triangles
o square
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0.0 0.0
vt 0.5 0.0 0.0
vt 0.5 0.5
vt 0.0 0.5
vn 0 0 1

f 1/1 2/2 3/3
s off
f 1/1/1 3/3/1 4/4/1
"""


def _write(tmp_path, text):
    path = tmp_path / "mesh.obj"
    path.write_text(text)
    return path


def test_two_triangles_by_hand(tmp_path):
    V, F, uv = read_obj(_write(tmp_path, SQUARE_OBJ))
    np.testing.assert_array_equal(V, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(F, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(uv, [[[0, 0], [0.5, 0], [0.5, 0.5]], [[0, 0], [0.5, 0.5], [0, 0.5]]])
    assert (V.dtype, F.dtype, uv.dtype) == (np.float64, np.int64, np.float64)
    assert (V.shape, F.shape, uv.shape) == ((4, 3), (2, 3), (2, 3, 2))


def test_spot_corners_match_the_file():
    # Face 1 is "f 739/1 735/2 736/3"; v 739 = (0.317288, -0.397295, 0.364448), vt 1 = (0.800375, 0.667457),
    # vt 2 = (0.789584, 0.668215) (tests/test_mesh_io.py reads the same lines through Blender).
    V, F, uv = read_obj(SPOT)
    assert (V.shape, F.shape, uv.shape) == ((2930, 3), (5856, 3), (5856, 3, 2))
    np.testing.assert_array_equal(F[0], [738, 734, 735])
    np.testing.assert_array_equal(V[738], [0.317288, -0.397295, 0.364448])
    np.testing.assert_array_equal(uv[0, :2], [[0.800375, 0.667457], [0.789584, 0.668215]])


@pytest.mark.parametrize("faces, message", [
    ("f 1/1 2/2 3/3 4/4", "4 corners; read_obj reads triangulated"),
    ("f 1 2 3", "no texture coordinate index"),
    ("f 1//1 2//1 3//1", "no texture coordinate index"),
    ("f -4/-4 -3/-3 -2/-2", "indices must be positive"),
    ("f 1/1 2/2 5/3", "vertex 5 of 4"),
    ("f 1/1 2/2 3/9", "texture coordinate 9 of 4"),
    ("", "no faces"),
])
def test_refusals_name_the_problem(tmp_path, faces, message):
    text = SQUARE_OBJ.split("f ")[0] + faces + "\n"
    with pytest.raises(ValueError, match=message):
        read_obj(_write(tmp_path, text))


def test_missing_uvs_are_refused(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/2 3/3\n"
    with pytest.raises(ValueError, match="no texture coordinates"):
        read_obj(_write(tmp_path, text))
