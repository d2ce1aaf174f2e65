"""core.warm_up loads every kernel a run executes outside its worker processes."""
from numba.core.registry import CPUDispatcher

from perceptual_uv.core import (chart_bitmaps, footprint, meshwise_global, meshwise_local, one_ring, overlap, packing,
                                textured)
from perceptual_uv.core.warm_up import load_kernels

# The kernels a run on spot executed in the driving process (listed from numba's dispatchers after a run).
MAIN_PROCESS_KERNELS = [(footprint, "_footprint_kernel"), (textured, "_textured_kernel"),
                        (meshwise_local, "_local_update_kernel"), (meshwise_global, "_hessian_blocks_kernel"),
                        (one_ring, "_one_ring_kernel"), (overlap, "_overlap_areas_kernel"), (overlap, "_grid_pairs"),
                        (chart_bitmaps, "_touch_triangles"), (chart_bitmaps, "row_spans"),
                        (packing, "_first_fit"), (packing, "_occupy")]


def test_every_main_process_kernel_is_loaded():
    load_kernels()
    for module, name in MAIN_PROCESS_KERNELS:
        kernel = getattr(module, name)
        assert isinstance(kernel, CPUDispatcher)
        assert kernel.signatures, f"{module.__name__}.{name} was not loaded"
