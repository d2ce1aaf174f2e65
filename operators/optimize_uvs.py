# SPDX-License-Identifier: GPL-3.0-or-later
"""Operator "Optimize UVs" (``uv.perceptual_optimize``): the whole method behind one button."""
import dataclasses
import time
import traceback

import bpy

from ..properties import settings_annotations, settings_from

# Time the modal operator spends in the pipeline per timer tick before it hands the UI back.
SLICE_SECONDS = 0.1


def _objects(context):
    """The active object and the other selected meshes: optimized one texture at a time
    (``bridge.texture_sets``; selected meshes that show no texture are left as they are)."""
    active = context.active_object
    return [active, *(obj for obj in context.selected_objects if obj is not active and obj.type == "MESH")]


class UV_OT_perceptual_optimize(bpy.types.Operator):
    """Re-parameterize the UV map so the texture needs fewer pixels for the same look on screen, and bake the
    texture into a new image on a new UV map (the original UV map, image and materials stay as they are)"""

    bl_idname = "uv.perceptual_optimize"
    bl_label = "Optimize UVs"
    bl_options = {"REGISTER", "UNDO"}

    __annotations__ = settings_annotations()

    @classmethod
    def poll(cls, context):
        from ..bridge.read_objects import target_problem

        if context.mode not in {"OBJECT", "EDIT_MESH"}:
            cls.poll_message_set("Switch to Object or Edit Mode")
            return False
        problem = target_problem(context.active_object)
        if problem is not None:
            cls.poll_message_set(problem)
        return problem is None

    def _start(self, context, *, modal=False):
        from ..bridge.texture_sets import iter_optimize_textures

        self._previous_mode = context.mode
        settings = settings_from(self)
        if modal:  # the bake runs in a background process while the modal timer keeps the interface alive
            settings = dataclasses.replace(settings, bake_in_background=True)
        if context.mode == "EDIT_MESH":
            bpy.ops.object.mode_set(mode="OBJECT")  # edit-mode meshes hold their data in BMesh until left
        return iter_optimize_textures(_objects(context), settings)

    def _restore_mode(self):
        if self._previous_mode == "EDIT_MESH":
            bpy.ops.object.mode_set(mode="EDIT")

    def _finish(self, context, runs):
        for _, result in runs:
            report = result.report
            memory = report.get("memory_ratio")
            memory = f"image memory {memory:.2f} of the input's, " if memory is not None else ""
            width, height = report["resolution"]
            self.report({"INFO"}, f"{report['uv_map']}: {width} x {height} px image '{report['image']}', "
                        f"{memory}relative texel cost {report['relative_cost']:.2f}, "
                        f"{report['triangles_within_bound']:.0%} of triangles within the loss bound, "
                        f"{report['times_s']['total']:.0f} s")
            for note in report.get("notes", []):
                self.report({"INFO"}, note)
            for warning in report.get("warnings", []):
                self.report({"WARNING"}, warning)

    def execute(self, context):
        from ..bridge.pipeline import run_to_end

        try:
            runs = run_to_end(self._start(context))
        except (ValueError, OSError, RuntimeError) as error:  # RuntimeError: a dead worker
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        finally:
            self._restore_mode()
        self._finish(context, runs)
        return {"FINISHED"}

    def invoke(self, context, event):
        scene_settings = context.scene.perceptual_uv
        for name in scene_settings.bl_rna.properties.keys():
            if name != "rna_type" and not self.properties.is_property_set(name):
                setattr(self, name, getattr(scene_settings, name))
        try:
            self._pipeline = self._start(context, modal=True)
        except ValueError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self._timer = context.window_manager.event_timer_add(0.05, window=context.window)
        context.window_manager.progress_begin(0, 1000)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end_modal(self, context):
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        context.workspace.status_text_set(None)
        self._restore_mode()

    def modal(self, context, event):
        if event.type == "ESC":
            self._pipeline.close()  # removes everything the run created so far
            self._end_modal(context)
            self.report({"WARNING"}, "Optimize UVs cancelled; nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        deadline = time.perf_counter() + SLICE_SECONDS
        try:
            while time.perf_counter() < deadline:
                progress = next(self._pipeline)
                context.window_manager.progress_update(int(1000 * progress.fraction))
                context.workspace.status_text_set(f"Optimize UVs: {progress.line()} (Esc to cancel)")
        except StopIteration as finished:
            self._end_modal(context)
            self._finish(context, finished.value)
            return {"FINISHED"}
        except (ValueError, OSError) as error:
            self._end_modal(context)
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        except Exception as error:  # noqa: BLE001  an internal failure: still end the modal run cleanly
            # The pipeline has removed what it created; the timer, progress bar and status text are ours.
            traceback.print_exc()
            self._end_modal(context)
            self.report({"ERROR"}, f"Optimize UVs failed ({type(error).__name__}: {error}); nothing was changed, "
                        "details are in the system console")
            return {"CANCELLED"}
        return {"RUNNING_MODAL"}
