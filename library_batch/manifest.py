# SPDX-License-Identifier: GPL-3.0-or-later
"""The batch manifest (``OUT/manifest.jsonl``, one JSON object per finished asset, appended as results arrive)
and the summary files (``OUT/summary.json``, ``OUT/summary.csv``)."""
import csv
import io
import json
import os
import pathlib

__all__ = ["MANIFEST_NAME", "Manifest", "image_memory", "summarize", "write_summary"]

MANIFEST_NAME = "manifest.jsonl"
_BYTES_PER_TEXEL = 4  # RGBA, 8 bits per channel, no mipmaps


class Manifest:
    """Append-only record of finished assets; the last entry of an asset is its state.

    Parameters
    ----------
    folder : path-like
        The batch's output folder.
    """

    def __init__(self, folder):
        self.folder = pathlib.Path(folder)
        self.path = self.folder / MANIFEST_NAME
        self.entries = {}
        self.ignored_lines = 0
        if self.path.is_file():
            with open(self.path, encoding="utf-8") as stream:
                for line in stream:
                    try:
                        entry = json.loads(line)
                        self.entries[entry["asset"]] = entry
                    except (ValueError, KeyError, TypeError):  # a line cut by a crash, or foreign text
                        self.ignored_lines += bool(line.strip())

    def outputs_exist(self, entry):
        """Whether every output file an entry lists is still there."""
        return bool(entry.get("outputs")) and all((self.folder / p).is_file() for p in entry["outputs"])

    def finished(self, asset_id, key):
        """The entry that makes asset ``asset_id`` with content key ``key`` need no new run, or None.

        A "done" entry counts while its outputs exist; a "bad_input" entry counts as is (the same bytes with the
        same settings and version fail the same way).
        """
        entry = self.entries.get(asset_id)
        if entry is None or entry.get("key") != key:
            return None
        if entry["status"] == "done" and self.outputs_exist(entry):
            return entry
        if entry["status"] == "bad_input":
            return entry
        return None

    def append(self, entry):
        """Write one entry (a JSON line, flushed to disk before returning) and keep it as the asset's state."""
        self.folder.mkdir(parents=True, exist_ok=True)
        line = json.dumps(entry, sort_keys=True) + "\n"
        with open(self.path, "a+b") as stream:
            stream.seek(0, os.SEEK_END)
            if stream.tell():
                stream.seek(-1, os.SEEK_END)
                if stream.read(1) != b"\n":  # a line cut by a crash stays on its own line
                    line = "\n" + line
            stream.write(line.encode("utf-8"))
            stream.flush()
            os.fsync(stream.fileno())
        self.entries[entry["asset"]] = entry


def image_memory(report):
    """(before, after) bytes of the texture images of a report, or (None, None).

    Uses the report's ``image_memory`` {"before", "after"} when it has one, else the input and output resolutions
    at 4 bytes per texel (8-bit RGBA, no mipmaps).
    """
    if not report:
        return None, None
    memory = report.get("image_memory")
    if isinstance(memory, dict) and "before" in memory and "after" in memory:
        return int(memory["before"]), int(memory["after"])
    size_in, size_out = report.get("input_resolution"), report.get("resolution")
    if not size_in or not size_out:
        return None, None
    return _pixels(size_in) * _BYTES_PER_TEXEL, _pixels(size_out) * _BYTES_PER_TEXEL


def _pixels(size):
    """Pixels of an image whose report gives ``[width, height]`` or (older reports) its side."""
    return int(size[0]) * int(size[1]) if isinstance(size, (list, tuple)) else int(size) ** 2


_CSV_FIELDS = ("asset", "status", "time_s", "attempts", "relative_cost", "resolution", "image_bytes_before",
               "image_bytes_after", "input_bytes", "output_bytes", "duplicate_of", "error", "outputs")


def summarize(entries, *, run, slowest=5):
    """The summary of a batch: counts, image memory before and after, time, slowest assets.

    Parameters
    ----------
    entries : list of dict
        The manifest entries of every asset of the batch (this run's and the skipped ones').
    run : dict
        This run's facts: ``started``, ``total_time_s``, ``skipped``, ``cluster`` ...; copied into the summary.
    slowest : int
        How many of the slowest assets to list.

    Returns
    -------
    dict
    """
    counts = {"assets": len(entries)}
    for status in ("done", "bad_input", "failed"):
        counts[status] = sum(e["status"] == status for e in entries)
    counts["duplicates"] = sum(bool(e.get("duplicate_of")) for e in entries)
    done = [e for e in entries if e["status"] == "done"]
    before = [e.get("image_bytes_before") for e in done]
    after = [e.get("image_bytes_after") for e in done]
    known = [(b, a) for b, a in zip(before, after) if b is not None and a is not None]
    timed = sorted((e for e in done if not e.get("duplicate_of")), key=lambda e: -(e.get("time_s") or 0))
    return dict(run, counts=counts,
                image_memory={"assets": len(known), "before_bytes": sum(b for b, _ in known),
                              "after_bytes": sum(a for _, a in known),
                              "ratio": (sum(a for _, a in known) / sum(b for b, _ in known)) if known else None},
                slowest=[{"asset": e["asset"], "time_s": e.get("time_s")} for e in timed[:slowest]],
                problems=[{"asset": e["asset"], "status": e["status"], "error": e.get("error", "")}
                          for e in entries if e["status"] != "done"])


def _replace_text(path, text):
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)


def write_summary(folder, summary, entries):
    """Write ``summary.json`` (the summary) and ``summary.csv`` (one row per asset), each replaced atomically.

    Returns
    -------
    tuple of pathlib.Path
        The two files.
    """
    folder = pathlib.Path(folder)
    json_path, csv_path = folder / "summary.json", folder / "summary.csv"
    _replace_text(json_path, json.dumps(summary, indent=2) + "\n")
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=_CSV_FIELDS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for entry in sorted(entries, key=lambda e: e["asset"]):
        size = entry.get("resolution")
        writer.writerow(dict(entry, outputs=" ".join(entry.get("outputs", [])), attempts=entry.get("attempts"),
                             resolution="x".join(map(str, size)) if isinstance(size, (list, tuple)) else size))
    _replace_text(csv_path, buffer.getvalue())
    return json_path, csv_path
