"""Large arrays reach spawned workers through shared memory (core.shared_arrays)."""
import multiprocessing
import pickle

import numpy as np
import pytest

from perceptual_uv.core.loss_planes import PlaneStack
from perceptual_uv.core.shared_arrays import SharedArrays


def test_large_arrays_pickle_as_handles_and_unpickle_equal():
    rng = np.random.default_rng(0)
    large = rng.random((512, 512))  # 2 MiB: shared
    small = np.arange(10)  # pickled as usual
    stack = PlaneStack([large, large[:300, :200].copy()], names=("luma", "normal"))
    state = {"luma": stack, "F": small, "options": {"seed": 3}, "pair": (large, "x")}
    shared = SharedArrays(min_bytes=1 << 16)
    try:
        sent = pickle.dumps(shared.share(state))
        # two planes of the stack and the pair's copy: three blocks, and only their names travel
        assert shared.nbytes >= 2 * large.nbytes + 300 * 200 * 8
        assert len(sent) < 10_000 < large.nbytes
        received = pickle.loads(sent)
        assert isinstance(received["luma"], PlaneStack) and received["luma"].names == ("luma", "normal")
        np.testing.assert_array_equal(received["luma"][0], large)
        np.testing.assert_array_equal(received["luma"][1], large[:300, :200])
        np.testing.assert_array_equal(received["pair"][0], large)
        assert received["pair"][1] == "x" and received["options"] == {"seed": 3}
        assert received["F"] is not small and np.array_equal(received["F"], small)
        assert received["luma"][0].flags.c_contiguous and received["luma"][0].flags.writeable
        assert state["luma"][0] is large  # the caller's state is untouched
    finally:
        shared.close()
    shared.close()  # idempotent


def _sum_of(state):
    return float(state["plane"].sum()), state["plane"].shape


def test_a_spawned_process_reads_the_shared_array():
    plane = np.linspace(0.0, 1.0, 400 * 300).reshape(400, 300)
    shared = SharedArrays(min_bytes=1024)
    try:
        handle_state = shared.share({"plane": plane})
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            total, shape = pool.apply(_sum_of, (handle_state,))
    finally:
        shared.close()
    assert shape == (400, 300)
    assert total == pytest.approx(400 * 300 / 2, rel=1e-12)  # the mean of a linspace over [0, 1] is 1/2
