"""The ``batch`` command (issue 25): inputs, content keys, manifest, and a real run on a 2-worker LocalCluster over
a folder with a duplicate and a bad file, then a rerun that resumes."""
import json
import pathlib
import shutil
import subprocess
import sys
import time

import pytest

from perceptual_uv.cli import parse_args, UsageError
from perceptual_uv.library_batch.inputs import content_key, external_files, find_models, plan_assets
from perceptual_uv.library_batch.manifest import Manifest, image_memory, summarize
from perceptual_uv.library_batch.task import optimize_command

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPOT = ROOT / "tests" / "data" / "spot"
# The fastest settings of the CLI tests (test_cli_optimize.py) and a fixed small resolution.
FAST_ARGS = ["--iterations", "10", "--screen-pixels", "32", "--max-screen-pixels", "32", "--resolution", "64"]


def spot_patch_obj(folder, name, *, above=0.9):
    """Write the bundled spot cut to the faces above a height (OBJ y; ~110 triangles at 0.9) into ``folder``, with
    its material library and texture; no bpy needed. Returns the .obj path."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vertices, uvs, faces = [], [], []
    for line in (SPOT / "spot_triangulated.obj").read_text().splitlines():
        words = line.split()
        if words and words[0] == "v":
            vertices.append(line)
        elif words and words[0] == "vt":
            uvs.append(line)
        elif words and words[0] == "f":
            faces.append([tuple(int(i) for i in corner.split("/")[:2]) for corner in words[1:]])
    kept = [f for f in faces if all(float(vertices[v - 1].split()[2]) > above for v, _ in f)]
    vmap, tmap = {}, {}
    for face in kept:
        for v, t in face:
            vmap.setdefault(v, len(vmap) + 1)
            tmap.setdefault(t, len(tmap) + 1)
    lines = ["mtllib spot.mtl", "usemtl spot", *(vertices[v - 1] for v in vmap), *(uvs[t - 1] for t in tmap)]
    lines += ["f " + " ".join(f"{vmap[v]}/{tmap[t]}" for v, t in face) for face in kept]
    path = folder / name
    path.write_text("\n".join(lines) + "\n")
    for extra in ("spot.mtl", "spot_texture.png"):
        shutil.copy2(SPOT / extra, folder / extra)
    return path


def make_library(root):
    """a/spot.obj, b/spot_copy.obj (the same bytes: a duplicate) and bad.obj (not a model)."""
    spot_patch_obj(root / "a", "spot.obj")
    spot_patch_obj(root / "b", "spot_copy.obj")
    (root / "bad.obj").write_text("this is not an OBJ file \x00\x01\n")
    return root


def run_batch_cli(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "perceptual_uv", "batch", *args], capture_output=True, text=True,
                          timeout=timeout)


def read_manifest(out):
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def leftovers(out):
    """Temporary or set-aside files anywhere under ``out``."""
    return [p for p in out.rglob("*") if ".partial" in p.name or p.name.endswith(".previous")]


# --- inputs, keys, layout ------------------------------------------------------------------------------------

def test_find_models_takes_files_folders_and_globs_and_skips_the_output_folder(tmp_path):
    lib = tmp_path / "lib"
    for rel in ("x/a.obj", "x/y/b.glb", "c.gltf", "d.blend", "notes.txt", ".hidden/e.obj", "x/f.blend1"):
        (lib / rel).parent.mkdir(parents=True, exist_ok=True)
        (lib / rel).write_text("{}")
    (lib / "out" / "old.blend").parent.mkdir()
    (lib / "out" / "old.blend").write_text("")
    models, roots = find_models([str(lib)], out=lib / "out")
    assert [p.relative_to(lib).as_posix() for p in models] == ["c.gltf", "d.blend", "x/a.obj", "x/y/b.glb"]
    assert roots == [lib.resolve()]
    models, _ = find_models([str(lib / "x" / "**" / "*.glb"), str(lib / "d.blend"), str(lib / "d.blend")],
                            out=tmp_path / "o")
    assert [p.name for p in models] == ["b.glb", "d.blend"]
    for bad, message in (([str(lib / "nope")], "no such file"), ([str(lib / "notes.txt")], "unsupported"),
                         ([str(lib / "*.stl")], "no .blend")):
        with pytest.raises(ValueError, match=message):
            find_models(bad, out=tmp_path / "o")


def test_content_key_follows_bytes_external_files_and_settings_not_names(tmp_path):
    a = spot_patch_obj(tmp_path / "a", "one.obj")
    b = spot_patch_obj(tmp_path / "b", "two.obj")
    assert [p.name for p in external_files(a)] == ["spot.mtl", "spot_texture.png"]
    settings = {"epsilon": 0.01}
    assert content_key(a, settings) == content_key(b, settings)
    assert content_key(a, settings) != content_key(a, {"epsilon": 0.02})
    with open(b.parent / "spot_texture.png", "ab") as stream:  # the texture changed, the .obj did not
        stream.write(b"\0")
    assert content_key(a, settings) != content_key(b, settings)
    gltf = tmp_path / "m.gltf"
    gltf.write_text(json.dumps({"buffers": [{"uri": "m%20data.bin"}], "images": [{"uri": "data:image/png;base64,"}]}))
    assert external_files(gltf) == [tmp_path / "m data.bin"]
    before = content_key(gltf, settings)
    (tmp_path / "m data.bin").write_bytes(b"123")
    assert content_key(gltf, settings) != before


def test_plan_assets_mirrors_the_tree_and_separates_same_stems(tmp_path):
    lib = tmp_path / "lib"
    for rel in ("a/x.obj", "a/x.glb", "b/c/y.blend"):
        (lib / rel).parent.mkdir(parents=True, exist_ok=True)
        (lib / rel).write_text("o")
    models, roots = find_models([str(lib / "a"), str(lib / "b")], out=tmp_path / "out")
    assets = plan_assets(models, roots, out=tmp_path / "out", settings={})
    folders = sorted(a.folder.relative_to((tmp_path / "out").resolve()).as_posix() for a in assets)
    assert folders == ["a/x_glb", "a/x_obj", "b/c/y"]
    assert sorted(a.id for a in assets) == ["a/x.glb", "a/x.obj", "b/c/y.blend"]


def test_optimize_command_in_both_forms():
    python = optimize_command("in.obj", "o.blend", "r.json", ["--seed", "3"])
    assert python[1:] == ["-m", "perceptual_uv", "optimize", "in.obj", "--out", "o.blend", "--report", "r.json",
                          "--seed", "3"]
    blender = optimize_command("in.obj", "o.blend", "r.json", [], blender="/opt/blender/blender")
    assert blender[:5] == ["/opt/blender/blender", "-b", "--factory-startup", "--python", str(ROOT / "cli.py")]
    assert blender[5:8] == ["--", "optimize", "in.obj"]


def test_batch_options_reuse_optimize_options_and_check_their_values():
    args = parse_args(["batch", "lib", "--out", "o", "--epsilon", "0.02", "--resolution", "128", "--workers", "3",
                       "--asset-workers", "2", "--timeout", "60", "--retries", "2", "--format", "glb"])
    assert (args.epsilon, args.resolution, args.dask_workers, args.workers) == (0.02, 128, 3, 2)
    assert args.settings.epsilon == 0.02 and args.settings.workers == 2
    assert parse_args(["batch", "lib", "--out", "o"]).workers == 1  # one process per asset; assets run side by side
    for bad in (["--retries", "-1"], ["--timeout", "0"], ["--workers", "0"], ["--scheduler", "tcp://h:8786",
                                                                              "--workers", "2"],
                ["--epsilon", "-1"], ["--cost", "0.3", "--resolution", "64"]):
        with pytest.raises(UsageError):
            parse_args(["batch", "lib", "--out", "o", *bad])


def test_the_cost_measure_reaches_every_asset_and_its_key():
    from perceptual_uv.library_batch.run import batch_settings, optimize_options

    def parsed(*extra):
        return parse_args(["batch", "lib", "--out", "o", "--cost", "0.25", *extra])

    memory, texels = parsed(), parsed("--cost-measure", "texels")
    assert optimize_options(memory)[2:6] == ["--cost", "0.25", "--cost-measure", "memory"]
    assert optimize_options(texels)[2:6] == ["--cost", "0.25", "--cost-measure", "texels"]
    child = parse_args(["optimize", str(SPOT / "spot_triangulated.obj"), "--out", "x.blend",
                        *optimize_options(texels)])
    assert child.settings == texels.settings  # the child runs with the batch's settings
    assert batch_settings(memory)["cost_measure"] == "memory" and batch_settings(texels)["cost_measure"] == "texels"
    models = [SPOT / "spot_triangulated.obj"]
    keys = [plan_assets(models, [SPOT], out=pathlib.Path("o"), settings=batch_settings(args))[0].key
            for args in (memory, texels)]
    assert keys[0] != keys[1]  # another measure is another result: not skipped as done
    explicit = parse_args(["batch", "lib", "--out", "o", "--resolution", "64"])
    assert "--cost-measure" not in optimize_options(explicit) and batch_settings(explicit)["cost_measure"] is None


@pytest.mark.parametrize("flags", [["--unstack"], ["--square-images"], ["--unstack", "--square-images"]])
def test_the_packing_options_reach_every_asset_and_its_key(flags):
    from perceptual_uv.library_batch.run import batch_settings, optimize_options

    default = parse_args(["batch", "lib", "--out", "o"])
    given = parse_args(["batch", "lib", "--out", "o", *flags])
    child = parse_args(["optimize", str(SPOT / "spot_triangulated.obj"), "--out", "x.blend",
                        *optimize_options(given)])
    assert child.settings == given.settings != default.settings  # the child runs with the batch's settings
    models = [SPOT / "spot_triangulated.obj"]
    keys = {plan_assets(models, [SPOT], out=pathlib.Path("o"), settings=batch_settings(args))[0].key
            for args in (default, given)}
    assert len(keys) == 2  # another packing is another result: not skipped as done


def test_manifest_keeps_the_last_entry_and_knows_what_is_finished(tmp_path):
    manifest = Manifest(tmp_path)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "a.blend").write_text("x")
    manifest.append({"asset": "a.obj", "key": "k1", "status": "failed", "outputs": []})
    manifest.append({"asset": "a.obj", "key": "k1", "status": "done", "outputs": ["a/a.blend"]})
    manifest.append({"asset": "bad.obj", "key": "k2", "status": "bad_input", "outputs": []})
    with open(manifest.path, "a") as stream:
        stream.write('{"asset": "cut by a cra')
    again = Manifest(tmp_path)
    assert again.ignored_lines == 1
    assert again.finished("a.obj", "k1")["status"] == "done"
    assert again.finished("a.obj", "k-other") is None  # new bytes or settings
    assert again.finished("bad.obj", "k2")["status"] == "bad_input"
    (tmp_path / "a" / "a.blend").unlink()
    assert again.finished("a.obj", "k1") is None  # its output is gone
    again.append({"asset": "c.obj", "key": "k3", "status": "failed", "outputs": []})  # after the cut line
    third = Manifest(tmp_path)
    assert third.ignored_lines == 1 and third.entries["c.obj"]["key"] == "k3"


def test_summary_counts_memory_and_slowest():
    assert image_memory({"input_resolution": [1024, 512], "resolution": 256}) == (1024 * 512 * 4, 256 * 256 * 4)
    assert image_memory({"image_memory": {"before": 10, "after": 3}, "resolution": 1}) == (10, 3)
    assert image_memory(None) == (None, None)
    entries = [{"asset": "a", "status": "done", "time_s": 5.0, "image_bytes_before": 100, "image_bytes_after": 20},
               {"asset": "b", "status": "done", "time_s": 0.0, "duplicate_of": "a", "image_bytes_before": 100,
                "image_bytes_after": 20},
               {"asset": "c", "status": "done", "time_s": 9.0, "image_bytes_before": None, "image_bytes_after": None},
               {"asset": "d", "status": "bad_input", "error": "no texture"}]
    summary = summarize(entries, run={"total_time_s": 1.0})
    assert summary["counts"] == {"assets": 4, "done": 3, "bad_input": 1, "failed": 0, "duplicates": 1}
    assert summary["image_memory"]["before_bytes"] == 200 and summary["image_memory"]["ratio"] == 0.2
    assert [s["asset"] for s in summary["slowest"]] == ["c", "a"]
    assert summary["problems"] == [{"asset": "d", "status": "bad_input", "error": "no texture"}]


def test_a_report_over_several_textures_points_every_image_into_the_asset_folder(tmp_path):
    from perceptual_uv.library_batch.run import _move_image_paths

    def texture(stem):
        return {"image_file": f"/staging/{stem}_perceptual.png",
                "maps": [{"new_image_file": f"/staging/{stem}_perceptual.png"},
                         {"new_image_file": f"/staging/{stem}_normal_perceptual.png"}]}

    a, b = texture("a"), texture("b")
    report = {"image_files": [a["image_file"], b["image_file"]], "maps": a["maps"] + b["maps"], "textures": [a, b]}
    _move_image_paths(report, tmp_path)

    assert report["image_files"] == [str(tmp_path / "a_perceptual.png"), str(tmp_path / "b_perceptual.png")]
    assert "image_file" not in report
    assert [entry["new_image_file"] for entry in report["textures"][1]["maps"]] == [
        str(tmp_path / "b_perceptual.png"), str(tmp_path / "b_normal_perceptual.png")]
    assert report["textures"][0]["image_file"] == str(tmp_path / "a_perceptual.png")

def test_orchestrator_does_not_import_bpy():
    code = ("import sys, perceptual_uv.cli, perceptual_uv.library_batch.run; "
            "print('bpy' in sys.modules, 'perceptual_uv.bridge' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.stdout.split() == ["False", "False"], result.stderr


def test_batch_without_dask_says_how_to_install_it(tmp_path):
    code = ("import sys; sys.modules['dask'] = None; sys.modules['distributed'] = None; "
            "from perceptual_uv.cli import main; sys.exit(main(sys.argv[1:]))")
    result = subprocess.run([sys.executable, "-c", code, "batch", str(SPOT), "--out", str(tmp_path / "o")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "perceptual_uv: error: the batch command needs Dask: pip install dask distributed"]


def test_batch_refuses_inputs_that_name_nothing_in_one_line(tmp_path):
    result = run_batch_cli(str(tmp_path / "missing"), "--out", str(tmp_path / "o"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith("perceptual_uv: error: ")
    assert "no such file or folder" in result.stderr


# --- a real run on a LocalCluster of 2 worker processes ------------------------------------------------------

@pytest.mark.bpy
def test_batch_runs_a_library_records_it_and_resumes(tmp_path):
    pytest.importorskip("distributed")
    pytest.importorskip("bpy")
    lib, out = make_library(tmp_path / "lib"), tmp_path / "out"
    result = run_batch_cli(str(lib), "--out", str(out), "--workers", "2", *FAST_ARGS)
    assert result.returncode == 1, result.stderr[-3000:]  # 1: one asset is a bad input
    assert "Traceback" not in result.stderr
    entries = {e["asset"]: e for e in read_manifest(out)}
    assert sorted(entries) == ["a/spot.obj", "b/spot_copy.obj", "bad.obj"]
    done, duplicate, bad = entries["a/spot.obj"], entries["b/spot_copy.obj"], entries["bad.obj"]
    assert done["status"] == "done" and done["attempts"] == 1 and done["duplicate_of"] is None
    assert done["outputs"] == ["a/spot/spot.blend", "a/spot/spot.report.json", "a/spot/spot_texture_perceptual.png"]
    report = json.loads((out / "a" / "spot" / "spot.report.json").read_text())
    assert report["resolution"] == [64, 64] and done["relative_cost"] == report["relative_cost"]
    assert done["image_bytes_before"] == 1024 * 1024 * 4 and done["image_bytes_after"] == 64 * 64 * 4
    assert done["time_s"] > 0 and done["output_bytes"] == sum((out / p).stat().st_size for p in done["outputs"])
    # The duplicate (same bytes and settings, another name) ran once; its folder holds copies named after it.
    assert duplicate["key"] == done["key"] and duplicate["duplicate_of"] == "a/spot.obj"
    assert duplicate["status"] == "done" and duplicate["outputs"] == [
        "b/spot_copy/spot_copy.blend", "b/spot_copy/spot_copy.report.json", "b/spot_copy/spot_texture_perceptual.png"]
    assert (out / "b/spot_copy/spot_copy.blend").read_bytes() == (out / "a/spot/spot.blend").read_bytes()
    copy_report = json.loads((out / "b/spot_copy/spot_copy.report.json").read_text())
    assert copy_report["output"] == str((out / "b/spot_copy/spot_copy.blend").resolve())
    assert bad["status"] == "bad_input" and bad["attempts"] == 1 and bad["outputs"] == []
    assert "image texture" in bad["error"] and "\n" not in bad["error"]
    assert not (out / "bad").exists() and leftovers(out) == []
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"assets": 3, "done": 2, "bad_input": 1, "failed": 0, "duplicates": 1,
                                 "not_run": 0}
    assert summary["image_memory"]["after_bytes"] == 2 * 64 * 64 * 4
    assert summary["cluster"]["workers"] == 2
    rows = (out / "summary.csv").read_text().splitlines()
    assert rows[0].startswith("asset,status,time_s") and len(rows) == 4
    assert sum(",64x64," in row for row in rows[1:]) == 2  # the new images' width x height
    assert "bad_input: bad.obj: " in result.stdout and "image memory: 8.0 MiB -> 32.0 KiB" in result.stdout
    assert "batch: 2 Dask worker(s) on a local cluster" in result.stderr
    assert "finished (" in result.stderr and "ETA" in result.stderr

    # Rerun: nothing to do, nothing appended, outputs untouched.
    stamp = (out / "a/spot/spot.blend").stat().st_mtime_ns
    again = run_batch_cli(str(lib), "--out", str(out), "--workers", "2", *FAST_ARGS, timeout=120)
    assert again.returncode == 1 and "3 already finished, 0 to run" in again.stderr
    assert len(read_manifest(out)) == 3 and (out / "a/spot/spot.blend").stat().st_mtime_ns == stamp

    # A deleted output is made again: the duplicate's copy comes from the finished original, without a run.
    (out / "b/spot_copy/spot_copy.blend").unlink()
    third = run_batch_cli(str(lib), "--out", str(out), "--workers", "2", *FAST_ARGS, timeout=120)
    assert "2 already finished, 1 to run" in third.stderr
    assert (out / "b/spot_copy/spot_copy.blend").is_file() and len(read_manifest(out)) == 4
    assert "Dask worker" not in third.stderr  # no cluster was needed


def test_dask_is_a_command_line_requirement_not_an_extension_one():
    def names(path):
        return {line.split("==")[0].strip().lower() for line in (ROOT / path).read_text().splitlines()
                if line.strip() and not line.startswith("#")}

    assert {"dask", "distributed"} <= names("requirements.txt")
    assert not {"dask", "distributed"} & names("requirements-extension.txt")
    assert all("==" in line for line in (ROOT / "requirements.txt").read_text().splitlines()
               if line.startswith(("dask", "distributed")))


@pytest.mark.bpy
def test_an_asset_past_the_timeout_is_killed_retried_then_failed(tmp_path):
    pytest.importorskip("distributed")
    pytest.importorskip("bpy")
    spot_patch_obj(tmp_path / "lib", "spot.obj")
    out = tmp_path / "out"
    result = run_batch_cli(str(tmp_path / "lib"), "--out", str(out), "--workers", "1", "--timeout", "1.5",
                           "--retries", "1", *FAST_ARGS, timeout=300)
    assert result.returncode == 1, result.stderr[-3000:]
    assert "attempt 1 failed (timed out after 1.5 s (killed)); retrying" in result.stderr
    [entry] = read_manifest(out)
    assert entry["status"] == "failed" and entry["attempts"] == 2 and entry["time_s"] < 30
    assert entry["error"] == "timed out after 1.5 s (killed)"
    assert "failed: spot.obj: timed out" in result.stdout
    assert not (out / "spot").exists() and leftovers(out) == []
    assert Manifest(out).finished("spot.obj", entry["key"]) is None  # a failed asset runs again next time


def test_one_batch_at_a_time_per_output_folder(tmp_path):
    fcntl = pytest.importorskip("fcntl")
    pytest.importorskip("distributed")
    spot_patch_obj(tmp_path / "lib", "spot.obj")
    (tmp_path / "out").mkdir()
    with open(tmp_path / "out" / ".batch.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        result = run_batch_cli(str(tmp_path / "lib"), "--out", str(tmp_path / "out"), timeout=120)
    assert result.returncode == 2
    last_line = result.stderr.strip().splitlines()[-1]
    assert last_line == f"perceptual_uv: error: another batch is running on {tmp_path / 'out'}"
    assert not (tmp_path / "out" / "manifest.jsonl").exists()


def test_progress_prints_counts_and_eta_at_most_every_5_s_without_tqdm(monkeypatch, capsys):
    from perceptual_uv.library_batch import run

    monkeypatch.setitem(sys.modules, "tqdm", None)
    progress = run._Progress(4)
    progress.started -= 60  # one minute in
    progress.update(finished=1, done=1, bad=0, failed=0, running=2, retrying=0, force=True)
    progress.update(finished=1, done=1, bad=0, failed=0, running=2, retrying=0)  # within 5 s: no line
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["batch: 1/4 finished (1 done, 0 bad input, 0 failed, 2 running, 1 waiting), 1m00s elapsed, "
                     "ETA 3m00s"]
    progress.last -= run.PROGRESS_EVERY_S
    progress.update(finished=2, done=1, bad=1, failed=0, running=2, retrying=1)
    assert "2/4 finished (1 done, 1 bad input, 0 failed, 2 running, 0 waiting, 1 retried)" in capsys.readouterr().err


def test_closing_its_own_cluster_quiets_the_cluster_logs_first_and_leaves_a_remote_one_alone():
    """A worker heartbeat that meets the closed scheduler logs a traceback at ERROR level into the batch's stderr
    (a Ctrl-C once printed one): the batch quiets ``distributed`` on its own cluster's workers and nannies before
    closing; on a cluster it only connected to, it changes nothing."""
    import logging

    from perceptual_uv.library_batch import run

    calls = []

    class Fake:
        def __init__(self, name):
            self.name = name

        def run(self, function, **options):
            calls.append((self.name, "run", function, options))

        def close(self):
            calls.append((self.name, "close"))

    logger = logging.getLogger("distributed")
    level = logger.level
    try:
        assert run._close(Fake("client"), None) is None
        assert calls == [("client", "close")]
        assert logger.level == level
        calls.clear()
        run._close(Fake("client"), Fake("cluster"))
        assert calls == [("client", "run", run._quiet_cluster_logs, {}),
                         ("client", "run", run._quiet_cluster_logs, {"nanny": True}),
                         ("client", "close"), ("cluster", "close")]
        assert logger.level == logging.CRITICAL
    finally:
        logger.setLevel(level)


def test_external_files_of_an_fbx_are_the_images_it_names_where_blenders_importer_finds_them(tmp_path):
    """Binary FBX stores a string as a type code and a 4-byte length before its bytes; ASCII FBX in quotes. A
    texture named by an absolute path of the machine that wrote the file is found by its name anywhere below the
    file's folder, as Blender's importer searches; a name found nowhere is left out."""
    (tmp_path / "maps").mkdir()
    (tmp_path / "deep" / "er").mkdir(parents=True)
    (tmp_path / "maps" / "albedo.png").write_bytes(b"a")
    (tmp_path / "deep" / "er" / "Rough.TGA").write_bytes(b"r")

    def string(text):
        data = text.encode()
        return b"S" + len(data).to_bytes(4, "little") + data

    binary = tmp_path / "binary.fbx"
    binary.write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + string("maps\\albedo.png") + b"\x00\x07"
                       + string("C:\\Users\\artist\\Desktop\\Rough.TGA") + string("missing.jpg")
                       + string("Texture::albedo") + b"\x00png.png\x00")
    assert external_files(binary) == [tmp_path / "maps" / "albedo.png", tmp_path / "deep" / "er" / "Rough.TGA"]
    ascii_fbx = tmp_path / "ascii.fbx"
    ascii_fbx.write_text('; FBX 7.4.0 project file\nTexture: "Texture::a", "" {\n'
                         '\tFileName: "U:/Some/Absolute/rough.tga"\n\tRelativeFilename: "maps\\albedo.png"\n}\n')
    assert external_files(ascii_fbx) == [tmp_path / "deep" / "er" / "Rough.TGA", tmp_path / "maps" / "albedo.png"]


def test_lz4_block_of_literals_and_an_overlapping_back_reference():
    from perceptual_uv.library_batch.external_files import _fast_decompress, _lz4_block

    # token 0x32: 3 literals, then a match of 2 + 4 = 6 bytes at offset 3 (overlapping what it writes); token
    # 0x10: the last sequence, 1 literal.
    block = b"\x32abc\x03\x00" + b"\x10!"
    assert _lz4_block(block) == b"abcabcabc!"
    assert _fast_decompress(b"\x00" + block) == b"abcabcabc!"
    assert _fast_decompress(b"\x02" + len(block).to_bytes(4, "little") + block
                            + (2).to_bytes(4, "little") + b"\x10?") == b"abcabcabc!?"
    # lengths past 15 continue in the next bytes: 15 + 255 + 3 = 273 literals
    assert _lz4_block(b"\xf0\xff\x03" + b"x" * 273) == b"x" * 273


def test_usd_layers_that_reference_each_other_are_each_listed_once(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "a.usda").write_text('#usda 1.0\n(\n    subLayers = [@./sub/b.usda@]\n)\n')
    (tmp_path / "sub" / "b.usda").write_text('#usda 1.0\n(\n    subLayers = [@../a.usda@, @../sub/../a.usda@]\n)\n'
                                              'def "T" { asset inputs:file = @../t.png@ }\n')
    (tmp_path / "t.png").write_bytes(b"p")
    assert external_files(tmp_path / "a.usda") == [tmp_path / "sub" / "b.usda", tmp_path / "sub" / ".." / "a.usda",
                                                   tmp_path / "sub" / ".." / "t.png"]
