# SPDX-License-Identifier: GPL-3.0-or-later
"""UV editor sidebar tab "Perceptual UV" and the UV menu entry."""
import bpy

from ..operators.clear_cache import UV_OT_perceptual_clear_cache
from ..operators.optimize_uvs import UV_OT_perceptual_optimize
from ..operators.show_loss import UV_OT_perceptual_show_loss
from ..properties import ROLE_COST_FIELDS


def draw_uv_menu_entry(self, context):
    self.layout.separator()
    self.layout.operator(UV_OT_perceptual_optimize.bl_idname, icon="UV")


class IMAGE_PT_perceptual_uv(bpy.types.Panel):
    bl_label = "Perceptual UV"
    bl_space_type = "IMAGE_EDITOR"
    bl_region_type = "UI"
    bl_category = "Perceptual UV"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.perceptual_uv

        col = layout.column()
        col.prop(settings, "epsilon")
        col.prop(settings, "resolution_mode")
        if settings.resolution_mode == "COST":
            col.prop(settings, "target_cost")
            col.prop(settings, "cost_measure")
        else:
            col.prop(settings, "resolution")

        # One cost per kind of map (0: the Relative Cost); the operator turns the others into role costs.
        header, body = layout.panel("perceptual_uv_map_costs", default_closed=True)
        header.label(text="Per-Map Costs")
        if body is not None:
            col = body.column()
            for name, _, _ in ROLE_COST_FIELDS:
                col.prop(settings, name)

        col = layout.column(heading="Optimization")
        col.prop(settings, "iterations")
        col.prop(settings, "screen_pixels")
        col.prop(settings, "max_screen_pixels")
        col.prop(settings, "workers")
        col.prop(settings, "seed")

        col = layout.column(heading="Output")
        col.prop(settings, "margin")
        col.prop(settings, "keep_stacks")
        col.prop(settings, "square_images")
        col.prop(settings, "uv_map_name")
        col.prop(settings, "image_name")
        col.prop(settings, "use_material_copy")

        row = layout.row()
        row.scale_y = 1.5
        op = row.operator(UV_OT_perceptual_optimize.bl_idname, icon="UV")
        for name in settings.bl_rna.properties.keys():
            if name != "rna_type" and hasattr(op, name):
                setattr(op, name, getattr(settings, name))
        layout.operator(UV_OT_perceptual_show_loss.bl_idname, icon="SHADING_SOLID")
        layout.operator(UV_OT_perceptual_clear_cache.bl_idname, icon="TRASH")
