"""Run the Khronos glTF validator (npm package ``gltf-validator``, run with node) on a .glb or .gltf file.

The package is not a Python dependency: it lives in ``.venv/node`` (or the folder named by the environment variable
``PERCEPTUAL_UV_GLTF_VALIDATOR``, the ``--prefix`` folder of an ``npm install``). Install it with::

    .venv/bin/python tests/gltf_validate.py --install

and validate a file from the shell with ``.venv/bin/python tests/gltf_validate.py FILE.glb`` (exit code 1 when the
file has errors). Tests call :func:`unavailable` to skip when node or the package is missing, and
:func:`validate` for the report.
"""
import json
import os
import pathlib
import shutil
import subprocess
import sys

__all__ = ["VALIDATOR_VERSION", "validator_prefix", "unavailable", "install", "validate"]

VALIDATOR_VERSION = "2.0.0-dev.3.10"
REPO = pathlib.Path(__file__).resolve().parent.parent

# Reads the file, resolves external resources (.bin, images of a .gltf) next to it, prints the report as JSON.
_SCRIPT = r"""
const fs = require("fs");
const path = require("path");
const validator = require(process.argv[1]);
const file = process.argv[2];
const folder = path.dirname(file);
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
  uri: path.basename(file),
  maxIssues: 1000,
  externalResourceFunction: (uri) => new Promise((resolve, reject) => {
    fs.readFile(path.join(folder, decodeURIComponent(uri)), (error, data) => error ? reject(error.toString())
                                                                                  : resolve(new Uint8Array(data)));
  }),
}).then((report) => { process.stdout.write(JSON.stringify(report)); })
  .catch((error) => { process.stderr.write(String(error)); process.exit(3); });
"""


def validator_prefix():
    """The npm ``--prefix`` folder that holds (or will hold) ``node_modules/gltf-validator``."""
    return pathlib.Path(os.environ.get("PERCEPTUAL_UV_GLTF_VALIDATOR") or REPO / ".venv" / "node")


def _module_dir():
    return validator_prefix() / "node_modules" / "gltf-validator"


def unavailable():
    """Why the validator cannot run here (a sentence for ``pytest.skip``), or None when it can."""
    if shutil.which("node") is None:
        return "node is not installed (Debian package nodejs)"
    if not (_module_dir() / "package.json").is_file():
        return (f"the npm package gltf-validator is not installed in {validator_prefix()}: run "
                "'.venv/bin/python tests/gltf_validate.py --install'")
    return None


def install():
    """``npm install`` the pinned validator into :func:`validator_prefix`; returns npm's exit code."""
    if shutil.which("npm") is None:
        print("npm is not installed (Debian package npm)", file=sys.stderr)
        return 1
    prefix = validator_prefix()
    prefix.mkdir(parents=True, exist_ok=True)
    command = ["npm", "install", "--prefix", str(prefix), "--no-audit", "--no-fund", "--no-save",
               f"gltf-validator@{VALIDATOR_VERSION}"]
    return subprocess.run(command).returncode


def validate(path, *, timeout=120):
    """Validate ``path`` (.glb, or .gltf with its resources beside it).

    Returns
    -------
    dict
        ``errors``, ``warnings``, ``infos``, ``hints`` (counts), ``messages`` (the validator's issue list: dicts
        with ``code``, ``message``, ``severity`` 0 error .. 3 hint, ``pointer``) and ``report`` (the whole report).

    Raises
    ------
    RuntimeError
        The validator is unavailable or failed to run (not: the file has errors, which the counts say).
    """
    reason = unavailable()
    if reason:
        raise RuntimeError(reason)
    path = pathlib.Path(path).resolve()
    if not path.is_file():
        raise FileNotFoundError(f"no file to validate at {path}")
    run = subprocess.run(["node", "-e", _SCRIPT, str(_module_dir()), str(path)], capture_output=True, text=True,
                         timeout=timeout)
    if run.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {path} (exit {run.returncode}): {run.stderr.strip()[-2000:]}")
    report = json.loads(run.stdout)
    issues = report["issues"]
    return {"errors": issues["numErrors"], "warnings": issues["numWarnings"], "infos": issues["numInfos"],
            "hints": issues["numHints"], "messages": issues["messages"], "report": report}


def _main(argv):
    if argv == ["--install"]:
        return install()
    if len(argv) != 1 or argv[0].startswith("-"):
        print(__doc__.strip(), file=sys.stderr)
        return 2
    result = validate(argv[0])
    severities = {0: "error", 1: "warning", 2: "info", 3: "hint"}
    shown = 20
    for message in result["messages"][:shown]:
        print(f"{severities.get(message['severity'], message['severity'])}: {message['code']} "
              f"{message.get('pointer', '')}: {message['message']}")
    if len(result["messages"]) > shown:
        codes = {}
        for message in result["messages"]:
            codes[message["code"]] = codes.get(message["code"], 0) + 1
        print(f"... {len(result['messages']) - shown} more; all issues by code: "
              + ", ".join(f"{code} {count}" for code, count in sorted(codes.items())))
    print(f"{result['errors']} errors, {result['warnings']} warnings, {result['infos']} infos, "
          f"{result['hints']} hints")
    return 1 if result["errors"] else 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
