# SPDX-License-Identifier: GPL-3.0-or-later
"""Command line interface, the same in both forms:

    python -m perceptual_uv optimize IN --out OUT.blend ...            (bpy module in the venv)
    blender -b FILE --python <extension dir>/cli.py -- optimize IN ...  (arguments after ``--``)

Exit codes: 0 success, 2 bad input (one line on stderr, no traceback), 1 an internal failure (one line on stderr
naming the file the traceback was written to), 130 cancelled.
"""
import argparse
import os
import pathlib
import sys
import threading

PROG = "perceptual_uv"


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


if __name__ == "__main__" and not __package__:  # blender -b FILE --python cli.py -- ARGS
    sys.exit(_import_package_from_file().main(blender_argv(sys.argv)))

from .core.progress import wait_for_threads  # noqa: E402
# After the script bootstrap above:
from .core.settings import COST_MEASURES, COST_ROLES, MODEL_SUFFIXES, OptimizeSettings, suffix_listing  # noqa: E402

OUTPUT_SUFFIXES = (".blend", ".glb", ".fbx")


DEFAULTS = OptimizeSettings()


class UsageError(ValueError):
    """Bad input from the user: reported in one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def _existing_model(text):
    path = pathlib.Path(text)
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise argparse.ArgumentTypeError(
            f"{text}: unsupported input type (expected {suffix_listing(MODEL_SUFFIXES)})")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    return path


def _output_model(text):
    path = pathlib.Path(text)
    if path.suffix.lower() not in OUTPUT_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text}: unsupported output type (expected "
                                         f"{suffix_listing(OUTPUT_SUFFIXES)})")
    return path


def _costs(text):
    try:
        costs = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text}: expected comma-separated numbers such as 0.1,0.2,0.3,0.5") from None
    if not costs or any(not 0 < cost <= 4 for cost in costs):
        raise argparse.ArgumentTypeError(f"{text}: every relative cost must be in (0, 4]")
    return costs


def _role_cost(text):
    """``ROLE=COST`` of ``--cost-for`` as a (role, cost) pair; the settings check the role and the range."""
    role, equals, cost = text.partition("=")
    try:
        return role.strip(), float(cost)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ROLE=COST (e.g. normal=0.2), not {text!r}") from None


def _add_optimize_options(parser, *, workers_flag="--workers"):
    """The options ``optimize`` and ``batch`` share: which object and UV map, and the optimization settings.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser.
    workers_flag : str
        Flag of the per-asset worker processes (``batch`` uses ``--workers`` for its Dask workers).
    """
    parser.add_argument("--object", help="mesh object to optimize (default: the textured mesh objects)")
    parser.add_argument("--uv", help="input UV map (default: the active one, or the one the texture is read "
                                     "through when that is another)")
    parser.add_argument("--epsilon", type=float, default=DEFAULTS.epsilon,
                        help=f"perceptual loss bound (default {DEFAULTS.epsilon})")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--cost", type=float, default=DEFAULTS.target_cost,
                      help="the new images' memory relative to the input's, e.g. 0.25 for a quarter: each map's "
                           f"side is round(sqrt(COST * width * height)) of its input (default {DEFAULTS.target_cost}; "
                           "with --cost-measure texels the paper's relative texel cost, Eq. 21)")
    size.add_argument("--resolution", type=int, default=None, help="explicit texture size in pixels")
    parser.add_argument("--cost-measure", dest="cost_measure", choices=COST_MEASURES, default=DEFAULTS.cost_measure,
                        help=f"what --cost and --cost-for measure (default {DEFAULTS.cost_measure}): memory, the "
                             "images' pixels relative to the input's; texels, the texels the new UV map covers "
                             "relative to the input's (Eq. 20-21, the paper's cost and evaluate's; the image is as "
                             "large as the packing at that texel density needs)")
    parser.add_argument("--iterations", type=int, default=DEFAULTS.iterations, help="loss evaluations per triangle")
    parser.add_argument("--screen-pixels", type=int, default=DEFAULTS.screen_pixels,
                        help=f"per-triangle view size (default {DEFAULTS.screen_pixels}; grows to one pixel per "
                             "input texel, up to --max-screen-pixels)")
    parser.add_argument("--max-screen-pixels", type=int, default=DEFAULTS.max_screen_pixels,
                        help=f"largest per-triangle view size (default {DEFAULTS.max_screen_pixels}; lower it "
                             "to bound the time on large textures)")
    parser.add_argument("--margin", type=int, default=DEFAULTS.margin, help="island margin in pixels")
    parser.add_argument("--unstack", dest="keep_stacks", action="store_false",
                        help="give every UV island texels of its own, also islands that share texels in the input "
                             "(by default they stay stacked and the new images hold those texels once)")
    parser.add_argument("--square-images", action="store_true",
                        help="make every new image a square (by default the packing may choose a width-to-height "
                             "ratio from 2:1 to 1:2 that holds the islands denser in the same memory)")
    parser.add_argument("--cost-for", dest="cost_for", action="append", type=_role_cost, default=[],
                        metavar="ROLE=COST",
                        help="relative cost of one kind of map instead of --cost's, e.g. normal=0.2 (repeatable; "
                             "roles: " + ", ".join(COST_ROLES) + ")")
    parser.add_argument(workers_flag, dest="workers", type=int, default=DEFAULTS.workers,
                        metavar="N" if workers_flag != "--workers" else None,
                        help="worker processes of one asset's triangle-wise stage (0: one per core)")
    parser.add_argument("--seed", type=int, default=DEFAULTS.seed)
    parser.add_argument("--fresh", action="store_true",
                        help="compute the triangle-wise and mesh-wise stages again instead of reusing the results "
                             "an earlier run with the same mesh, UV map, texture and stage settings kept (or the "
                             "triangles a stopped run had done)")
    parser.add_argument("--bake-in-background", dest="bake_in_background", action="store_true",
                        help="bake the maps in a background Blender process, as the Optimize UVs button does "
                             "(the same pixels; it adds the start-up of one more process)")


def _add_batch_options(batch):
    """``batch``'s own options; the optimization settings come from :func:`_add_optimize_options`."""
    batch.add_argument("inputs", metavar="INPUT", nargs="+",
                       help=f"model files, folders (searched recursively for {suffix_listing(MODEL_SUFFIXES)} "
                            "files) or globs")
    batch.add_argument("--out", required=True, type=pathlib.Path,
                       help="output folder: the input tree mirrored, one folder per asset, manifest and summary")
    batch.add_argument("--format", choices=tuple(suffix[1:] for suffix in OUTPUT_SUFFIXES), default="blend",
                       help="output format (default blend)")
    batch.add_argument("--scheduler", metavar="ADDRESS",
                       help="Dask scheduler address, e.g. tcp://host:8786 (default: a local cluster)")
    batch.add_argument("--workers", dest="dask_workers", type=int, default=None, metavar="N",
                       help="local Dask worker processes, one asset at a time each (default: cores / "
                            "--asset-workers, at least 1; not with --scheduler)")
    batch.add_argument("--timeout", type=float, default=None, metavar="S",
                       help="seconds one asset may take before it is killed and retried (default: no limit)")
    batch.add_argument("--retries", type=int, default=1,
                       help="new attempts after a crash, a dead worker or a timeout (default 1)")
    batch.add_argument("--blender", metavar="PATH",
                       help="run each asset as `PATH -b --factory-startup --python cli.py -- optimize ...` "
                            "instead of `python -m perceptual_uv optimize ...` with the bpy module")


def build_parser():
    parser = _Parser(prog=PROG, description="Re-parameterize a textured mesh's UV map so its texture needs fewer "
                     "pixels for the same look on screen (Sun et al. 2022).")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    optimize = commands.add_parser("optimize", help="optimize the UV map of a model and bake its texture")
    optimize.add_argument("input", metavar="IN", type=_existing_model,
                          help=suffix_listing(MODEL_SUFFIXES))
    _add_optimize_options(optimize)
    optimize.add_argument("--scheduler", metavar="ADDRESS",
                          help="Dask scheduler (e.g. tcp://host:8786): the triangle-wise stage runs on every worker "
                               "of that cluster, with the same results as here (needs dask and distributed)")
    optimize.add_argument("--out", required=True, type=_output_model,
                          help=suffix_listing(tuple("OUT" + suffix for suffix in OUTPUT_SUFFIXES)))
    optimize.add_argument("--report", type=pathlib.Path, help="write the JSON report here")

    batch = commands.add_parser("batch", help="optimize every model of an asset library on Dask (resumable)")
    _add_batch_options(batch)
    _add_optimize_options(batch, workers_flag="--asset-workers")
    batch.set_defaults(workers=1)  # --asset-workers: assets run side by side, one process each by default

    evaluate = commands.add_parser("evaluate", help="perceptual loss of a UV map at several relative costs")
    evaluate.add_argument("input", metavar="IN", type=_existing_model)
    evaluate.add_argument("--uv", required=True, help="UV map to evaluate")
    evaluate.add_argument("--texture", metavar="IMAGE",
                          help="evaluate the meshes that show this image (a file whose meshes show several)")
    evaluate.add_argument("--ref-uv", help="UV map of the reference texture (default: the active one)")
    evaluate.add_argument("--costs", type=_costs, default=[0.1, 0.2, 0.3, 0.5])
    evaluate.add_argument("--json", type=pathlib.Path, help="write the results here")
    evaluate.add_argument("--plot", type=pathlib.Path, help="write a q_r-c_r plot (PNG) here")
    evaluate.add_argument("--shaded", action="store_true",
                          help="render the whole material (every map re-baked) under fixed lights with Cycles "
                               "instead of the base colour alone, and report q_r per map")
    evaluate.add_argument("--screen", type=int, default=512, help="side of each of the 20 views (default 512)")
    return parser


def _validate(args):
    if args.command == "batch":
        if args.retries < 0:
            raise UsageError(f"--retries must be 0 or more, not {args.retries}")
        if args.timeout is not None and not args.timeout > 0:
            raise UsageError(f"--timeout must be positive, not {args.timeout}")
        if args.dask_workers is not None and args.scheduler:
            raise UsageError("--workers sets the local cluster's size; the cluster at --scheduler has its own workers")
        if args.dask_workers is not None and args.dask_workers < 1:
            raise UsageError(f"--workers must be 1 or more, not {args.dask_workers}")
    if args.command == "evaluate" and not 16 <= args.screen <= 4096:
        raise UsageError(f"--screen must be in [16, 4096], not {args.screen}")
    if args.command in ("optimize", "batch"):
        try:
            args.settings = OptimizeSettings(
                epsilon=args.epsilon, target_cost=args.cost, resolution=args.resolution, iterations=args.iterations,
                screen_pixels=args.screen_pixels, max_screen_pixels=args.max_screen_pixels, margin=args.margin,
                keep_stacks=args.keep_stacks, square_images=args.square_images, workers=args.workers, seed=args.seed,
                reuse_triangle_results=not args.fresh,
                bake_in_background=args.bake_in_background, role_costs=tuple(args.cost_for),
                cost_measure=args.cost_measure,
                scheduler=args.scheduler if args.command == "optimize" else None)
        except ValueError as error:
            raise UsageError(str(error)) from None
    return args


def parse_args(argv):
    """Parse and validate ``argv`` (without the program name); raises UsageError on bad input."""
    return _validate(build_parser().parse_args(argv))


def _run(args):
    if args.command == "batch":
        from .library_batch.run import run_batch

        return run_batch(args)
    if args.command == "optimize":
        from .bridge.batch import optimize_file

        return optimize_file(args)
    from .bridge.batch import evaluate_file

    return evaluate_file(args)


# Longest wait for the stages' threads before the process exits (one mesh-wise iteration, a worker pool's start or
# an image's encoding take seconds at most): a thread that hangs must not keep a cancelled run from exiting.
THREADS_WAIT_S = 60.0

# Set by SIGTERM/SIGINT: a KeyboardInterrupt raised while numba compiles a kernel can be swallowed by the
# compiler, so the run also checks this between steps (``args.interrupted``) and cancels there.
_INTERRUPTED = threading.Event()


def _interrupt(signum, frame):
    _INTERRUPTED.set()
    raise KeyboardInterrupt


def _was_interrupted(error):
    """Whether a KeyboardInterrupt caused ``error``: numba wraps one raised while it loads a compiled kernel in
    a SystemError, and the interrupt must still cancel cleanly."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


def _write_traceback(error):
    """Write ``error``'s traceback to a new file in the temporary folder; returns its path."""
    import tempfile
    import traceback

    handle, path = tempfile.mkstemp(prefix=f"{PROG}-internal-error-", suffix=".txt")
    with os.fdopen(handle, "w") as out:
        out.write("".join(traceback.format_exception(error)))
    return path


def _forget_handled_interrupt():
    """Make the interpreter forget a KeyboardInterrupt this CLI has handled.

    CPython 3.11 remembers one that left any code run through its C API (``PyRun_*``, as Blender runs Python),
    even when a caller caught it, and ends a ``python -m`` process by SIGINT instead of its exit code: a cancelled
    run exited -2 instead of 130 when the signal landed there. The flag is a global of that interpreter; elsewhere
    there is nothing to forget."""
    import ctypes

    try:
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except (ValueError, AttributeError):
        pass


def main(argv=None):
    """Run the CLI; returns the process exit code.

    Before it returns, the stages' threads that a cancel or an error left running finish (they stop at their
    next check or are bounded): a daemon thread still in numpy while the interpreter shuts down makes the
    process exit 120 instead of this code. A second Ctrl-C or SIGTERM meanwhile, or :data:`THREADS_WAIT_S`,
    stops waiting. A cancel exits 130 (:func:`_forget_handled_interrupt`)."""
    code = _main(argv)
    try:
        wait_for_threads(timeout=THREADS_WAIT_S)
    except KeyboardInterrupt:
        code = 130
    _forget_handled_interrupt()
    return code


def _main(argv):
    import signal

    argv = sys.argv[1:] if argv is None else list(argv)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _interrupt)  # a batch system's stop cleans up like Ctrl-C
        signal.signal(signal.SIGINT, _interrupt)
    _INTERRUPTED.clear()
    try:
        args = parse_args(argv)
        args.interrupted = _INTERRUPTED
        result = _run(args)
        if args.command == "batch":
            return result  # 0: every asset has its output; 1: some failed or were bad inputs (the summary lists them)
    except SystemExit as done:  # --help
        return done.code if isinstance(done.code, int) else 0
    except (UsageError, ValueError, FileNotFoundError, PermissionError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except NotImplementedError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: cancelled", file=sys.stderr)
        return 130
    except Exception as error:
        if _was_interrupted(error):
            print(f"{PROG}: cancelled", file=sys.stderr)
            return 130
        if type(error).__name__ == "WorkerDiedError":
            print(f"{PROG}: error: {error}", file=sys.stderr)
            return 1
        print(f"{PROG}: internal error: {type(error).__name__}: {error} (traceback written to "
              f"{_write_traceback(error)})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
