# SPDX-License-Identifier: GPL-3.0-or-later
"""Charts that share texels in the input stay stacked: one island for the post-processing and the packing.

Artists lay mirrored halves, repeated parts and tiled details on the same texels on purpose, and photogrammetry
atlases do it by accident; either way the input's texture holds those texels once. A method that gives every
chart texels of its own needs, for the same texel density, as many times the input's texels as the charts
stack (sofa_03's input uses 2.3 times the image area it covers). Keeping such charts stacked costs the method
nothing it could gain: the charts read the same source texels at the same relative positions, so one copy of
them, under one similarity map of the input layout, serves all of them, and the bake writes the same values
from each.

A stack of several charts therefore gets its input layout back, scaled uniformly so that its charts' UV area
adds up to what the method gave them (the charts' own fitted shapes are given up, as a folded chart's are,
:func:`.overlap.restore_folded_charts`), turns as one chart and packs as one island. Like the fold restore, it
is post-processing every method gets.
"""
import numpy as np

from .charts import signed_uv_areas
from .cost import uv_area
from .overlap import overlap_areas, overlapping_pairs

__all__ = ["STACK_SHARE", "stacked_charts", "restack_charts", "stacked_faces", "packing_islands"]

#: Two charts stack when the UV area they share exceeds this fraction of the smaller one's area.
STACK_SHARE = 0.01


def _check(uv, face_chart):
    uv = np.asarray(uv, dtype=np.float64)
    face_chart = np.asarray(face_chart)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2) or face_chart.shape != uv.shape[:1]:
        raise ValueError(f"uv must be (m, 3, 2) and face_chart (m,), got {uv.shape} and {face_chart.shape}")
    if len(face_chart) and (face_chart.min() < 0 or not np.issubdtype(face_chart.dtype, np.integer)):
        raise ValueError("face_chart must hold chart numbers from 0")
    return uv, face_chart.astype(np.int64)


def _wrapped(uv, face_chart, n_charts):
    """``uv`` with every chart moved by whole UV units so that its corners' mean lies in ``[0, 1)^2``.

    An image repeats (glTF's and Blender's default extension), so the moved chart reads the same texels: a tile
    laid one unit to the right of another stacks with it.
    """
    corners = np.bincount(np.repeat(face_chart, 3), minlength=n_charts).astype(np.float64)
    mean = np.stack([np.bincount(np.repeat(face_chart, 3), uv[:, :, axis].ravel(), minlength=n_charts)
                     for axis in (0, 1)], axis=1) / np.maximum(corners, 1)[:, None]
    return uv - np.floor(mean)[face_chart][:, None, :]


def stacked_charts(uv, face_chart, *, share=STACK_SHARE):
    """The stack of every chart: charts whose UV triangles share texels, joined transitively.

    Parameters
    ----------
    uv : (m, 3, 2) array_like of float
        Input UVs per face corner (any real values: the image repeats).
    face_chart : (m,) array_like of int
        Chart of every face, numbered from 0 (``uv_topology(F, uv).face_chart``).
    share : float, optional
        Two charts stack when the UV area they share (their triangles' pairwise overlaps, each chart moved by
        whole units to the unit square first) exceeds ``share`` times the smaller chart's UV area.

    Returns
    -------
    (n_charts,) int64 ndarray
        Stack number of every chart, numbered from 0 in order of each stack's first chart; a chart that shares
        no texels is a stack of its own.
    """
    uv, face_chart = _check(uv, face_chart)
    if not 0 <= share < 1:
        raise ValueError(f"share must be in [0, 1), got {share}")
    n_charts = int(face_chart.max()) + 1 if len(face_chart) else 0
    parent = np.arange(n_charts)
    if n_charts > 1:
        placed = _wrapped(uv, face_chart, n_charts)
        pairs = overlapping_pairs(placed)
        pairs = pairs[face_chart[pairs[:, 0]] != face_chart[pairs[:, 1]]]
        if len(pairs):
            charts = np.sort(face_chart[pairs], axis=1)
            keys, inverse = np.unique(charts, axis=0, return_inverse=True)
            shared = np.bincount(inverse.ravel(), overlap_areas(placed, pairs), minlength=len(keys))
            area = np.bincount(face_chart, np.abs(signed_uv_areas(placed)), minlength=n_charts)
            joined = keys[shared > share * np.minimum(area[keys[:, 0]], area[keys[:, 1]])]
            for a, b in joined:
                a, b = _root(parent, a), _root(parent, b)
                parent[max(a, b)] = min(a, b)
    roots = np.array([_root(parent, chart) for chart in range(n_charts)], dtype=np.int64)
    return np.unique(roots, return_inverse=True)[1].astype(np.int64).reshape(-1)


def _root(parent, node):
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


def restack_charts(uv_in, uv_new, face_chart, stack):
    """Lay every stack of several charts out as in the input, scaled uniformly to its charts' new UV area.

    Parameters
    ----------
    uv_in : (m, 3, 2) array_like of float
        Input UVs per face corner.
    uv_new : (m, 3, 2) array_like of float
        A method's UVs of the same charts, before packing.
    face_chart : (m,) array_like of int
        Chart of every face in the input.
    stack : (n_charts,) array_like of int
        Stack of every chart (:func:`stacked_charts` of ``uv_in``).

    Returns
    -------
    (m, 3, 2) float64 ndarray
        ``uv_new``, except that the charts of every stack of two or more are the input layout (each chart moved
        by the whole UV units :func:`stacked_charts` moved it) times one factor ``s`` per stack, with ``s^2`` the
        stack's summed chart areas in ``uv_new`` over those in ``uv_in``: its charts share texels as in the
        input and keep, together, the texels the method gave them.
    """
    uv_in, face_chart = _check(uv_in, face_chart)
    uv_new = np.asarray(uv_new, dtype=np.float64)
    stack = np.asarray(stack, dtype=np.int64)
    if uv_new.shape != uv_in.shape:
        raise ValueError(f"uv_in {uv_in.shape} and uv_new {uv_new.shape} must describe the same faces")
    n_charts = int(face_chart.max()) + 1 if len(face_chart) else 0
    if stack.shape != (n_charts,):
        raise ValueError(f"stack must give one stack per chart, shape ({n_charts},), got {stack.shape}")
    uv = uv_new.copy()
    counts = np.bincount(stack, minlength=int(stack.max()) + 1 if n_charts else 0)
    face_stack = stack[face_chart]
    placed = _wrapped(uv_in, face_chart, n_charts)
    for number in np.flatnonzero(counts > 1):
        faces = face_stack == number
        before = uv_area(placed[faces])
        if before > 0:
            uv[faces] = placed[faces] * np.sqrt(uv_area(uv_new[faces]) / before)
    return uv


def stacked_faces(face_chart, stack):
    """The stack of every face whose chart shares its stack with other charts; -1 for every other face.

    Parameters
    ----------
    face_chart : (m,) array_like of int
        Chart of every face in the input.
    stack : (n_charts,) array_like of int
        Stack of every chart (:func:`stacked_charts`).

    Returns
    -------
    (m,) int64 ndarray
    """
    face_chart = np.asarray(face_chart, dtype=np.int64)
    stack = np.asarray(stack, dtype=np.int64)
    if not len(stack):
        return np.full(len(face_chart), -1, dtype=np.int64)
    several = np.bincount(stack)[stack] > 1
    return np.where(several[face_chart], stack[face_chart], -1)


def packing_islands(face_chart, face_stack):
    """The islands a packer moves: every chart alone, but the faces of one stack together.

    Parameters
    ----------
    face_chart : (m,) array_like of int
        Chart of every face of the UV map being packed (its own charts: a method may cut the input's).
    face_stack : (m,) array_like of int
        :func:`stacked_faces`: a stack number, or -1 for a face that packs with its chart.

    Returns
    -------
    (m,) int64 ndarray
        Island of every face, numbered from 0.
    """
    face_chart = np.asarray(face_chart, dtype=np.int64)
    face_stack = np.asarray(face_stack, dtype=np.int64)
    if face_stack.shape != face_chart.shape:
        raise ValueError(f"face_chart {face_chart.shape} and face_stack {face_stack.shape} must describe the same "
                         "faces")
    if not len(face_chart):
        return face_chart.copy()
    key = np.where(face_stack >= 0, face_chart.max() + 1 + face_stack, face_chart)
    return np.unique(key, return_inverse=True)[1].astype(np.int64).reshape(-1)
