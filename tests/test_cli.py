"""Argument handling of both CLI forms: ``python -m perceptual_uv`` and ``blender -b --python cli.py -- ...``."""
import pathlib
import subprocess
import sys

import pytest

from perceptual_uv.cli import blender_argv, main, parse_args

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPOT = ROOT / "tests" / "data" / "spot" / "spot_triangulated.obj"


def run_module(*args):
    return subprocess.run([sys.executable, "-m", "perceptual_uv", *args], capture_output=True, text=True, timeout=120)


def run_as_blender_script(*blender_args):
    """What ``blender -b scene.blend --python cli.py -- ...`` does: run the file as __main__ with Blender's argv."""
    code = ("import runpy, sys; sys.argv = sys.argv[1:]; "
            f"runpy.run_path({str(ROOT / 'cli.py')!r}, run_name='__main__')")
    argv = ["blender", "-b", "scene.blend", "--python", str(ROOT / "cli.py"), *blender_args]
    return subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120,
                          cwd="/")


def test_module_help_lists_both_commands():
    result = run_module("--help")
    assert result.returncode == 0
    assert "optimize" in result.stdout and "evaluate" in result.stdout


def test_blender_argv_takes_what_follows_the_double_dash():
    argv = ["blender", "-b", "a.blend", "--python", "cli.py", "--", "optimize", "in.obj", "--out", "o.blend"]
    assert blender_argv(argv) == ["optimize", "in.obj", "--out", "o.blend"]
    assert blender_argv(["blender", "-b", "a.blend", "--python", "cli.py"]) == []


def test_blender_form_parses_arguments_after_double_dash():
    result = run_as_blender_script("--", "optimize", "/nonexistent/model.obj", "--out", "out.blend")
    assert result.returncode == 2
    assert result.stderr.strip() == "perceptual_uv: error: argument IN: /nonexistent/model.obj: no such file"


def test_blender_form_help_and_missing_arguments():
    assert run_as_blender_script("--", "--help").returncode == 0
    missing = run_as_blender_script()
    assert missing.returncode == 2 and "required" in missing.stderr
    assert "Traceback" not in missing.stderr


def test_optimize_defaults_follow_the_design_contract():
    settings = parse_args(["optimize", str(SPOT), "--out", "x.blend"]).settings
    assert (settings.epsilon, settings.target_cost, settings.resolution) == (0.01, 0.3, None)
    assert (settings.iterations, settings.screen_pixels, settings.seed) == (100, 64, 0)
    assert settings.max_screen_pixels == 256
    capped = parse_args(["optimize", str(SPOT), "--out", "x.blend", "--max-screen-pixels", "64"]).settings
    assert capped.max_screen_pixels == 64
    assert settings.scheduler is None and settings.reuse_triangle_results and settings.role_costs == ()


def test_scheduler_fresh_and_role_costs_reach_the_settings():
    settings = parse_args(["optimize", str(SPOT), "--out", "x.blend", "--scheduler", "tcp://host:8786", "--fresh",
                           "--cost-for", "normal=0.2", "--cost-for", "emissive=0.1"]).settings
    assert settings.scheduler == "tcp://host:8786" and not settings.reuse_triangle_results
    assert settings.role_costs == (("normal", 0.2), ("emissive", 0.1))
    batch = parse_args(["batch", str(SPOT), "--out", "library", "--scheduler", "tcp://host:8786"])
    assert batch.scheduler == "tcp://host:8786" and batch.settings.scheduler is None  # each asset runs locally


def test_the_cost_measure_reaches_the_settings():
    settings = parse_args(["optimize", str(SPOT), "--out", "x.blend"]).settings
    assert settings.cost_measure == "memory"  # --cost is the images' memory relative to the input's
    texels = parse_args(["optimize", str(SPOT), "--out", "x.blend", "--cost", "0.2", "--cost-measure", "texels",
                         "--cost-for", "normal=0.1"]).settings
    assert (texels.target_cost, texels.cost_measure, texels.role_costs) == (0.2, "texels", (("normal", 0.1),))
    assert parse_args(["batch", str(SPOT), "--out", "lib", "--cost-measure", "texels"]).settings.cost_measure == \
        "texels"
    assert main(["optimize", str(SPOT), "--out", "x.blend", "--cost-measure", "bytes"]) == 2


def test_unstack_reaches_the_settings():
    assert parse_args(["optimize", str(SPOT), "--out", "x.blend"]).settings.keep_stacks  # stacked islands stay so
    assert not parse_args(["optimize", str(SPOT), "--out", "x.blend", "--unstack"]).settings.keep_stacks
    assert not parse_args(["batch", str(SPOT), "--out", "lib", "--unstack"]).settings.keep_stacks


def test_cost_and_resolution_are_exclusive():
    assert main(["optimize", str(SPOT), "--out", "x.blend", "--cost", "0.3", "--resolution", "512"]) == 2


@pytest.mark.parametrize("args, fragment", [
    (["optimize", "model.stl", "--out", "x.blend"], "unsupported input type"),
    (["optimize", str(SPOT), "--out", "x.png"], "unsupported output type"),
    (["optimize", str(SPOT), "--out", "x.blend", "--epsilon", "0"], "epsilon 0.0: must be in (0, 1)"),
    (["optimize", str(SPOT), "--out", "x.blend", "--resolution", "4"], "resolution 4"),
    (["optimize", str(SPOT), "--out", "x.blend", "--iterations", "3"], "iterations 3"),
    (["evaluate", str(SPOT), "--uv", "UVMap", "--costs", "0.1,abc"], "comma-separated"),
    (["evaluate", str(SPOT), "--uv", "UVMap", "--costs", "0,0.5"], "(0, 4]"),
])
def test_bad_input_is_one_line_and_exit_2(args, fragment, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1 and err.startswith("perceptual_uv: error: ")


def test_the_formats_the_messages_name_are_the_ones_read_and_written(capsys):
    from perceptual_uv.core.settings import suffix_listing

    assert suffix_listing((".a",)) == ".a"
    assert suffix_listing((".a", ".b", ".c")) == ".a, .b or .c"
    assert main(["optimize", "model.stl", "--out", "x.blend"]) == 2
    assert ("expected .blend, .glb, .gltf, .obj, .fbx, .usd, .usda, .usdc or .usdz)"
            in capsys.readouterr().err)
    assert main(["optimize", str(SPOT), "--out", "x.usdz"]) == 2
    assert "expected .blend, .glb or .fbx)" in capsys.readouterr().err
    assert main(["batch", str(SPOT), "--out", "lib", "--format", "usdz"]) == 2
    assert "(choose from 'blend', 'glb', 'fbx')" in capsys.readouterr().err


def test_an_interrupt_that_numba_wraps_in_a_system_error_still_cancels(monkeypatch, capsys):
    """Ctrl-C or SIGTERM while numba loads a cached kernel reaches the CLI as a SystemError caused by the
    KeyboardInterrupt (seen in CI); any other SystemError is not ours to hide."""
    from perceptual_uv import cli

    def interrupted_in_numba(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as interrupt:
            raise SystemError("CPUDispatcher(...) returned a result with an exception set") from interrupt

    monkeypatch.setattr(cli, "_run", interrupted_in_numba)
    assert main(["optimize", str(SPOT), "--out", "unused.blend"]) == 130
    assert capsys.readouterr().err.strip().endswith("cancelled")


def test_an_internal_failure_prints_one_line_naming_the_traceback_file_and_exits_1(monkeypatch, capsys):
    """Issue 22: the CLI never prints a traceback; an internal failure (here a SystemError that no interrupt
    caused, and a ZeroDivisionError from a kernel) is one line and exit 1, the traceback in a file."""
    from perceptual_uv import cli

    for error in (SystemError("something else"), ZeroDivisionError("division by zero")):
        def broken(args, error=error):
            raise error

        monkeypatch.setattr(cli, "_run", broken)
        assert main(["optimize", str(SPOT), "--out", "unused.blend"]) == 1
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1
        message = f"perceptual_uv: internal error: {type(error).__name__}: {error} (traceback written to "
        assert lines[0].startswith(message) and lines[0].endswith(")")
        path = pathlib.Path(lines[0][len(message):-1])
        try:
            text = path.read_text()
            assert text.startswith("Traceback (most recent call last):")
            assert "in broken" in text and text.rstrip().endswith(f"{type(error).__name__}: {error}")
        finally:
            path.unlink()


def test_a_cancel_exits_130_when_the_interrupt_left_code_run_through_the_c_api(tmp_path):
    # CPython 3.11 remembers a KeyboardInterrupt that left code run through PyRun_* (as Blender runs Python), even a
    # caught one, and ends a `python -m` process by SIGINT (returncode -2). The run here is cancelled that way:
    # its body raises KeyboardInterrupt through PyRun_String, the CLI reports the cancel and must exit 130.
    (tmp_path / "cancel_through_c_api.py").write_text(
        "import ctypes, sys\n"
        "from perceptual_uv import cli\n"
        "run = ctypes.pythonapi.PyRun_String\n"
        "run.restype, run.argtypes = ctypes.py_object, [ctypes.c_char_p, ctypes.c_int, ctypes.py_object,"
        " ctypes.py_object]\n"
        "cli._run = lambda args: run(b'raise KeyboardInterrupt', 257, {}, {})  # 257: Py_file_input\n"
        f"sys.exit(cli.main(['optimize', {str(SPOT)!r}, '--out', 'out.glb']))\n")
    done = subprocess.run([sys.executable, "-m", "cancel_through_c_api"], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert done.returncode == 130, done.stderr[-2000:]
    assert done.stderr.strip().splitlines()[-1] == "perceptual_uv: cancelled"
