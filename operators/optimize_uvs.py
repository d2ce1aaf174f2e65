# SPDX-License-Identifier: GPL-3.0-or-later
"""Operator "Optimize UVs" (``uv.perceptual_optimize``)."""
import bpy

from ..properties import settings_annotations


def _target_problem(obj):
    """Why ``obj`` cannot be optimized, or None when it can."""
    from ..bridge.material import base_color_image_node

    if obj is None or obj.type != "MESH":
        return "Select a mesh object"
    if not obj.data.uv_layers:
        return f"Mesh '{obj.data.name}' has no UV map"
    if not any(base_color_image_node(slot.material) for slot in obj.material_slots):
        return f"Object '{obj.name}' has no image texture feeding a material's Base Color"
    return None


class UV_OT_perceptual_optimize(bpy.types.Operator):
    """Re-parameterize the active UV map so the texture needs fewer pixels for the same look on screen"""

    bl_idname = "uv.perceptual_optimize"
    bl_label = "Optimize UVs"
    bl_options = {"REGISTER", "UNDO"}

    __annotations__ = settings_annotations()

    @classmethod
    def poll(cls, context):
        problem = _target_problem(context.active_object)
        if problem is not None:
            cls.poll_message_set(problem)
        return problem is None

    def execute(self, context):
        self.report({"ERROR"}, "Optimize UVs is not implemented yet")
        return {"CANCELLED"}
