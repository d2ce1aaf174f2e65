# SPDX-License-Identifier: GPL-3.0-or-later
"""Command line interface, the same in both forms:

    python -m perceptual_uv optimize IN --out OUT.blend ...            (bpy module in the venv)
    blender -b FILE --python <extension dir>/cli.py -- optimize IN ...  (arguments after ``--``)

Exit codes: 0 success, 2 bad input (one line on stderr, no traceback), 1 an internal failure.
"""
import argparse
import pathlib
import sys

PROG = "perceptual_uv"
MODEL_SUFFIXES = (".blend", ".glb", ".gltf", ".obj")
OUTPUT_SUFFIXES = (".blend", ".glb")


class UsageError(ValueError):
    """Bad input from the user: reported in one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def _existing_model(text):
    path = pathlib.Path(text)
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text}: unsupported input type (expected one of {', '.join(MODEL_SUFFIXES)})")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    return path


def _output_model(text):
    path = pathlib.Path(text)
    if path.suffix.lower() not in OUTPUT_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text}: unsupported output type (expected .blend or .glb)")
    return path


def _costs(text):
    try:
        costs = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text}: expected comma-separated numbers such as 0.1,0.2,0.3,0.5") from None
    if not costs or any(not 0 < cost <= 4 for cost in costs):
        raise argparse.ArgumentTypeError(f"{text}: every relative cost must be in (0, 4]")
    return costs


def build_parser():
    parser = _Parser(prog=PROG, description="Re-parameterize a textured mesh's UV map so its texture needs fewer "
                     "pixels for the same look on screen (Sun et al. 2022).")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    optimize = commands.add_parser("optimize", help="optimize the UV map of a model and bake its texture")
    optimize.add_argument("input", metavar="IN", type=_existing_model, help=".blend, .glb/.gltf or .obj")
    optimize.add_argument("--object", help="mesh object to optimize (default: the textured mesh objects)")
    optimize.add_argument("--uv", help="input UV map (default: the active one)")
    optimize.add_argument("--epsilon", type=float, default=0.01, help="perceptual loss bound (default 0.01)")
    size = optimize.add_mutually_exclusive_group()
    size.add_argument("--cost", type=float, default=None, help="target relative cost (default 0.3)")
    size.add_argument("--resolution", type=int, default=None, help="explicit texture size in pixels")
    optimize.add_argument("--iterations", type=int, default=100, help="loss evaluations per triangle")
    optimize.add_argument("--screen-pixels", type=int, default=64, help="per-triangle view size (default 64)")
    optimize.add_argument("--workers", type=int, default=0, help="worker processes (0: one per core)")
    optimize.add_argument("--seed", type=int, default=0)
    optimize.add_argument("--out", required=True, type=_output_model, help="OUT.blend or OUT.glb")
    optimize.add_argument("--report", type=pathlib.Path, help="write the JSON report here")

    evaluate = commands.add_parser("evaluate", help="perceptual loss of a UV map at several relative costs")
    evaluate.add_argument("input", metavar="IN", type=_existing_model)
    evaluate.add_argument("--uv", required=True, help="UV map to evaluate")
    evaluate.add_argument("--ref-uv", help="UV map of the reference texture (default: the active one)")
    evaluate.add_argument("--costs", type=_costs, default=[0.1, 0.2, 0.3, 0.5])
    evaluate.add_argument("--json", type=pathlib.Path, help="write the results here")
    evaluate.add_argument("--plot", type=pathlib.Path, help="write a q_r-c_r plot (PNG) here")
    return parser


def _validate(args):
    if args.command == "optimize":
        if not 0 < args.epsilon < 1:
            raise UsageError(f"--epsilon {args.epsilon}: must be in (0, 1)")
        if args.cost is not None and not 0 < args.cost <= 4:
            raise UsageError(f"--cost {args.cost}: must be in (0, 4]")
        if args.resolution is not None and not 8 <= args.resolution <= 16384:
            raise UsageError(f"--resolution {args.resolution}: must be in [8, 16384]")
        if args.iterations < 10:
            raise UsageError(f"--iterations {args.iterations}: at least 10 evaluations per triangle")
        if args.workers < 0:
            raise UsageError(f"--workers {args.workers}: must be >= 0")
        if args.cost is None and args.resolution is None:
            args.cost = 0.3
    return args


def parse_args(argv):
    """Parse and validate ``argv`` (without the program name); raises UsageError on bad input."""
    return _validate(build_parser().parse_args(argv))


def _run(args):
    if args.command == "optimize":
        from .bridge.batch import optimize_file

        return optimize_file(args)
    from .bridge.batch import evaluate_file

    return evaluate_file(args)


def main(argv=None):
    """Run the CLI; returns the process exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args = parse_args(argv)
        _run(args)
    except SystemExit as done:  # --help
        return done.code if isinstance(done.code, int) else 0
    except (UsageError, ValueError, FileNotFoundError, PermissionError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: cancelled", file=sys.stderr)
        return 130
    return 0


def blender_argv(argv):
    """The arguments Blender passes through to a ``--python`` script: everything after ``--``."""
    return argv[argv.index("--") + 1:] if "--" in argv else []


def _import_package_from_file():
    """Import this file's folder as the package ``perceptual_uv`` (a --python script has no package)."""
    import importlib.util

    folder = pathlib.Path(__file__).resolve().parent
    spec = importlib.util.spec_from_file_location(PROG, folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[PROG] = package
    spec.loader.exec_module(package)
    return importlib.import_module(f"{PROG}.cli")


if __name__ == "__main__":
    if __package__:
        sys.exit(main())
    sys.exit(_import_package_from_file().main(blender_argv(sys.argv)))
