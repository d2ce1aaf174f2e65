# SPDX-License-Identifier: GPL-3.0-or-later
"""Shared fixtures: the bundled and shared model folders, a clean Blender scene, a private results cache."""
import pathlib
import sys

import pytest

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
TEST_DATA = REPO_ROOT / "tests" / "data"
SHARED = REPO_ROOT.parent / "shared"
SHARED_MODELS = SHARED / "models"


@pytest.fixture(scope="session")
def test_data_dir():
    """Folder of the models bundled with the repository (``tests/data``)."""
    return TEST_DATA


@pytest.fixture(scope="session")
def spot_obj(test_data_dir):
    """Path of the bundled spot model (OBJ with its PNG texture)."""
    return test_data_dir / "spot" / "spot_triangulated.obj"


@pytest.fixture(scope="session")
def shared_models_dir():
    """``../shared/models`` next to the repository; skips the test when it is absent."""
    if not SHARED_MODELS.is_dir():
        pytest.skip(f"shared models not available at {SHARED_MODELS}")
    return SHARED_MODELS


def reset_blender_scene():
    """Replace the open file by an empty one (factory startup, preferences and extensions kept)."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    return bpy.context.scene


@pytest.fixture
def empty_scene():
    """An empty Blender scene for a bpy test (skips without the bpy module)."""
    pytest.importorskip("bpy")
    return reset_blender_scene()


# The modules holding a cache of stage results made on first use, and the list that holds it.
_STAGE_CACHES = (("perceptual_uv.bridge.trianglewise_stage", "_TRIANGLE_RESULTS"),
                 ("perceptual_uv.bridge.meshwise_stage", "_MESHWISE_RESULTS"))


def _forget_stage_caches():
    for module, name in _STAGE_CACHES:
        if module in sys.modules:
            getattr(sys.modules[module], name).clear()


@pytest.fixture(autouse=True)
def private_results_cache(tmp_path_factory, monkeypatch):
    """Every test gets its own cache of triangle-wise and mesh-wise results (in memory and on disk, for its
    subprocesses too): a test never reuses another test's results, nor the user's."""
    monkeypatch.setenv("PERCEPTUAL_UV_RESULTS_CACHE", str(tmp_path_factory.mktemp("results_cache")))
    _forget_stage_caches()
    yield
    _forget_stage_caches()
