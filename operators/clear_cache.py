# SPDX-License-Identifier: GPL-3.0-or-later
"""Operator "Clear Cached Results" (``uv.perceptual_clear_cache``): forget the kept triangle-wise and mesh-wise
results."""
import bpy


class UV_OT_perceptual_clear_cache(bpy.types.Operator):
    """Forget the triangle-wise and mesh-wise results kept from earlier runs, so the next Optimize UVs computes
    them again"""

    bl_idname = "uv.perceptual_clear_cache"
    bl_label = "Clear Cached Results"
    bl_options = {"REGISTER"}

    def execute(self, context):
        from ..bridge.meshwise_stage import meshwise_results
        from ..bridge.trianglewise_stage import triangle_results

        removed = 0
        for cache in (triangle_results(), meshwise_results()):
            try:
                removed += cache.clear()
            except OSError as error:
                self.report({"ERROR"}, f"Could not clear {cache.folder}: {error.strerror or error}")
                return {"CANCELLED"}
        self.report({"INFO"}, f"Removed {removed} cached result(s) from {triangle_results().folder}")
        return {"FINISHED"}
