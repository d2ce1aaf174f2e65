"""numba entry point: one place that decides where compiled kernels are cached.

The cache goes to a per-user folder, never into the extension folder (which may be read-only and is replaced
on every update).
"""
import os
import sys

__all__ = ["njit", "prange", "cache_dir"]


def cache_dir():
    """Per-user folder for numba's on-disk cache (``$PERCEPTUAL_UV_CACHE`` overrides it)."""
    override = os.environ.get("PERCEPTUAL_UV_CACHE")
    if override:
        return os.path.join(override, "numba")
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~")
    elif sys.platform == "darwin":
        base = os.path.expanduser("~/Library/Caches")
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    return os.path.join(base, "perceptual_uv", "numba")


os.environ.setdefault("NUMBA_CACHE_DIR", cache_dir())

import numba  # noqa: E402  (must follow NUMBA_CACHE_DIR)

if not numba.config.CACHE_DIR:
    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]

prange = numba.prange


def njit(*args, **kwargs):
    """``numba.njit`` with the on-disk cache on by default."""
    kwargs.setdefault("cache", True)
    return numba.njit(*args, **kwargs)
