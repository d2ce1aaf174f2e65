"""How this package starts a helper process: the interpreter to run (inside Blender ``sys.executable`` is
Blender), the environment while it starts (one BLAS/numba thread, no re-run of ``__main__``) and the bootstrap
that imports this package in the child under the parent's module names. Used by the triangle-wise workers
(:mod:`.worker_pool`) and the background bake (``bridge.bake_process``); kept apart so that neither depends on
the other's code."""
import contextlib
import os
import sys
import types

__all__ = []


# Run in each spawned worker before any task is unpickled (as ``exec(source, namespace)``): registers the
# parents of this package as bare namespace modules (their ``__init__`` never runs), then imports the caller's
# module ``module_name`` under the same name as in the parent and hands its ``_worker_init`` the ``state``.
_BOOTSTRAP = """
import importlib, sys, types
for name, path in parents:
    if name not in sys.modules:
        module = types.ModuleType(name)
        module.__path__ = [path]
        sys.modules[name] = module
importlib.import_module(module_name)._worker_init(state)
"""


def _package_parents():
    """``(name, directory)`` of every package above ``core``, outermost first."""
    core_package = __name__.rsplit(".", 1)[0]  # e.g. bl_ext.user_default.perceptual_uv.core
    names = core_package.split(".")[:-1]
    directory = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the extension folder
    parents = []
    for depth in range(len(names), 0, -1):
        parents.append((".".join(names[:depth]), directory))
        directory = os.path.dirname(directory)
    return parents[::-1]


def _looks_like_python(path):
    name = os.path.basename(path or "").lower()
    return bool(path) and os.path.isfile(path) and name.startswith("python")


def _python_executable():
    """A Python interpreter for worker processes (inside Blender ``sys.executable`` may be Blender)."""
    candidates = [sys.executable, getattr(sys, "_base_executable", None)]
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    for prefix in (sys.prefix, sys.base_prefix, sys.exec_prefix):
        if sys.platform == "win32":
            candidates += [os.path.join(prefix, "python.exe"), os.path.join(prefix, "bin", "python.exe")]
        else:
            candidates += [os.path.join(prefix, "bin", f"python{version}"), os.path.join(prefix, "bin", "python3")]
    return next((path for path in candidates if _looks_like_python(path)), None)


@contextlib.contextmanager
def _spawn_environment():
    """Environment of the workers while they start: one BLAS/numba thread each, no re-import of ``__main__``."""
    saved_env = {key: os.environ.get(key) for key in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                         "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")}
    main = sys.modules.get("__main__")
    try:
        for key in saved_env:
            os.environ[key] = "1"
        # Spawn re-runs the parent's main script in each child unless __main__ has no file (Blender's scripts
        # and the CLI must not run again in a worker); the workers only need this module.
        sys.modules["__main__"] = types.ModuleType("__main__")
        yield
    finally:
        if main is not None:
            sys.modules["__main__"] = main
        for key, value in saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
