"""Load the compiled kernels that a run executes in the calling process, before the run needs them.

The triangle-wise stage and the loss passes run in worker processes; the rest of a run (the fit's targets, the
mesh-wise fit, the fold restore, the stacks, the views' one-rings, the packing, the bake's seam texels) runs numba
kernels in the process that drives the run: in Blender, its interface thread. numba compiles each kernel on its
first call after an install or update (about 40 s in all on this project's machine, the longest single kernel 22 s)
and loads it from its cache later (about 0.2 s for the first kernel of a process, milliseconds for the next).
:func:`load_kernels` calls each of them once on a tiny input, with the argument types a run gives them, so that a
caller can do it in a thread while its interface stays live (``bridge.pipeline`` does, while it imports the stages).
"""
import numpy as np

from .charts import uv_topology
from .cost import texel_reuse
from .footprint import footprint_texels
from .meshwise import solve_meshwise
from .one_ring import one_ring_faces
from .overlap import restore_folded_charts
from .packing import pack_charts
from .stacks import stacked_charts
from .textured import textured_triangles

__all__ = ["load_kernels"]


def load_kernels():
    """Compile, or load from numba's cache, every kernel a run executes outside its worker processes.

    Runs the fit's texel test (:func:`.textured.textured_triangles`), one mesh-wise iteration, the fold restore,
    the packing, the bake's footprint search and the input's texel reuse on a square of two triangles with a third
    folded over them.
    """
    uv = np.array([[[0.1, 0.1], [0.6, 0.1], [0.1, 0.6]],
                   [[0.6, 0.1], [0.6, 0.6], [0.1, 0.6]],
                   [[0.2, 0.2], [0.5, 0.2], [0.2, 0.5]]])
    F = np.array([[0, 1, 3], [1, 2, 3], [4, 5, 6]])
    texture = np.linspace(0.0, 1.0, 64).reshape(8, 8)
    textured_triangles(uv, texture)
    targets = np.tile([0.0, 1.0, 1.0, 0.0], (len(F), 1))
    weights = np.ones(len(F))
    topology = uv_topology(F, uv)
    solve_meshwise(F, uv, targets, weights, weights, topology=topology, max_iterations=1)
    restore_folded_charts(uv, uv, topology.face_chart)
    stacked_charts(uv, topology.face_chart)
    one_ring_faces(F)
    pack_charts(uv, topology.face_chart, margin=1, resolution=16)
    footprint_texels(uv, np.zeros((8, 8), dtype=bool))
    texel_reuse(uv, (8, 8))
