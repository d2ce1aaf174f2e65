"""Every ``core`` module imports with bpy made unimportable: core runs in worker processes and plain Python."""
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_every_core_module_imports_without_bpy():
    modules = sorted(f"perceptual_uv.core.{path.stem}" for path in (ROOT / "core").glob("*.py")
                     if path.stem != "__init__")
    assert "perceptual_uv.core.deformation" in modules
    code = f"""
import importlib, sys
class _NoBpy:
    def find_spec(self, name, path=None, target=None):
        if name == "bpy" or name.startswith(("bpy.", "bmesh", "mathutils", "gpu")):
            raise ImportError(f"{{name}} is blocked: core must not import Blender modules")
sys.meta_path.insert(0, _NoBpy())
for name in {modules!r}:
    importlib.import_module(name)
assert not any(m == "bpy" or m.startswith("bpy.") for m in sys.modules), "bpy got imported"
print("imported", len({modules!r}))
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == f"imported {len(modules)}"
