# SPDX-License-Identifier: GPL-3.0-or-later
"""Perceptual UV: re-parameterize a textured mesh's UV map so its texture needs fewer pixels for the same look.

Implements Sun et al., "Efficient Texture Parameterization Driven by Perceptual-Loss-on-Screen",
Computer Graphics Forum 41(7), 2022. Importing this package does not import bpy: ``core`` runs in worker
processes and plain Python; Blender calls ``register``/``unregister``.
"""

_SUBMODULES = ("properties", "operators", "panels")


def _modules():
    import importlib

    return [importlib.import_module(f"{__name__}.{name}") for name in _SUBMODULES]


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
