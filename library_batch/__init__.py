# SPDX-License-Identifier: GPL-3.0-or-later
"""Batch optimization of an asset library on Dask distributed (``python -m perceptual_uv batch``).

Every asset runs as its own ``optimize`` subprocess, launched from a Dask task: a fresh factory-settings bpy
session per asset, killable on a timeout. Modules:

- ``inputs``: find the models of the INPUT arguments, hash each one's bytes (and its external files) with the
  settings, and lay the outputs out as the input tree mirrored under the output folder.
- ``manifest``: the append-only ``manifest.jsonl`` that makes runs resumable, and the summary files.
- ``task``: the Dask task, run in a worker process: one ``optimize`` child, published only when it succeeds.
- ``run``: the orchestrator (LocalCluster or a scheduler address, retries, progress, Ctrl-C).

Nothing here imports bpy; dask is imported only by ``run``, when a batch starts.
"""

__all__ = []
