"""Files written whole or not at all: a reader (or a run cut off by a full disk, a kill, a crash) never sees half
of one."""
import contextlib
import os
import pathlib
import uuid

__all__ = ["atomic_path"]


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block finishes.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write; its folder is created if missing.

    Yields
    ------
    pathlib.Path
        A name in the same folder (so the rename is atomic) with the same suffix (writers that add or check one
        keep working), unique per call, not created beforehand (writers that back up an existing file leave
        nothing behind). Whatever is left at that name when the block raises is removed.

    Examples
    --------
    >>> import json, tempfile
    >>> folder = tempfile.mkdtemp()
    >>> with atomic_path(f"{folder}/report.json") as temporary:
    ...     _ = temporary.write_text(json.dumps({"ok": True}))
    >>> sorted(p.name for p in pathlib.Path(folder).iterdir())
    ['report.json']
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:12]}.partial{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            temporary.unlink()
