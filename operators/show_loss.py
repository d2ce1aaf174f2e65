# SPDX-License-Identifier: GPL-3.0-or-later
"""Operator "Show Loss Overlay" (``uv.perceptual_show_loss``): colour the mesh by its per-triangle loss."""
import bpy


class UV_OT_perceptual_show_loss(bpy.types.Operator):
    """Show the perceptual loss per face in the 3D viewport (green: within the bound, red: twice over it)"""

    bl_idname = "uv.perceptual_show_loss"
    bl_label = "Show Loss Overlay"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        from ..bridge.loss_overlay import LOSS_COLOR_ATTRIBUTE

        obj = context.active_object
        if obj is None or obj.type != "MESH" or LOSS_COLOR_ATTRIBUTE not in obj.data.color_attributes:
            cls.poll_message_set("Run Optimize UVs on the active mesh first")
            return False
        return True

    def execute(self, context):
        from ..bridge.loss_overlay import LOSS_COLOR_ATTRIBUTE

        mesh = context.active_object.data
        mesh.color_attributes.active_color = mesh.color_attributes[LOSS_COLOR_ATTRIBUTE]
        views = [space for area in context.screen.areas if area.type == "VIEW_3D" for space in area.spaces
                 if space.type == "VIEW_3D"] if context.screen else []
        for space in views:
            space.shading.type = "SOLID"
            space.shading.color_type = "VERTEX"
        if not views:
            self.report({"WARNING"}, "No 3D viewport to show the overlay in")
        return {"FINISHED"}
