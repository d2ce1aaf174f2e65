"""A cache of a stage's results, in memory and in a folder, keyed by the stage's inputs, settings and code.

The triangle-wise stage takes minutes and depends only on the mesh, its UV map, the texture, a few settings and
the code of ``core``; the cost, margin and names only change what comes after it. Keeping its result lets the
redo panel and a second CLI run with another cost rerun the mesh-wise fit, the packing and the bake alone.
"""
import collections
import dataclasses
import hashlib
import json
import os
import pathlib
import time
import zipfile

import numpy as np

from ._jit import cache_dir, core_source_hash
from .atomic import atomic_path

__all__ = ["ResultCache", "stage_results", "result_key", "default_cache_folder", "save_arrays", "dataclass_from"]


def save_arrays(path, **arrays):
    """Write ``arrays`` to the .npz file ``path`` whole or not at all (:func:`.atomic.atomic_path`)."""
    with atomic_path(path) as temporary, open(temporary, "wb") as handle:
        np.savez(handle, **arrays)


def dataclass_from(kind, stored):
    """An instance of the dataclass ``kind`` from an open .npz ``stored``: its fields found there, 0-d arrays as
    Python scalars, other entries ignored."""
    return kind(**{field.name: _scalar_or_array(stored[field.name]) for field in dataclasses.fields(kind)
                   if field.name in stored.files})


def _scalar_or_array(value):
    return value.item() if value.ndim == 0 else value


def default_cache_folder():
    """The per-user folder of stage results: ``$PERCEPTUAL_UV_RESULTS_CACHE`` if set, else ``results`` next to
    numba's cache (:func:`perceptual_uv.core._jit.cache_dir`)."""
    override = os.environ.get("PERCEPTUAL_UV_RESULTS_CACHE")
    return pathlib.Path(override) if override else pathlib.Path(cache_dir()).parent / "results"


def stage_results(holder, kind, subfolder=None):
    """The :class:`ResultCache` of one pipeline stage, made on first use and kept in ``holder``.

    Parameters
    ----------
    holder : list
        The stage module's list that keeps the cache once made (empty until then; tests empty it to start
        afresh).
    kind : type
        The stage's result dataclass.
    subfolder : str, optional
        The stage's folder under :func:`default_cache_folder` (None: that folder itself).

    Returns
    -------
    ResultCache
    """
    if not holder:
        folder = default_cache_folder()
        holder.append(ResultCache(kind, folder=folder / subfolder if subfolder else folder))
    return holder[0]


def result_key(*arrays, **settings):
    """A key for a result of ``arrays`` under ``settings`` and the current ``core`` code.

    Parameters
    ----------
    *arrays : array_like
        The stage's array inputs (dtype, shape and bytes all count).
    **settings
        JSON-serializable settings the result depends on.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    digest = hashlib.sha256(core_source_hash().encode())
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.reshape(-1).view(np.uint8) if array.size else b"")  # the bytes, without a copy
    digest.update(json.dumps(settings, sort_keys=True).encode())
    return digest.hexdigest()


class ResultCache:
    """Results of one dataclass type by key: the last ``memory`` in memory, up to ``files`` in ``folder``.

    Parameters
    ----------
    kind : type
        A dataclass whose fields are arrays, numbers, strings or None.
    folder : path-like or None
        Where results are kept across sessions (``<key>.npz``, oldest removed first beyond ``files``); None
        keeps them in memory only.
    memory : int
        Results kept in memory, most recently used first.
    files : int
        Results kept in ``folder``.
    """

    def __init__(self, kind, *, folder=None, memory=2, files=32):
        self.kind = kind
        self.folder = pathlib.Path(folder) if folder is not None else None
        self.memory = memory
        self.files = files
        self._recent = collections.OrderedDict()

    def get(self, key):
        """The result stored under ``key``, or None (an unreadable file counts as missing and is removed)."""
        if key in self._recent:
            self._recent.move_to_end(key)
            return self._recent[key]
        if self.folder is None:
            return None
        path = self.folder / f"{key}.npz"
        try:
            with np.load(path, allow_pickle=False) as stored:
                result = dataclass_from(self.kind, stored)
        except FileNotFoundError:
            return None
        except (OSError, ValueError, TypeError, KeyError, zipfile.BadZipFile):  # truncated or foreign: compute again
            path.unlink(missing_ok=True)
            return None
        os.utime(path)
        self._remember(key, result)
        return result

    def put(self, key, result):
        """Store ``result`` under ``key`` (in memory, and in the folder if it can be written)."""
        self._remember(key, result)
        if self.folder is None:
            return
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            arrays = {field.name: np.asarray(getattr(result, field.name)) for field in dataclasses.fields(result)
                      if getattr(result, field.name) is not None}
            save_arrays(self.folder / f"{key}.npz", **arrays)
            self._trim()
        except OSError:  # a read-only or full disk costs the next run its time, nothing else
            pass

    def discard(self, key):
        """Forget the result stored under ``key``, in memory and in the folder (nothing if there is none)."""
        self._recent.pop(key, None)
        if self.folder is not None:
            (self.folder / f"{key}.npz").unlink(missing_ok=True)

    def clear(self):
        """Forget every result, in memory and in the folder; return the number of files removed."""
        self._recent.clear()
        if self.folder is None or not self.folder.is_dir():
            return 0
        removed = 0
        for path in self.folder.glob("*.npz"):
            path.unlink(missing_ok=True)
            removed += 1
        return removed

    def _remember(self, key, result):
        self._recent[key] = result
        self._recent.move_to_end(key)
        while len(self._recent) > self.memory:
            self._recent.popitem(last=False)

    def _trim(self):
        stored = sorted(self.folder.glob("*.npz"), key=lambda path: path.stat().st_mtime)
        for path in stored[:max(len(stored) - self.files, 0)]:
            path.unlink(missing_ok=True)
        for path in self.folder.glob("*.partial"):  # left by a run killed while writing (not one writing now)
            try:
                if time.time() - path.stat().st_mtime > 3600:
                    path.unlink()
            except FileNotFoundError:
                pass
