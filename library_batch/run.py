# SPDX-License-Identifier: GPL-3.0-or-later
"""The batch orchestrator: plan the assets, run the missing ones on Dask, record them, summarize.

One code path for a ``LocalCluster`` of worker processes (one thread each) and for a scheduler address. Each
asset is one Dask task (:func:`library_batch.task.run_asset`) that runs ``optimize`` in a child process. This
process never imports bpy.
"""
import contextlib
import datetime
import json
import logging
import os
import pathlib
import shutil
import signal
import sys
import threading
import time
import uuid

from .inputs import external_files, find_models, plan_assets
from .manifest import Manifest, image_memory, summarize, write_summary
from .task import TERMINATE_GRACE_S, cancel_children, previous_folder, restore_previous, run_asset

__all__ = ["INSTALL_HINT", "batch_settings", "optimize_options", "run_batch"]

INSTALL_HINT = "the batch command needs Dask: pip install dask distributed"
PROGRESS_EVERY_S = 5.0
_PACKAGE_DIR = pathlib.Path(__file__).resolve().parents[1]


def _log(message):
    print(message, file=sys.stderr, flush=True)


def _version():
    import tomllib

    try:
        with open(_PACKAGE_DIR / "blender_manifest.toml", "rb") as stream:
            return str(tomllib.load(stream).get("version", "unknown"))
    except (OSError, ValueError):
        return "unknown"


def batch_settings(args):
    """The settings that change an asset's result (part of its content key), from the parsed ``batch`` args."""
    return {"version": _version(), "format": args.format, "object": args.object, "uv": args.uv,
            "epsilon": args.epsilon, "target_cost": None if args.resolution is not None else args.cost,
            "cost_measure": None if args.resolution is not None else args.cost_measure,
            "resolution": args.resolution, "iterations": args.iterations, "screen_pixels": args.screen_pixels,
            "max_screen_pixels": args.max_screen_pixels, "margin": args.margin, "seed": args.seed,
            "role_costs": sorted(args.cost_for), "keep_stacks": args.keep_stacks, "square_images": args.square_images}


def optimize_options(args):
    """The ``optimize`` options of every asset's run, from the parsed ``batch`` args."""
    options = ["--epsilon", repr(args.epsilon)]
    options += (["--resolution", str(args.resolution)] if args.resolution is not None else
                ["--cost", repr(args.cost), "--cost-measure", args.cost_measure])
    options += ["--iterations", str(args.iterations), "--screen-pixels", str(args.screen_pixels),
                "--max-screen-pixels", str(args.max_screen_pixels), "--margin", str(args.margin),
                "--workers", str(args.workers), "--seed", str(args.seed)]
    if args.fresh:
        options.append("--fresh")
    if not args.keep_stacks:
        options.append("--unstack")
    if args.square_images:
        options.append("--square-images")
    for role, cost in args.cost_for:
        options += ["--cost-for", f"{role}={cost!r}"]
    if args.object:
        options += ["--object", args.object]
    if args.uv:
        options += ["--uv", args.uv]
    return options


def _now():
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _duration(seconds):
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds // 60 % 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


def _size(count):
    for unit in ("B", "KiB", "MiB", "GiB"):
        if count < 1024 or unit == "GiB":
            return f"{count:.0f} {unit}" if unit == "B" else f"{count:.1f} {unit}"
        count /= 1024


def _one_line(error):
    text = f"{type(error).__name__}: {error}".strip()
    return text.splitlines()[0] if text else type(error).__name__


def recover(out):
    """Undo what a batch killed without cleaning up left in ``out``: earlier results set aside are put back
    (replacing the unfinished attempt) and temporary files are removed."""
    out = pathlib.Path(out)
    for previous in sorted(out.rglob(".*.previous")):
        if previous.is_dir():
            restore_previous(previous.with_name(previous.name[1:-len(".previous")]))
    for partial in list(out.rglob(".*.partial*")):
        if partial.is_dir():
            shutil.rmtree(partial, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                partial.unlink()


def _input_bytes(path):
    files = [path] + [p for p in external_files(path) if p.is_file()]
    return sum(p.stat().st_size for p in files)


def _copy_result(source_entry, asset, out, fmt):
    """Copy a finished asset's outputs to a duplicate's folder, renamed after it; returns the new output list."""
    source = out / source_entry["folder"]
    source_name = source.name
    staging = asset.folder.with_name(f".{asset.name}.partial")
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(source, staging)
    for suffix in (f".{fmt}", ".report.json"):
        if (staging / f"{source_name}{suffix}").exists():
            os.replace(staging / f"{source_name}{suffix}", staging / f"{asset.name}{suffix}")
    report_path = staging / f"{asset.name}.report.json"
    if report_path.is_file():
        report = json.loads(report_path.read_text())
        report.update(input=str(asset.input), output=str(asset.folder / f"{asset.name}.{fmt}"))
        _move_image_paths(report, asset.folder)
        report_path.write_text(json.dumps(report, indent=2) + "\n")
    if asset.folder.exists():
        os.replace(asset.folder, previous_folder(asset.folder))
    os.replace(staging, asset.folder)
    shutil.rmtree(previous_folder(asset.folder), ignore_errors=True)
    return sorted(p.relative_to(out).as_posix() for p in asset.folder.rglob("*") if p.is_file())


def _move_image_paths(report, folder):
    """Point a report's image files (the base colour's, every map's, each texture's of a report over several)
    into ``folder``, where the asset's outputs were moved."""
    def moved(path):
        return str(folder / pathlib.Path(path).name) if path else path

    if "image_file" in report:
        report["image_file"] = moved(report["image_file"])
    if "image_files" in report:
        report["image_files"] = [moved(path) for path in report["image_files"]]
    for entry in report.get("maps", []):
        if "new_image_file" in entry:
            entry["new_image_file"] = moved(entry["new_image_file"])
    for texture in report.get("textures", []):
        _move_image_paths(texture, folder)


class _Progress:
    """One overall progress display: a tqdm bar when tqdm is installed, else a line on stderr every 5 s."""

    def __init__(self, total):
        self.total, self.started, self.last = total, time.time(), 0.0
        try:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="asset", file=sys.stderr, dynamic_ncols=True)
        except ImportError:
            self.bar = None

    def update(self, *, finished, done, bad, failed, running, retrying, force=False):
        waiting = self.total - finished - running
        text = f"{done} done, {bad} bad input, {failed} failed, {running} running, {max(waiting, 0)} waiting"
        if retrying:
            text += f", {retrying} retried"
        if self.bar is not None:
            self.bar.n = finished
            self.bar.set_postfix_str(text, refresh=True)
            return
        now = time.time()
        if not force and now - self.last < PROGRESS_EVERY_S:
            return
        self.last = now
        elapsed = now - self.started
        eta = _duration(elapsed / finished * (self.total - finished)) if finished else "?"
        _log(f"batch: {finished}/{self.total} finished ({text}), {_duration(elapsed)} elapsed, ETA {eta}")

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _start_client(args, n_workers):
    """A distributed Client on a new LocalCluster, or on the scheduler at ``args.scheduler``."""
    from distributed import Client, LocalCluster

    if args.scheduler:
        try:
            return Client(args.scheduler, timeout="30s"), None
        except (OSError, ValueError) as error:  # unreachable (TimeoutError is an OSError) or a malformed address
            raise ValueError(f"cannot connect to the Dask scheduler at {args.scheduler}: {_one_line(error)}") from None
    # The worker processes inherit an ignored SIGINT: a Ctrl-C in the terminal reaches the whole process group,
    # and only this process acts on it (it stops the children and closes the cluster), without worker tracebacks.
    in_main_thread = threading.current_thread() is threading.main_thread()
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if in_main_thread else None
    try:
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, memory_limit=0,
                               silence_logs=logging.ERROR)
    finally:
        if in_main_thread:
            signal.signal(signal.SIGINT, handler)
    return Client(cluster), cluster


def _dashboard(client):
    try:
        if "dashboard" in client.scheduler_info().get("services", {}):
            return client.dashboard_link
    except Exception:  # an address we cannot tell is only a missing nicety
        return None
    return None


def run_batch(args):
    """``batch``: optimize every model of the INPUT arguments on Dask; see README "Batch runs".

    Parameters
    ----------
    args : argparse.Namespace
        From :func:`perceptual_uv.cli.parse_args`.

    Returns
    -------
    int
        0 when every asset has its output, 1 when some failed or are bad inputs (the summary lists them).

    Raises
    ------
    ValueError
        Dask missing, inputs that name nothing, an output folder that cannot be written (exit code 2).
    KeyboardInterrupt
        Ctrl-C or SIGTERM, after the running assets were stopped and their partial outputs removed.
    """
    try:
        import dask  # noqa: F401
        import distributed  # noqa: F401
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    started = time.time()
    out = pathlib.Path(args.out).resolve()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"cannot create the output folder {out}: {error.strerror or error}") from None
    if not os.access(out, os.W_OK):
        raise ValueError(f"cannot write into the output folder {out}")
    models, roots = find_models(args.inputs, out=out)
    with _exclusive(out):
        return _run_locked(args, out, models, roots, started)


@contextlib.contextmanager
def _exclusive(out):
    """Hold ``OUT/.batch.lock``: one batch at a time per output folder (a nightly run that overlaps the last)."""
    try:
        import fcntl
    except ImportError:  # Windows: no lock
        yield
        return
    with open(out / ".batch.lock", "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise ValueError(f"another batch is running on {out}") from None
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _run_locked(args, out, models, roots, started):
    """:func:`run_batch` once it holds the output folder."""
    recover(out)
    settings = batch_settings(args)
    assets = plan_assets(models, roots, out=out, settings=settings)
    manifest = Manifest(out)
    if manifest.ignored_lines:
        _log(f"batch: {manifest.ignored_lines} unreadable line(s) in {manifest.path} ignored")
    run_id = uuid.uuid4().hex
    skipped = [a for a in assets if manifest.finished(a.id, a.key)]
    todo = [a for a in assets if not manifest.finished(a.id, a.key)]
    by_key = {}
    for asset in todo:
        by_key.setdefault(asset.key, []).append(asset)
    sources = {}  # key -> a done entry whose outputs exist (this run's or an earlier one's)
    for asset in skipped:
        entry = manifest.entries[asset.id]
        if entry["status"] == "done":
            sources.setdefault(asset.key, entry)
    _log(f"batch: {len(assets)} assets, {len(skipped)} already finished, {len(todo)} to run "
         f"({len(todo) - len(by_key)} duplicates of others) -> {out}")

    def entry_for(asset, result, *, duplicate_of=None):
        report = result.get("report")
        before, after = image_memory(report)
        return {"asset": asset.id, "input": str(asset.input), "key": asset.key, "settings": settings,
                "status": result["status"], "folder": asset.folder.relative_to(out).as_posix(),
                "outputs": result.get("outputs", []), "output_bytes": result.get("output_bytes", 0),
                "input_bytes": _input_bytes(asset.input), "started": result.get("started"), "finished": _now(),
                "time_s": result.get("time_s"), "attempts": result.get("attempt"), "worker": result.get("worker"),
                "relative_cost": report.get("relative_cost") if report else None,
                "resolution": report.get("resolution") if report else None,
                "image_bytes_before": before, "image_bytes_after": after, "error": result.get("error", ""),
                "duplicate_of": duplicate_of, "log": result.get("log")}

    def finish_duplicates(primary, entry):
        """Give the waiting duplicates of ``primary`` its result: copies of its outputs, or its failure.

        Returns the duplicates' manifest entries."""
        entries = []
        for asset in by_key.pop(primary.key, [])[1:]:
            result = {"status": entry["status"], "error": entry["error"], "time_s": 0.0, "attempt": 0,
                      "started": _now(), "report": None}
            if entry["status"] == "done":
                try:
                    result["outputs"] = _copy_result(entry, asset, out, args.format)
                    result["output_bytes"] = sum((out / p).stat().st_size for p in result["outputs"])
                    report_file = asset.folder / f"{asset.name}.report.json"
                    result["report"] = json.loads(report_file.read_text()) if report_file.is_file() else None
                except OSError as error:
                    result.update(status="failed", error=f"could not copy {primary.id}'s outputs: {error}")
            else:
                result["error"] = f"same content as {primary.id}: {entry['error']}"
            entries.append(entry_for(asset, result, duplicate_of=primary.id))
            manifest.append(entries[-1])
        return entries

    counts = {"done": 0, "bad_input": 0, "failed": 0, "retried": 0, "finished": 0}

    def count(entries):
        for entry in entries:
            counts[entry["status"]] += 1
            counts["finished"] += 1

    # Duplicates of results that already exist are copied without a run.
    for key in list(by_key):
        if key in sources:
            source_asset = next(a for a in skipped if manifest.entries[a.id] is sources[key])
            by_key[key] = [source_asset] + by_key[key]
            count(finish_duplicates(source_asset, sources[key]))
    primaries = [group[0] for group in by_key.values()]
    if not primaries:
        return _finish(args, assets, manifest, out, started, skipped, run_id, cluster_info=None)

    jobs = {}
    for asset in primaries:
        jobs[asset.id] = {"run_id": run_id, "input": str(asset.input), "folder": str(asset.folder),
                          "name": asset.name, "format": args.format, "options": optimize_options(args),
                          "timeout": args.timeout, "blender": args.blender, "base": str(out),
                          "log": str(out / "logs" / f"{asset.relative.as_posix()}.log")}
    cpu = os.cpu_count() or 1
    n_workers = args.dask_workers or max(1, cpu // max(1, args.workers or cpu))
    import dask

    client = cluster = None
    pending = {}  # future -> (asset, attempt, submitted at)
    progress = None
    try:
        # A worker that dies takes its task with it: count that as one attempt here (our --retries), not as
        # Dask's silent reschedule; one task per worker thread at a time.
        with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                              "distributed.scheduler.worker-saturation": 1.0}):
            client, cluster = _start_client(args, n_workers)
        workers = len(client.scheduler_info().get("workers", {}))
        where = f"scheduler {args.scheduler}" if args.scheduler else "a local cluster"
        _log(f"batch: {workers} Dask worker(s) on {where}")
        dashboard = _dashboard(client)
        if dashboard:
            _log(f"batch: dashboard at {dashboard}")

        def submit(asset, attempt):
            future = client.submit(run_asset, jobs[asset.id], attempt, pure=False,
                                   key=f"perceptual-uv-{run_id[:8]}-{attempt}-{asset.id}")
            pending[future] = (asset, attempt, _now())

        for asset in primaries:
            submit(asset, 1)
        progress = _Progress(len(todo))
        running, last_poll = 0, 0.0
        while pending:
            finished = [f for f in pending if f.done()]
            for future in finished:
                asset, attempt, submitted = pending.pop(future)
                try:
                    result = future.result()
                except Exception as error:  # KilledWorker (the worker died), a lost connection, a task bug
                    result = {"status": "error", "error": _one_line(error), "attempt": attempt, "time_s": None,
                              "started": submitted}
                result["log"] = os.path.relpath(jobs[asset.id]["log"], out)
                if result["status"] in ("error", "cancelled") and attempt <= args.retries:
                    _log(f"batch: {asset.id}: attempt {attempt} failed ({result['error']}); retrying")
                    counts["retried"] += 1
                    submit(asset, attempt + 1)
                    continue
                if result["status"] in ("error", "cancelled"):
                    result["status"] = "failed"
                    _log(f"batch: {asset.id}: failed after {attempt} attempt(s): {result['error']}")
                elif result["status"] == "bad_input":
                    _log(f"batch: {asset.id}: bad input: {result['error']}")
                entry = entry_for(asset, result)
                manifest.append(entry)
                count([entry] + finish_duplicates(asset, entry))
            if finished or time.time() - last_poll >= 1.0:
                with contextlib.suppress(Exception):
                    keys = {f.key for f in pending}
                    running = sum(k in keys for ks in client.processing().values() for k in ks)
                last_poll = time.time()
            progress.update(finished=counts["finished"], done=counts["done"], bad=counts["bad_input"],
                            failed=counts["failed"], running=running, retrying=counts["retried"],
                            force=bool(finished))
            time.sleep(0.2)
        progress.close()
        cluster_info = {"scheduler": args.scheduler, "workers": workers, "dashboard": dashboard}
    except KeyboardInterrupt:
        for number in (signal.SIGINT, signal.SIGTERM):  # the clean-up below is bounded; let it finish
            signal.signal(number, signal.SIG_IGN)
        if progress is not None:
            progress.close()
        _log("batch: interrupted: stopping the running assets")
        _stop(client, pending, run_id)
        client = _close(client, cluster)
        cluster = None
        for asset, _, _ in pending.values():
            _clean_unfinished(asset, manifest)
        recover(out)
        _finish(args, assets, manifest, out, started, skipped, run_id, cluster_info=None, interrupted=True)
        raise
    finally:
        _close(client, cluster)
    return _finish(args, assets, manifest, out, started, skipped, run_id, cluster_info=cluster_info)


def _stop(client, pending, run_id):
    """Terminate the running children of this run on every worker and wait for their tasks to clean up."""
    if client is None:
        return
    from distributed import wait

    with contextlib.suppress(Exception):
        client.run(cancel_children, run_id)
    with contextlib.suppress(Exception):
        wait(list(pending), timeout=TERMINATE_GRACE_S + 10)
    with contextlib.suppress(Exception):
        client.cancel(list(pending))


def _quiet_cluster_logs():
    """Let Dask's ``distributed`` log nothing below CRITICAL in this process (a worker, a nanny or the batch)."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL)


def _close(client, cluster):
    """Close the client and, when the batch made it, the cluster; returns None.

    Closing our own cluster first quiets its processes' ``distributed`` logs: a worker's heartbeat that meets the
    scheduler already closed logs its failure with a traceback at ERROR level, above the cluster's
    ``silence_logs``, and its stderr is the batch's. A cluster the batch only connected to (``--scheduler``) is
    left as it is.
    """
    if client is not None and cluster is not None:
        with contextlib.suppress(Exception):
            client.run(_quiet_cluster_logs)
        with contextlib.suppress(Exception):
            client.run(_quiet_cluster_logs, nanny=True)
        _quiet_cluster_logs()  # the scheduler of a LocalCluster runs in this process
    for thing in (client, cluster):
        if thing is not None:
            with contextlib.suppress(Exception):
                thing.close()
    return None


def _clean_unfinished(asset, manifest):
    """Remove an interrupted asset's partial outputs; an earlier result stays (or is put back)."""
    entry = manifest.entries.get(asset.id)
    if (not previous_folder(asset.folder).is_dir() and entry and entry["status"] == "done"
            and manifest.outputs_exist(entry)):
        return  # an earlier result its task had not moved aside yet
    restore_previous(asset.folder, base=manifest.folder)


def _finish(args, assets, manifest, out, started, skipped, run_id, *, cluster_info, interrupted=False):
    """Write and print the summary; returns the exit code."""
    entries = [manifest.entries[a.id] for a in assets
               if a.id in manifest.entries and manifest.entries[a.id].get("key") == a.key]
    total = time.time() - started
    summary = summarize(entries, run={"run_id": run_id, "started": datetime.datetime.fromtimestamp(
        started, datetime.timezone.utc).isoformat(timespec="seconds"), "total_time_s": round(total, 3),
        "interrupted": interrupted, "output_folder": str(out), "inputs": list(args.inputs),
        "settings": batch_settings(args), "skipped": len(skipped), "cluster": cluster_info})
    summary["counts"]["assets"] = len(assets)
    summary["counts"]["not_run"] = len(assets) - len(entries)
    json_path, csv_path = write_summary(out, summary, entries)
    counts = summary["counts"]
    earlier = sum(manifest.entries[a.id]["status"] == "done" for a in skipped)
    print(f"batch: {counts['assets']} assets: {counts['done']} done ({earlier} from earlier runs, "
          f"{counts['duplicates']} duplicates), {counts['bad_input']} bad input, {counts['failed']} failed"
          + (f", {counts['not_run']} not run" if counts["not_run"] else "") + f", in {_duration(total)}")
    memory = summary["image_memory"]
    if memory["assets"]:
        print(f"image memory: {_size(memory['before_bytes'])} -> {_size(memory['after_bytes'])} "
              f"({memory['ratio']:.3f}) over {memory['assets']} assets")
    if summary["slowest"]:
        print("slowest: " + ", ".join(f"{s['asset']} {s['time_s']:.1f} s" for s in summary["slowest"]
                                      if s["time_s"] is not None))
    for problem in summary["problems"]:
        print(f"{problem['status']}: {problem['asset']}: {problem['error']}")
    print(f"summary: {json_path} {csv_path}")
    print(f"manifest: {manifest.path}")
    return 0 if counts["done"] == counts["assets"] else 1
