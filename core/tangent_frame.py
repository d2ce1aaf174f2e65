"""Tangent-space normals read in one UV map's tangent frame and written in another's, as Blender computes them.

A tangent-space normal map stores a direction in the frame (T, B, N) of the UV map it is drawn on: T the
MikkTSpace tangent of that map, B = sign N x T its bitangent, N the surface normal. Re-drawing the map on another
UV map changes T and B, so the stored values must change for the shading normal to stay. The two halves here
follow the two programs that do this in a bake: :func:`tangent_to_object` is Cycles' Normal Map node (stored
value to an object-space direction through the frame of the map it reads), :func:`object_to_tangent` Blender's
tangent-space NORMAL bake (object-space direction to the stored value in the frame of the map it writes). Both
take the frame as interpolated at the point (barycentric mix of the corners' unit tangents, bitangent signs and
normals, not renormalized), as those programs do, so a value written here agrees with what the bake writes.
"""
import numpy as np

__all__ = ["interpolate_frame", "tangent_to_object", "object_to_tangent"]


def interpolate_frame(bary, tangents, signs, normals):
    """The tangent frame at barycentric points: each corner's quantity mixed by the weights, not renormalized.

    Parameters
    ----------
    bary : (p, 3) array_like of float
        Barycentric coordinates of each point in its triangle.
    tangents : (p, 3, 3) array_like of float
        Per point, the unit tangents of its triangle's three corners (MikkTSpace of the UV map).
    signs : (p, 3) array_like of float
        Per point, the bitangent signs (+1 or -1) of the three corners.
    normals : (p, 3, 3) array_like of float
        Per point, the normals of the three corners (the smooth normals of a smooth face, the face normal of a
        flat one).

    Returns
    -------
    tangent : (p, 3) ndarray of float64
    sign : (p,) ndarray of float64
    normal : (p, 3) ndarray of float64
    """
    bary = np.asarray(bary, dtype=np.float64)
    return (np.einsum("pk,pkd->pd", bary, np.asarray(tangents, dtype=np.float64)),
            np.einsum("pk,pk->p", bary, np.asarray(signs, dtype=np.float64)),
            np.einsum("pk,pkd->pd", bary, np.asarray(normals, dtype=np.float64)))


def _unit(vectors):
    """Rows scaled to length 1; zero rows stay zero."""
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, length, out=np.zeros_like(vectors), where=length > 0)


def tangent_to_object(stored, tangent, sign, normal, *, strength=1.0):
    """The object-space direction a Normal Map node gives for stored tangent-space values.

    Parameters
    ----------
    stored : (p, 3) array_like of float
        The map's values, in [0, 1] (0.5 is no tilt): c = 2 stored - 1 are the coordinates along (T, B, N).
    tangent : (p, 3) array_like of float
        T at each point (:func:`interpolate_frame`).
    sign : (p,) array_like of float
        The interpolated bitangent sign; B = sign N x T (its value is used as it is, as Cycles does).
    normal : (p, 3) array_like of float
        N at each point, the interpolated normal.
    strength : float, optional
        The node's Strength: the result is mixed from the unit normal, ``unit(n + (d - n) strength)``.

    Returns
    -------
    (p, 3) ndarray of float64
        Unit directions ``unit(c_x T + c_y B + c_z N)`` (zero where that sum is zero).
    """
    c = 2.0 * np.asarray(stored, dtype=np.float64) - 1.0
    tangent = np.asarray(tangent, dtype=np.float64)
    normal = np.asarray(normal, dtype=np.float64)
    bitangent = np.asarray(sign, dtype=np.float64)[:, None] * np.cross(normal, tangent)
    direction = _unit(c[:, :1] * tangent + c[:, 1:2] * bitangent + c[:, 2:] * normal)
    if strength != 1.0:
        base = _unit(normal)
        direction = _unit(base + (direction - base) * max(float(strength), 0.0))
    return direction


def object_to_tangent(direction, tangent, sign, normal):
    """Stored tangent-space values of object-space directions, as Blender's tangent-space NORMAL bake writes them.

    Parameters
    ----------
    direction : (p, 3) array_like of float
        Object-space directions (any length).
    tangent : (p, 3) array_like of float
        T of the frame written in, at each point (:func:`interpolate_frame`).
    sign : (p,) array_like of float
        The interpolated bitangent sign; its sign is taken (negative: -1, else +1), as the bake does.
    normal : (p, 3) array_like of float
        N at each point, the interpolated normal.

    Returns
    -------
    (p, 3) ndarray of float64
        ``0.5 unit(M^-1 d) + 0.5`` with M the matrix of columns (T, B, N), B = sign N x T: the coordinates of the
        direction along the frame's axes (M is inverted, not transposed: the interpolated frame need not be
        orthonormal). Points whose frame has no inverse get (0.5, 0.5, 1), the unperturbed normal.
    """
    direction = np.asarray(direction, dtype=np.float64)
    tangent = np.asarray(tangent, dtype=np.float64)
    normal = np.asarray(normal, dtype=np.float64)
    sign = np.where(np.asarray(sign, dtype=np.float64) < 0.0, -1.0, 1.0)
    frame = np.stack([tangent, sign[:, None] * np.cross(normal, tangent), normal], axis=-1)
    local = np.tile([0.0, 0.0, 1.0], (len(direction), 1))
    determinant = np.linalg.det(frame) if len(frame) else np.empty(0)
    # a frame that is singular at float32 precision (a zero tangent, a degenerate face) has no meaningful inverse
    scale = np.prod(np.linalg.norm(frame, axis=1), axis=-1) if len(frame) else np.empty(0)
    solvable = np.abs(determinant) > 1e-6 * scale
    if solvable.any():
        local[solvable] = np.linalg.solve(frame[solvable], direction[solvable][:, :, None])[:, :, 0]
    local = _unit(local)
    local[np.linalg.norm(local, axis=1) == 0] = (0.0, 0.0, 1.0)
    return 0.5 * local + 0.5
