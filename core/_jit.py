"""numba entry point: one place that decides where compiled kernels are cached.

The cache goes to a per-user folder, never into the extension folder (which may be read-only and is replaced
on every update), in a subfolder per version of ``core``'s source. numba keys a cached kernel on its own file
only: a kernel that calls a kernel of another module would keep the old callee's machine code after that module
changed. One folder per source hash gives every change (an update, a developer's edit) freshly compiled kernels;
the few most recent folders are kept, older ones removed.
"""
import hashlib
import os
import pathlib
import shutil
import sys

__all__ = ["njit", "prange", "cache_dir", "core_source_hash"]

#: How many per-version numba folders stay (the current one and the most recently used others).
KEPT_VERSIONS = 4

_SOURCE_HASH = None


def core_source_hash():
    """SHA-256 (hex) of the source of every module of ``core``: names and bytes, in name order."""
    global _SOURCE_HASH
    if _SOURCE_HASH is None:
        digest = hashlib.sha256()
        for path in sorted(pathlib.Path(__file__).parent.glob("*.py")):
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
        _SOURCE_HASH = digest.hexdigest()
    return _SOURCE_HASH


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


def _versioned_numba_folder():
    """``cache_dir()/<source hash>``, created and marked as just used; older version folders beyond
    :data:`KEPT_VERSIONS` are removed (a process still running an old version recompiles what it misses)."""
    base = pathlib.Path(cache_dir())
    folder = base / core_source_hash()[:16]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)
        versions = sorted((path for path in base.iterdir() if path.is_dir() and len(path.name) == 16),
                          key=lambda path: path.stat().st_mtime, reverse=True)
        for old in versions[KEPT_VERSIONS:]:
            if old != folder:
                shutil.rmtree(old, ignore_errors=True)
    except OSError:  # a read-only or full disk: numba then compiles without caching
        pass
    return str(folder)


# Spawned workers inherit the variable, so they use the folder their parent chose (and prune nothing).
if not os.environ.get("NUMBA_CACHE_DIR"):
    os.environ["NUMBA_CACHE_DIR"] = _versioned_numba_folder()

import numba  # noqa: E402  (must follow NUMBA_CACHE_DIR)

if not numba.config.CACHE_DIR:
    numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]

prange = numba.prange


def njit(*args, **kwargs):
    """``numba.njit`` with the on-disk cache on by default."""
    kwargs.setdefault("cache", True)
    return numba.njit(*args, **kwargs)
