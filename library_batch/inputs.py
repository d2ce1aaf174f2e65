# SPDX-License-Identifier: GPL-3.0-or-later
"""The assets of a batch: which files, what identifies their content, and where their outputs go."""
import dataclasses
import glob
import hashlib
import json
import os
import pathlib

from ..core.settings import MODEL_SUFFIXES, suffix_listing
from .external_files import external_files, forget_folder_listings

__all__ = ["Asset", "find_models", "external_files", "content_key", "plan_assets"]

_GLOB_CHARS = frozenset("*?[")
_KINDS = suffix_listing(MODEL_SUFFIXES)
_CHUNK = 1 << 20


@dataclasses.dataclass
class Asset:
    """One input model and where its results go.

    Attributes
    ----------
    input : pathlib.Path
        The model file (resolved).
    relative : pathlib.PurePosixPath
        Its path below the common folder of the INPUT arguments.
    folder : pathlib.Path
        Its output folder: ``OUT / relative.parent / relative.stem`` (``stem_ext`` when two inputs of one folder
        share a stem).
    key : str
        SHA-256 of the input's bytes, its external files' bytes and the settings.
    """

    input: pathlib.Path
    relative: pathlib.PurePosixPath
    folder: pathlib.Path
    key: str = ""

    @property
    def name(self):
        """File stem of the outputs (the folder's name)."""
        return self.folder.name

    @property
    def id(self):
        """The asset's identity in the manifest: its input path relative to the common input folder."""
        return self.relative.as_posix()


def _is_model(path):
    return path.suffix.lower() in MODEL_SUFFIXES and path.is_file()


def _under(path, folder):
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False


def _walk(folder, *, skip):
    """Model files below ``folder``, recursively, hidden folders and the ``skip`` folder left out."""
    found = []
    for root, dirs, files in os.walk(folder):
        root_path = pathlib.Path(root)
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not _under(root_path / d, skip))
        found += [root_path / f for f in sorted(files) if not f.startswith(".") and _is_model(root_path / f)]
    return found


def _glob_root(pattern):
    """The folder a glob pattern starts from: its leading components without wildcards."""
    parts = pathlib.PurePath(pattern).parts
    fixed = []
    for part in parts:
        if _GLOB_CHARS & set(part):
            break
        fixed.append(part)
    return pathlib.Path(*fixed) if fixed else pathlib.Path(".")


def find_models(arguments, *, out):
    """The model files the INPUT arguments name, and the folder each argument is rooted at.

    Parameters
    ----------
    arguments : sequence of str
        Files, folders (searched recursively for the model files of :data:`.core.settings.MODEL_SUFFIXES`) and globs
        (``**`` recurses).
    out : path-like
        The output folder; models inside it (an earlier run's results) are never inputs.

    Returns
    -------
    models : list of pathlib.Path
        Resolved, without repetitions, in a stable order.
    roots : list of pathlib.Path
        The folder each argument is rooted at (a folder itself, a file's folder, a glob's fixed prefix).

    Raises
    ------
    ValueError
        An argument that names nothing, a file that is not a model, or no model at all.
    """
    out = pathlib.Path(out).resolve()
    models, roots = [], []
    for text in arguments:
        path = pathlib.Path(text)
        if _GLOB_CHARS & set(text):
            matches = [pathlib.Path(m).resolve() for m in sorted(glob.glob(text, recursive=True))]
            found = []
            for match in matches:
                if match.is_dir():
                    found += _walk(match, skip=out)
                elif _is_model(match):
                    found.append(match)
            found = [p for p in found if not _under(p, out)]
            if not found:
                raise ValueError(f"{text}: no {_KINDS} file matches")
            root = _glob_root(text).resolve()
        elif path.is_dir():
            root = path.resolve()
            found = _walk(root, skip=out)
            if not found:
                raise ValueError(f"{text}: no {_KINDS} file in this folder")
        elif path.is_file():
            if path.suffix.lower() not in MODEL_SUFFIXES:
                raise ValueError(f"{text}: unsupported input type (expected one of {', '.join(MODEL_SUFFIXES)})")
            found, root = [path.resolve()], path.resolve().parent
        else:
            raise ValueError(f"{text}: no such file or folder")
        models += found
        roots.append(root)
    return list(dict.fromkeys(models)), roots


def _hash_file(digest, path):
    with open(path, "rb") as stream:
        while chunk := stream.read(_CHUNK):
            digest.update(chunk)


def content_key(path, settings):
    """SHA-256 of a model's bytes, its external files' names and bytes, and the settings.

    Two inputs with the same key give the same result; the input's own path and name are not part of it.

    Parameters
    ----------
    path : path-like
        The model file.
    settings : dict
        JSON-serializable settings that change the result.

    Returns
    -------
    str
        Hex digest.
    """
    path = pathlib.Path(path)
    digest = hashlib.sha256()
    digest.update(json.dumps(settings, sort_keys=True).encode())
    digest.update(path.suffix.lower().encode() + b"\0")
    _hash_file(digest, path)
    for extra in external_files(path):
        digest.update(b"\0" + os.path.relpath(extra, path.parent).encode() + b"\0")
        if extra.is_file():
            _hash_file(digest, extra)
        else:
            digest.update(b"<missing>")
    return digest.hexdigest()


def plan_assets(models, roots, *, out, settings):
    """An :class:`Asset` per model: output folders mirroring the input tree under ``out``, and content keys.

    The mirrored tree starts at the common folder of ``roots``. Two models of one folder with the same stem
    (``a.obj`` and ``a.glb``) get folders named ``a_obj`` and ``a_glb``.
    """
    forget_folder_listings()  # one look at the folders' files per plan
    out = pathlib.Path(out).resolve()
    base = pathlib.Path(os.path.commonpath([str(r) for r in roots])) if roots else pathlib.Path("/")
    relatives = [pathlib.PurePosixPath(pathlib.Path(os.path.relpath(m, base)).as_posix()) for m in models]
    stems = {}
    for rel in relatives:
        stems.setdefault((rel.parent, rel.stem.lower()), []).append(rel)
    assets = []
    for model, rel in zip(models, relatives):
        clash = len(stems[(rel.parent, rel.stem.lower())]) > 1
        name = f"{rel.stem}_{rel.suffix.lower().lstrip('.')}" if clash else rel.stem
        folder = out.joinpath(*rel.parent.parts, name)
        assets.append(Asset(input=model, relative=rel, folder=folder, key=content_key(model, settings)))
    return assets
