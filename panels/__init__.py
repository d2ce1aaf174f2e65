# SPDX-License-Identifier: GPL-3.0-or-later
import bpy

from .uv_sidebar import IMAGE_PT_perceptual_uv, draw_uv_menu_entry

classes = (IMAGE_PT_perceptual_uv,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.IMAGE_MT_uvs.append(draw_uv_menu_entry)


def unregister():
    bpy.types.IMAGE_MT_uvs.remove(draw_uv_menu_entry)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
