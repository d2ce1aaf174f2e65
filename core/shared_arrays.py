"""Large arrays handed to spawned worker processes through shared memory rather than as pickled copies.

Starting a process pool pickles the initializer's arguments once per worker, in the thread that starts the pool:
for the triangle-wise stage's stack of six 2048 px planes that is 192 MB per worker, and the pickling holds the
interpreter lock long enough to freeze the caller's other thread (a modal operator's steps) for half a second.
:class:`SharedArrays` copies every large array of a state into a shared memory block and leaves in its place a
handle that pickles as the block's name, shape and dtype; a worker that unpickles the handle maps the same pages.
"""
from multiprocessing import shared_memory

import numpy as np

from .loss_planes import PlaneStack

__all__ = ["SharedArrays", "MIN_SHARED_BYTES"]

#: Arrays at least this large go through shared memory; smaller ones are pickled as usual.
MIN_SHARED_BYTES = 1 << 20

# Blocks a worker has attached: their pages must stay mapped while its arrays live (the worker's lifetime).
_ATTACHED = []


def _attach(name, shape, dtype):
    """In a worker: the array of the shared memory block ``name`` (a writable view of its pages)."""
    block = shared_memory.SharedMemory(name=name)
    _ATTACHED.append(block)
    return np.ndarray(shape, dtype=np.dtype(dtype), buffer=block.buf)


class _Handle:
    """Stands for an array in a shared memory block; unpickles as that array."""

    __slots__ = ("name", "shape", "dtype")

    def __init__(self, name, shape, dtype):
        self.name, self.shape, self.dtype = name, shape, dtype

    def __reduce__(self):
        return _attach, (self.name, self.shape, self.dtype)


class SharedArrays:
    """The shared memory blocks of one pool's state: :meth:`share` fills them, :meth:`close` frees them.

    Parameters
    ----------
    min_bytes : int, optional
        Arrays of at least this many bytes are shared.

    Notes
    -----
    Call :meth:`close` once the workers are done (or stopped); a worker keeps the pages it mapped until it
    exits, so closing after ``Pool.terminate`` is safe. A block is read and written like any array: the workers
    only read theirs.
    """

    def __init__(self, *, min_bytes=MIN_SHARED_BYTES):
        self.min_bytes = int(min_bytes)
        self._blocks = []

    @property
    def nbytes(self):
        """Bytes held in shared memory."""
        return sum(block.size for block in self._blocks)

    def share(self, value):
        """``value`` with every large array, inside dicts, lists, tuples and plane stacks, replaced by a handle
        to a shared copy; pickle the result to send it. ``value`` itself is not changed."""
        if isinstance(value, np.ndarray):
            if value.nbytes < self.min_bytes or value.dtype.hasobject:
                return value
            block = shared_memory.SharedMemory(create=True, size=value.nbytes)
            self._blocks.append(block)
            copy = np.ndarray(value.shape, dtype=value.dtype, buffer=block.buf)
            copy[...] = value  # numpy copies without holding the interpreter lock
            del copy  # no view may outlive close()
            return _Handle(block.name, value.shape, value.dtype.str)
        if isinstance(value, PlaneStack):
            return PlaneStack([self.share(plane) for plane in value], value.names)
        if isinstance(value, dict):
            return {key: self.share(item) for key, item in value.items()}
        if type(value) in (list, tuple):
            return type(value)(self.share(item) for item in value)
        return value

    def close(self):
        """Free every block (idempotent)."""
        while self._blocks:
            block = self._blocks.pop()
            block.close()
            try:
                block.unlink()
            except FileNotFoundError:
                pass
