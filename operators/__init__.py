# SPDX-License-Identifier: GPL-3.0-or-later
import bpy

from .clear_cache import UV_OT_perceptual_clear_cache
from .optimize_uvs import UV_OT_perceptual_optimize
from .show_loss import UV_OT_perceptual_show_loss

classes = (UV_OT_perceptual_optimize, UV_OT_perceptual_show_loss, UV_OT_perceptual_clear_cache)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
