"""The built extension installs into Blender, registers its UI, and unregisters without leftovers."""
import json
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.bpy


@pytest.fixture(scope="module")
def linux_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, str(ROOT / "tools" / "build_extension.py"), "--platforms", "linux-x64",
                    "--output-dir", str(out)], check=True, capture_output=True, text=True)
    (archive,) = out.glob("perceptual_uv-*-linux_x64.zip")
    return archive


def test_manifest_is_valid_and_has_no_committed_wheels():
    import tomllib

    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["id"] == "perceptual_uv"
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert manifest["tags"] == ["UV"]
    assert manifest["wheels"] == []


def test_zip_holds_the_package_and_linux_wheels_only(linux_zip):
    import zipfile

    names = zipfile.ZipFile(linux_zip).namelist()
    assert {"__init__.py", "blender_manifest.toml", "LICENSE", "operators/optimize_uvs.py",
            "panels/uv_sidebar.py", "core/deformation.py"} <= set(names)
    wheels = [name for name in names if name.startswith("wheels/")]
    assert any(name.startswith("wheels/scipy-") for name in wheels)
    assert any(name.startswith("wheels/numba-") for name in wheels)
    assert not any(name.startswith("wheels/numpy-") for name in wheels), "numpy is Blender's own"
    assert not any("win_amd64" in name or "macosx" in name for name in wheels)
    assert not any(name.startswith(("tests/", "bench/", "tools/", ".venv/")) for name in names)


def test_install_enable_disable_leaves_nothing_registered(linux_zip, tmp_path):
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path))
    script = ROOT / "tests" / "blender_scripts" / "extension_lifecycle.py"
    run = subprocess.run([sys.executable, str(script), str(linux_zip)], env=env, capture_output=True, text=True,
                         timeout=300)
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULT ")]
    assert run.returncode == 0 and lines, run.stdout[-2000:] + run.stderr[-2000:]
    result = json.loads(lines[-1][len("RESULT "):])

    assert result["install"] == ["FINISHED"]
    enabled = result["enabled"]
    assert enabled["addon_enabled"] and enabled["operator"] and enabled["panel"]
    assert enabled["operator_label"] == "Optimize UVs"
    assert enabled["panel_space"] == "IMAGE_EDITOR"
    assert enabled["settings_group"] and enabled["preferences"]
    assert enabled["scene_property"] and enabled["uv_menu_entry"]
    assert result["site_packages"].startswith(str(tmp_path))
    assert result["active_object"] == "Cube" and result["poll_untextured_cube"] is False

    disabled = result["disabled"]
    assert not disabled["addon_enabled"]
    assert not disabled["operator"] and not disabled["panel"]
    assert not disabled["settings_group"] and not disabled["preferences"]
    assert not disabled["scene_property"] and not disabled["uv_menu_entry"]
