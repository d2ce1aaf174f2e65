"""``batch`` under faults, on a real LocalCluster of 2 worker processes: a child or a worker killed mid-asset is
retried and the asset completes; Ctrl-C (SIGINT) stops everything and leaves no partial files."""
import json
import signal
import subprocess
import sys
import time

import pytest

from test_batch import FAST_ARGS, leftovers, read_manifest, spot_patch_obj  # noqa: E402  (tests/ is on sys.path)

pytest.importorskip("distributed")
pytest.importorskip("bpy")
psutil = pytest.importorskip("psutil")

pytestmark = pytest.mark.bpy


def start_batch(*args):
    return subprocess.Popen([sys.executable, "-m", "perceptual_uv", "batch", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def optimize_child(batch, *, timeout=120):
    """The first ``optimize`` child process below the batch process, once its log shows the triangle stage."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        assert batch.poll() is None, batch.communicate()[1][-3000:]
        for proc in psutil.Process(batch.pid).children(recursive=True):
            try:
                if "optimize" in proc.cmdline():
                    return proc
            except psutil.NoSuchProcess:
                continue
        time.sleep(0.2)
    raise AssertionError("no optimize child started")


def wait_for_log(path, text, *, timeout=120):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if path.is_file() and text in path.read_text():
            return
        time.sleep(0.2)
    raise AssertionError(f"{text!r} never appeared in {path}")


@pytest.mark.parametrize("victim", ["child", "worker"])
def test_killed_child_or_worker_is_retried_and_the_asset_completes(tmp_path, victim):
    spot_patch_obj(tmp_path / "lib", "spot.obj")
    out = tmp_path / "out"
    batch = start_batch(str(tmp_path / "lib"), "--out", str(out), "--workers", "2", "--retries", "1", *FAST_ARGS)
    child = optimize_child(batch)
    wait_for_log(out / "logs" / "spot.obj.log", "[triangle]")
    worker = child.parent()
    (worker if victim == "worker" else child).send_signal(signal.SIGKILL)
    if victim == "worker":  # the orphaned child is killed with its worker (PR_SET_PDEATHSIG)
        child.wait(timeout=60)
    _, err = batch.communicate(timeout=600)
    assert batch.returncode == 0, err[-3000:]
    assert "spot.obj: attempt 1 failed (" in err and "retrying" in err
    if victim == "child":
        assert "killed by signal 9 (SIGKILL)" in err
    else:
        assert "KilledWorker" in err
    [entry] = read_manifest(out)
    assert entry["status"] == "done" and entry["attempts"] == 2 and entry["asset"] == "spot.obj"
    assert sorted(p.name for p in (out / "spot").iterdir()) == ["spot.blend", "spot.report.json",
                                                                 "spot_texture_perceptual.png"]
    assert json.loads((out / "spot" / "spot.report.json").read_text())["resolution"] == [64, 64]
    assert leftovers(out) == []


def test_sigint_stops_the_batch_and_leaves_no_partial_files(tmp_path):
    lib, out = tmp_path / "lib", tmp_path / "out"
    spot_patch_obj(lib / "a", "spot.obj")
    spot_patch_obj(lib / "b", "other.obj", above=0.8)
    # An earlier result of a/spot.obj made with other settings: set aside while the new one runs, then put back.
    (out / "a" / "spot").mkdir(parents=True)
    (out / "a" / "spot" / "spot.blend").write_text("earlier result")
    earlier = {"asset": "a/spot.obj", "key": "other settings", "status": "done", "outputs": ["a/spot/spot.blend"]}
    (out / "manifest.jsonl").write_text(json.dumps(earlier) + "\n")
    batch = start_batch(str(lib), "--out", str(out), "--workers", "2", *FAST_ARGS)
    child = optimize_child(batch)
    wait_for_log(out / "logs" / "a" / "spot.obj.log", "[triangle]")
    children = [p for p in psutil.Process(batch.pid).children(recursive=True) if "optimize" in p.cmdline()]
    assert child in children
    batch.send_signal(signal.SIGINT)
    _, err = batch.communicate(timeout=120)
    assert batch.returncode == 130, err[-3000:]
    assert err.strip().splitlines()[-1] == "perceptual_uv: cancelled" and "Traceback" not in err
    gone, alive = psutil.wait_procs(children, timeout=30)
    assert alive == []
    assert leftovers(out) == []
    assert (out / "a" / "spot" / "spot.blend").read_text() == "earlier result"
    assert sorted(p.name for p in (out / "a" / "spot").iterdir()) == ["spot.blend"]
    assert not (out / "b").exists()
    assert read_manifest(out) == [earlier]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["counts"]["done"] == 0
