# SPDX-License-Identifier: GPL-3.0-or-later
"""The Dask task of one asset, run in a worker process: one ``optimize`` child process, its result published.

The child writes into the asset's output folder, which exists only while the child runs or once it succeeded:
an earlier result in that folder is moved aside to ``.NAME.previous`` first, deleted when the new one is
complete and put back when it is not. A timeout or a cancelled run terminates the child (SIGTERM: it removes
its own partial files, exit 130), then kills it after a grace period. On Linux the child is killed (SIGKILL)
when the worker thread that started it dies, so a killed worker leaves no orphan running: an orphan told to
stop with SIGTERM could miss it (a signal that arrives while numba compiles a kernel is lost) and go on writing
into the folder of the next attempt.
"""
import contextlib
import datetime
import json
import os
import pathlib
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

__all__ = ["optimize_command", "run_asset", "cancel_children", "restore_previous", "previous_folder",
           "TERMINATE_GRACE_S"]

TERMINATE_GRACE_S = 20.0
_POLL_S = 0.5
_CHILDREN = {}  # pid -> (run id, Popen) of the optimize children running in this worker process
_CANCELLED_RUNS = set()
_LOCK = threading.Lock()
PACKAGE_DIR = pathlib.Path(__file__).resolve().parents[1]


def optimize_command(input_path, out, report, options, *, blender=None):
    """The command line of one asset's ``optimize`` run.

    Parameters
    ----------
    input_path, out, report : path-like
        The model, the output model and the report path.
    options : list of str
        The optimize options (``--epsilon 0.01 ...``).
    blender : str, optional
        A Blender executable: run ``blender -b --factory-startup --python <package>/cli.py -- optimize ...``.
        Default: ``python -m perceptual_uv optimize ...`` with this Python (the bpy module).

    Returns
    -------
    list of str
    """
    arguments = ["optimize", str(input_path), "--out", str(out), "--report", str(report), *options]
    if blender:
        return [str(blender), "-b", "--factory-startup", "--python", str(PACKAGE_DIR / "cli.py"), "--", *arguments]
    return [sys.executable, "-m", "perceptual_uv", *arguments]


def _die_with_parent():
    """preexec_fn: SIGKILL this child when the thread that started it dies (Linux prctl PR_SET_PDEATHSIG)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)
    except (OSError, AttributeError):
        pass


def previous_folder(folder):
    """Where an earlier result of ``folder`` waits while a new one is made."""
    folder = pathlib.Path(folder)
    return folder.with_name(f".{folder.name}.previous")


def restore_previous(folder, *, base=None):
    """Undo an unfinished attempt on ``folder``: remove it and put an earlier result back if one was set aside.

    Parameters
    ----------
    folder : path-like
        The asset's output folder.
    base : path-like, optional
        The batch's output folder: parent folders left empty below it are removed too.
    """
    folder = pathlib.Path(folder)
    previous = previous_folder(folder)
    shutil.rmtree(folder, ignore_errors=True)
    if previous.is_dir():
        os.replace(previous, folder)
    elif base is not None:
        parent, base = folder.parent, pathlib.Path(base)
        while parent != base and base in parent.parents:
            try:
                parent.rmdir()
            except OSError:  # not empty (another asset's folder), or already gone
                break
            parent = parent.parent


def cancel_children(run_id):
    """Terminate this worker's optimize children of batch ``run_id`` and refuse its later tasks (``client.run``).

    Returns
    -------
    int
        How many children were terminated.
    """
    with _LOCK:
        _CANCELLED_RUNS.add(run_id)
        children = [proc for rid, proc in _CHILDREN.values() if rid == run_id]
    for proc in children:
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
    return len(children)


def _stop(proc):
    """SIGTERM, then SIGKILL after the grace period; returns the exit code."""
    with contextlib.suppress(ProcessLookupError):
        proc.terminate()
    try:
        return proc.wait(TERMINATE_GRACE_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def _last_line(log_path):
    """The last non-empty line of a log file ('' when there is none)."""
    try:
        with open(log_path, "rb") as stream:
            stream.seek(0, os.SEEK_END)
            stream.seek(max(0, stream.tell() - 8192))
            lines = [line.strip() for line in stream.read().decode("utf-8", "replace").splitlines()]
    except OSError:
        return ""
    lines = [line for line in lines if line]
    return lines[-1] if lines else ""


def _reason(log_path):
    """The child's one-line error without the program prefix."""
    line = _last_line(log_path)
    for prefix in ("perceptual_uv: error: ", "perceptual_uv: "):
        if line.startswith(prefix):
            return line[len(prefix):]
    return line


def _files(folder, base):
    return sorted(p.relative_to(base).as_posix() for p in pathlib.Path(folder).rglob("*") if p.is_file())


def run_asset(job, attempt):
    """Optimize one asset in a child process and publish its outputs: the body of a Dask task.

    Parameters
    ----------
    job : dict
        ``run_id``, ``input``, ``folder`` (the asset's output folder), ``name`` (output stem), ``format``
        ("blend", "glb" or "fbx"), ``options`` (optimize options), ``timeout`` (seconds or None), ``blender`` (path or
        None), ``log`` (log file of the child's output), ``base`` (the batch's output folder).
    attempt : int
        1 for the first attempt.

    Returns
    -------
    dict
        ``status``: "done", "bad_input" (exit 2, not worth retrying), "error" (crash, killed, timeout: worth
        retrying) or "cancelled"; ``returncode``, ``error`` (one line), ``time_s``, ``report`` (the JSON report
        or None), ``outputs`` (paths relative to ``base``), ``output_bytes``, ``attempt``, ``worker`` (host:pid).
    """
    started = time.time()
    result = {"started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "attempt": attempt, "worker": f"{socket.gethostname()}:{os.getpid()}", "report": None, "outputs": [],
              "output_bytes": 0, "returncode": None, "error": ""}
    if job["run_id"] in _CANCELLED_RUNS:
        return dict(result, status="cancelled", time_s=0.0)
    folder, base = pathlib.Path(job["folder"]), pathlib.Path(job["base"])
    previous = previous_folder(folder)
    if previous.is_dir():  # an attempt that died before cleaning up: its earlier result goes back first
        restore_previous(folder, base=base)
    if folder.exists():
        os.replace(folder, previous)
    folder.mkdir(parents=True)
    out = folder / f"{job['name']}.{job['format']}"
    report_path = folder / f"{job['name']}.report.json"
    log_path = pathlib.Path(job["log"])
    log_path.parent.mkdir(parents=True, exist_ok=True)
    command = optimize_command(job["input"], out, report_path, job["options"], blender=job.get("blender"))
    timed_out = False
    try:
        with open(log_path, "w" if attempt == 1 else "a") as log:
            log.write(f"# attempt {attempt} on {result['worker']}: {' '.join(command)}\n")
            log.flush()
            with _LOCK:
                if job["run_id"] in _CANCELLED_RUNS:
                    raise _Cancelled
                proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                        preexec_fn=_die_with_parent if sys.platform == "linux" else None)
                _CHILDREN[proc.pid] = (job["run_id"], proc)
            try:
                deadline = None if job.get("timeout") is None else started + job["timeout"]
                while True:
                    try:
                        code = proc.wait(_POLL_S)
                        break
                    except subprocess.TimeoutExpired:
                        if deadline is not None and time.time() > deadline:
                            timed_out = True
                            code = _stop(proc)
                            break
            finally:
                if proc.poll() is None:  # an exception in this thread: never leave the child behind
                    _stop(proc)
                with _LOCK:
                    _CHILDREN.pop(proc.pid, None)
    except _Cancelled:
        code = None
    except BaseException:
        restore_previous(folder, base=base)
        raise
    result["returncode"] = code
    result["time_s"] = round(time.time() - started, 3)
    if job["run_id"] in _CANCELLED_RUNS:
        restore_previous(folder, base=base)
        return dict(result, status="cancelled", error="cancelled")
    if code == 0 and out.is_file() and report_path.is_file():
        try:
            result["report"] = json.loads(report_path.read_text())
        except ValueError as error:
            restore_previous(folder, base=base)
            return dict(result, status="error", error=f"unreadable report: {error}")
        shutil.rmtree(previous, ignore_errors=True)
        result["outputs"] = _files(folder, base)
        result["output_bytes"] = sum((base / p).stat().st_size for p in result["outputs"])
        return dict(result, status="done")
    restore_previous(folder, base=base)
    if timed_out:
        return dict(result, status="error", error=f"timed out after {job['timeout']:g} s (killed)")
    if code == 2:
        return dict(result, status="bad_input", error=_reason(log_path) or "bad input")
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = "unknown"
        return dict(result, status="error", error=f"killed by signal {-code} ({name})")
    if code == 0:
        return dict(result, status="error", error="exit code 0 but the output or the report is missing")
    return dict(result, status="error", error=_reason(log_path) or f"exit code {code}")


class _Cancelled(Exception):
    pass
