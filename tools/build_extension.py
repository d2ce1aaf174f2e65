"""Build the installable extension: one zip per platform with its cp311 wheels.

Downloads the wheels of ``requirements-extension.txt`` (and their dependencies, except numpy, which Blender
ships) for each platform into ``wheels/``, stages the package in ``build/stage`` with those wheels listed in its
``blender_manifest.toml``, then builds and validates ``dist/perceptual_uv-<version>-<platform>.zip`` with the
``blender_ext.py`` CLI inside the bpy module. The committed manifest stays free of wheel names.

Usage: python tools/build_extension.py [--platforms linux-x64,windows-x64,macos-arm64] [--offline]
                                       [--output-dir dist]
"""
import argparse
import importlib.util
import pathlib
import re
import shutil
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
WHEELS = ROOT / "wheels"
STAGE = ROOT / "build" / "stage"

# pip platform tags per Blender platform; several per platform because projects publish different baselines.
PIP_PLATFORMS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_14_0_arm64", "macosx_12_0_arm64", "macosx_11_0_arm64"],
}
WHEEL_PLATFORM_MARKERS = {"linux-x64": "linux", "windows-x64": "win_amd64", "macos-arm64": "macosx"}
NOT_STAGED = (".git", ".venv", "build", "dist", "wheels", "out", "__pycache__", ".pytest_cache", ".hypothesis")


def blender_ext():
    spec = importlib.util.find_spec("bpy")
    if spec is None:
        sys.exit("the bpy module is not installed: run `make setup`")
    found = sorted(pathlib.Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        sys.exit("blender_ext.py not found inside the bpy module")
    return found[-1]


def download_wheels(platform):
    command = [sys.executable, "-m", "pip", "download", "--quiet", "--only-binary=:all:", "--python-version", "3.11",
               "--implementation", "cp", "--abi", "cp311", "--abi", "abi3", "--abi", "none",
               "-r", str(ROOT / "requirements-extension.txt"), "-d", str(WHEELS)]
    for tag in PIP_PLATFORMS[platform]:
        command += ["--platform", tag]
    print(f"downloading wheels for {platform}")
    subprocess.run(command, check=True)


def wheels_for(platforms):
    """Wheel file names in ``wheels/`` that any of ``platforms`` needs (pure-Python ones included, no numpy)."""
    markers = tuple(WHEEL_PLATFORM_MARKERS[platform] for platform in platforms)
    names = []
    for path in sorted(WHEELS.glob("*.whl")):
        platform_tag = path.stem.rsplit("-", 1)[-1]
        if path.name.startswith("numpy-"):
            continue
        if platform_tag == "any" or any(marker in platform_tag for marker in markers):
            names.append(path.name)
    return names


def stage(platforms, wheel_names):
    shutil.rmtree(STAGE, ignore_errors=True)
    shutil.copytree(ROOT, STAGE, ignore=shutil.ignore_patterns(*NOT_STAGED), symlinks=True)
    (STAGE / "wheels").mkdir()
    for name in wheel_names:
        shutil.copy2(WHEELS / name, STAGE / "wheels" / name)
    manifest = STAGE / "blender_manifest.toml"
    text = manifest.read_text()
    text = re.sub(r"^platforms = .*$", "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]", text,
                  count=1, flags=re.M)
    text = re.sub(r"^wheels = \[[^\]]*\]", "wheels = [\n" + "".join(f'  "./wheels/{n}",\n' for n in wheel_names) + "]",
                  text, count=1, flags=re.M)
    manifest.write_text(text)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--platforms", default=",".join(PIP_PLATFORMS))
    parser.add_argument("--offline", action="store_true", help="use the wheels already in wheels/")
    parser.add_argument("--output-dir", type=pathlib.Path, default=ROOT / "dist")
    args = parser.parse_args(argv)
    platforms = args.platforms.split(",")
    unknown = set(platforms) - set(PIP_PLATFORMS)
    if unknown:
        parser.error(f"unknown platform(s) {sorted(unknown)}; known: {sorted(PIP_PLATFORMS)}")
    WHEELS.mkdir(exist_ok=True)
    if not args.offline:
        for platform in platforms:
            download_wheels(platform)
    stage(platforms, wheels_for(platforms))
    cli = blender_ext()
    args.output_dir.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, str(cli), "validate", str(STAGE)], check=True)
    subprocess.run([sys.executable, str(cli), "build", "--source-dir", str(STAGE), "--output-dir",
                    str(args.output_dir), "--split-platforms"], check=True)
    for archive in sorted(args.output_dir.glob("*.zip")):
        subprocess.run([sys.executable, str(cli), "validate", str(archive)], check=True)
        print(archive)


if __name__ == "__main__":
    try:
        main()
    except subprocess.CalledProcessError as error:
        sys.exit(f"build_extension: {' '.join(map(str, error.cmd[:3]))} failed (exit {error.returncode})")
