"""Where the triangle-wise stage and the loss passes compute: spawned worker processes, a Dask cluster or this
process, one chunk of faces per task, with control handed back while nothing has finished.

A stage is a generator that a modal operator drives one step per timer tick, so waiting for workers must not
block: :func:`run_chunks` yields None every :data:`WAIT_SECONDS` while no chunk has finished, and the worker
pool starts in a background thread. The workers receive the stage's state once (its large arrays through
shared memory, :class:`.shared_arrays.SharedArrays`) and face-index chunks afterwards; a task is a module-level
function ``task(state, chunk) -> output`` (pickled by reference). Inside Blender, ``sys.executable`` may not be a
Python interpreter and the package is importable only as ``bl_ext.<repo>.perceptual_uv``: the workers get an
interpreter found next to the running Python and the bootstrap of :mod:`.spawn`, so the extension's
``__init__`` (which registers Blender classes) never runs in a worker.
"""
import contextlib
import os
import sys
import threading
import time

import numpy as np

from .progress import InThread
from .shared_arrays import SharedArrays
from .spawn import _BOOTSTRAP, _looks_like_python, _package_parents, _python_executable, _spawn_environment

__all__ = ["run_chunks", "one_blas_thread", "WorkerDiedError", "WAIT_SECONDS"]

# Longest wait for worker results before a stage's generator hands control back (the modal operator's tick).
WAIT_SECONDS = 0.1
DASK_CONNECT_SECONDS = 30

_WORKER_STATE = {}


def one_blas_thread():
    """Limit BLAS and OpenMP to one thread in this process until the returned context exits (a null context
    without threadpoolctl).

    A task makes thousands of tiny BLAS calls (L-BFGS-B's updates in the Bayesian optimizer, the multifrontal
    re-bake's small fronts); with a multi-threaded OpenBLAS each call hands work to, and waits for, threads that
    share the cores with the other workers, and the optimizer's overhead grows more than tenfold on busy cores.
    Worker processes keep the limit for their lifetime; tasks run in this process take it for their duration.
    """
    try:
        import threadpoolctl

        return threadpoolctl.threadpool_limits(1)
    except Exception:  # a speed setting: no run may fail for it (no threadpoolctl, a BLAS it cannot drive)
        return contextlib.nullcontext()


def _worker_init(state):
    _WORKER_STATE.clear()
    _WORKER_STATE.update(state)
    # Worker processes split the cores among themselves: one thread each for BLAS and numba.
    one_blas_thread()


class WorkerDiedError(RuntimeError):
    """A worker process of the triangle-wise stage ended without delivering its results."""


# One pool starts at a time: _spawn_environment swaps process-wide state (environment, __main__), and a pool
# still starting in the background after a cancel may overlap the next run's.
_SPAWN_LOCK = threading.Lock()


def _make_pool(workers, state, shared):
    """A pool of ``workers`` spawned processes, each initialized with ``state``, its large arrays put in
    ``shared`` (a :class:`.shared_arrays.SharedArrays`) rather than pickled per worker; None when no Python
    interpreter for them is found. Takes about a second (each worker starts Python and unpickles ``state``
    before the next starts): :func:`run_chunks` calls it in a background thread."""
    import multiprocessing

    executable = _python_executable()
    if executable is None:
        return None
    context = multiprocessing.get_context("spawn")
    if not _looks_like_python(sys.executable):
        context.set_executable(executable)
    namespace = {"parents": _package_parents(), "module_name": __name__, "state": shared.share(state)}
    with _SPAWN_LOCK, _spawn_environment():
        return context.Pool(workers, initializer=exec, initargs=(_BOOTSTRAP, namespace))


def _terminate_when_started(starting, shared):
    """Stop the pool ``starting`` (an :class:`.progress.InThread` of :func:`_make_pool`) makes, once it is made,
    and free its ``shared`` arrays."""
    try:
        pool = starting.join()
        if pool is not None:
            pool.terminate()
    finally:
        shared.close()


def _chunks(faces, size):
    """``faces`` in chunks of ``size`` consecutive faces, the chunks in a fixed pseudo-random order (the same for
    every call).

    A mesh's costly faces are often neighbours in its face order (WaterBottle's first faces have the largest
    views): taken in that order, the first chunks finish far slower than the rest and the stage's time left, read
    from the rate so far, is many times too long, and the last chunks may leave one worker busy alone. In a random
    order the chunks done at any time are a sample of all of them; each chunk keeps neighbouring faces, whose
    views read the same part of the texture.
    """
    chunks = [faces[start:start + size] for start in range(0, len(faces), size)]
    return [chunks[i] for i in np.random.default_rng(0).permutation(len(chunks))]


def run_chunks(task, state, faces, *, workers, chunk_size, scheduler=None):
    """Run ``task(state, chunk)`` on every chunk of ``faces``; a generator of the outputs in the order they finish.

    Parameters
    ----------
    task : callable
        A module-level function ``task(state, chunk) -> output`` (workers find it by its module and name).
    state : dict
        What every task reads; its large arrays reach the workers through shared memory.
    faces : (k,) int ndarray
        Split into chunks of ``chunk_size``, taken in a fixed pseudo-random order (:func:`_chunks`): a task's
        output must say which faces it holds.
    workers : int
        Worker processes; 0 = one per core, 1 = in this process (so is any count when no Python interpreter
        for workers is found).
    chunk_size : int
    scheduler : str, optional
        Address of a Dask scheduler: the chunks run as tasks of that cluster (``workers`` is then unused).

    Yields
    ------
    output or None
        Each chunk's output as it finishes, and None every :data:`WAIT_SECONDS` while none has (the caller gets
        control back, e.g. a modal operator's tick). Closing the generator stops the workers.

    Raises
    ------
    WorkerDiedError
        A worker process ended without delivering its results (out of memory, killed).
    """
    chunks = _chunks(faces, chunk_size)
    if scheduler is not None:
        yield from _run_chunks_on_dask(task, state, chunks, scheduler)
        return
    if workers == 0:
        workers = os.cpu_count() or 1
    workers = min(workers, len(chunks))
    pool = None
    shared = SharedArrays()
    if workers > 1:
        starting = InThread(_make_pool, workers, state, shared, interval=WAIT_SECONDS)
        try:
            pool = yield from starting.wait()
        except BaseException:
            # Closed (a cancel) or interrupted while the workers start: they are stopped once they are up, by a
            # thread of their own, so that the cancel does not wait for them (not a daemon: an interpreter that
            # exits meanwhile waits for it, rather than leave workers starting with a parent gone).
            threading.Thread(target=_terminate_when_started, args=(starting, shared)).start()
            raise
    if pool is None:
        shared.close()
        for chunk in chunks:
            with one_blas_thread():  # not held across the yield: the caller's own BLAS work keeps its threads
                output = task(state, chunk)
            yield output
        return
    import multiprocessing

    # Pool replaces a worker that dies but loses its task, so the results would never arrive: wait in short
    # slices and give up with a clear error once any of the original workers is gone.
    original_workers = {process.pid for process in pool._pool}
    died = False
    try:
        results = pool.imap_unordered(_chunk_call, [(task, chunk) for chunk in chunks])
        for _ in chunks:
            while True:
                try:
                    output = results.next(timeout=WAIT_SECONDS)
                    break
                except multiprocessing.TimeoutError:
                    if {process.pid for process in pool._pool} != original_workers:
                        died = True
                        raise WorkerDiedError("a worker process of the triangle-wise stage died (out of memory or "
                                              "killed?); run again with fewer workers") from None
                    yield None  # nothing finished yet: the caller gets control back (a modal operator's tick)
            yield output
        pool.close()
        yield from InThread(pool.join, interval=WAIT_SECONDS).wait()  # the workers take about a second to exit
    finally:
        if died:
            _stop_after_a_death(pool)
        else:
            pool.terminate()
        shared.close()


def _stop_after_a_death(pool):
    """Stop ``pool`` after one of its workers died, without waiting on it.

    ``Pool.terminate`` first takes the lock of the task queue, which a worker holds while it waits for a task:
    a worker killed while it waited leaves that lock taken for good, and ``terminate`` would wait forever. It
    runs in a daemon thread instead (where it stops the pool from replacing workers before it reaches the
    lock), and the workers are killed here.
    """
    from multiprocessing.pool import RUN

    threading.Thread(target=pool.terminate, daemon=True).start()
    deadline = time.monotonic() + 1.0
    while pool._worker_handler._state == RUN and time.monotonic() < deadline:
        time.sleep(0.001)
    for process in list(pool._pool):
        with contextlib.suppress(OSError, ValueError):
            process.kill()


def _run_chunks_on_dask(task, state, chunks, scheduler):
    """The chunks as tasks of the Dask cluster at ``scheduler``: the shared arrays are sent to every worker
    once, each task returns plain arrays, and the per-face seeds make the results those of a local run."""
    try:
        from distributed import Client
    except ImportError:
        raise ValueError("sending the triangle-wise stage to a Dask scheduler needs Dask: "
                         "pip install dask distributed") from None
    try:
        client = Client(scheduler, set_as_default=False, timeout=DASK_CONNECT_SECONDS)
    except (OSError, TimeoutError) as error:
        raise ValueError(f"cannot reach the Dask scheduler at {scheduler}: {error}") from None
    futures = []
    try:
        [shared] = client.scatter([state], broadcast=True)
        futures = [client.submit(task, shared, chunk, pure=False) for chunk in chunks]
        pending, last = set(futures), time.monotonic()
        while pending:
            finished = [future for future in pending if future.done()]
            if not finished:
                time.sleep(min(0.02, WAIT_SECONDS))
                if time.monotonic() - last >= WAIT_SECONDS:
                    last = time.monotonic()
                    yield None
                continue
            for future in finished:
                pending.discard(future)
                last = time.monotonic()
                yield future.result()  # a task that failed raises its error here
    finally:
        for future in futures:
            future.cancel()
        client.close()


def _chunk_call(job):
    """A pool worker's body: ``job = (task, chunk)`` on the state :func:`_worker_init` received."""
    task, chunk = job
    return task(_WORKER_STATE, chunk)
