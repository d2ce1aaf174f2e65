"""What a benchmark's cached result depends on, as hashes: the source of the code it runs and the model's files.

:func:`code_hash` hashes modules of this package with the modules they import, followed through their imports,
or single definitions (``module:name``) of a module that imports everything (:data:`HUBS`), so that a change to
one method there does not invalidate the others' results. ``bench.compare`` keys its result cache with them.
"""
import ast
import hashlib
import pathlib

from ..core.settings import MODEL_SUFFIXES

__all__ = ["PACKAGE", "HUBS", "code_hash", "model_hash"]

PACKAGE = pathlib.Path(__file__).resolve().parent.parent
"""The package's folder (its modules are named relative to it, e.g. ``core.ssp``)."""
HUBS = ("bridge.baselines", "bench.compare")
"""Modules that import every method: followed only when named, never through another module's imports."""


def _module_file(module, package=PACKAGE):
    return package.joinpath(*module.split(".")).with_suffix(".py")


def _imported_modules(module, package=PACKAGE):
    """Modules of this package that ``module`` imports anywhere in its file (also inside functions)."""
    parts = module.split(".")
    found = set()
    for node in ast.walk(ast.parse(_module_file(module, package).read_text())):
        names = []
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = parts[:len(parts) - node.level]
            elif node.module and node.module.split(".")[0] == "perceptual_uv":
                base = []
            else:
                continue
            stem = [p for p in (node.module or "").split(".") if p and p != "perceptual_uv"] if not node.level \
                else [p for p in (node.module or "").split(".") if p]
            names = [".".join(base + stem)] + [".".join(base + stem + [a.name]) for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name.split(".", 1)[1] for a in node.names if a.name.startswith("perceptual_uv.")]
        found.update(n for n in names if n and _module_file(n, package).is_file())
    return found


def _definition_source(module, name, package=PACKAGE):
    """The source of the top-level definition or assignment ``name`` (``Class.method`` too) in ``module``."""
    text = _module_file(module, package).read_text()
    body = ast.parse(text).body
    *outer, last = name.split(".")
    for part in outer:
        body = next(n.body for n in body if isinstance(n, ast.ClassDef) and n.name == part)
    for node in body:
        targets = [t.id for t in getattr(node, "targets", []) if isinstance(t, ast.Name)]
        if getattr(node, "name", None) == last or last in targets:
            return ast.get_source_segment(text, node)
    raise KeyError(f"{module} has no definition {name}")


def code_hash(sources, package=PACKAGE):
    """SHA-256 of the source ``sources`` name: modules with their imports (not through :data:`HUBS`), and
    ``module:name`` definitions (see :data:`.compare.METHOD_SOURCES`)."""
    files, todo, texts = set(), [], []
    for source in sources:
        if ":" in source:
            module, name = source.split(":")
            texts.append(f"{source}\n{_definition_source(module, name, package)}")
        else:
            todo.append((source, True))
    while todo:
        module, named = todo.pop()
        if module in files or (module in HUBS and not named):
            continue
        files.add(module)
        todo.extend((m, False) for m in _imported_modules(module, package))
    texts += [f"{module}\n{_module_file(module, package).read_text()}" for module in sorted(files)]
    return hashlib.sha256("\n".join(sorted(texts)).encode()).hexdigest()


def model_hash(path):
    """SHA-256 of a model file and of every other file in its folder (textures, buffers), names included; the
    folder's other model files (``core.settings.MODEL_SUFFIXES``) are left out."""
    path = pathlib.Path(path)
    digest = hashlib.sha256()
    for file in sorted(f for f in path.parent.rglob("*") if f.is_file()):
        if file.suffix.lower() in MODEL_SUFFIXES and file != path:
            continue
        digest.update(str(file.relative_to(path.parent)).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()
