"""Where numba's compiled kernels are cached: one folder per version of core's source."""
import hashlib
import os
import pathlib
import subprocess
import sys
import time

import perceptual_uv
from perceptual_uv.core import _jit

CORE = pathlib.Path(perceptual_uv.__file__).parent / "core"


def test_source_hash_covers_every_core_module_by_name_and_bytes():
    digest = hashlib.sha256()
    for path in sorted(CORE.glob("*.py")):
        digest.update(path.name.encode() + path.read_bytes())
    assert _jit.core_source_hash() == digest.hexdigest()


def test_numba_cache_folder_is_per_source_version_and_old_versions_are_pruned(tmp_path):
    # A kernel that calls another module's kernel is cached on its own file only; a folder per source hash is
    # what makes an edit of the callee recompile the caller. Five older version folders exist: the new one
    # and the three most recently used old ones stay (KEPT_VERSIONS = 4), the two oldest go; a file is kept.
    base = tmp_path / "numba"
    old = []
    for age in range(5):
        folder = base / f"{age:016d}"
        folder.mkdir(parents=True)
        (folder / "kernel.nbi").write_bytes(b"x")
        stamp = time.time() - 3600 * (age + 1)
        os.utime(folder, (stamp, stamp))
        old.append(folder)
    (base / "notes.txt").write_text("kept")
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    env["PERCEPTUAL_UV_CACHE"] = str(tmp_path)
    env["PYTHONPATH"] = str(pathlib.Path(perceptual_uv.__file__).parent.parent)
    code = ("import os, perceptual_uv.core._jit as j; "
            "print(os.environ['NUMBA_CACHE_DIR']); print(j.core_source_hash())")
    lines = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                           check=True).stdout.split()
    folder, source_hash = pathlib.Path(lines[0]), lines[1]
    assert folder == base / source_hash[:16] and folder.is_dir()
    assert [path.exists() for path in old] == [True, True, True, False, False]
    assert (base / "notes.txt").exists()


def test_a_cache_folder_already_chosen_is_kept_and_nothing_is_pruned(tmp_path):
    # Workers inherit NUMBA_CACHE_DIR from their parent: they must neither move to another folder nor prune.
    base = tmp_path / "numba"
    old = base / ("0" * 16)
    old.mkdir(parents=True)
    chosen = tmp_path / "chosen"
    env = dict(os.environ, PERCEPTUAL_UV_CACHE=str(tmp_path), NUMBA_CACHE_DIR=str(chosen),
               PYTHONPATH=str(pathlib.Path(perceptual_uv.__file__).parent.parent))
    code = "import os, perceptual_uv.core._jit; print(os.environ['NUMBA_CACHE_DIR'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(chosen)
    assert sorted(path.name for path in base.iterdir()) == ["0" * 16]
