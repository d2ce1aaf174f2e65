# SPDX-License-Identifier: GPL-3.0-or-later
"""Shared fixtures: the bundled and shared model folders, and a clean Blender scene."""
import pathlib

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
