# SPDX-License-Identifier: GPL-3.0-or-later
"""Settings shared by the sidebar panel (scene PropertyGroup) and the operator (redo panel, scripts)."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from .core.settings import OptimizeSettings

DEFAULTS = OptimizeSettings()

# The per-map cost fields of the sidebar: (property, role of ``core.settings.COST_ROLES``, label). 0 means "the
# Relative Cost"; "normal" stands for tangent-, object- and world-space normal maps.
ROLE_COST_FIELDS = (
    ("cost_normal", "normal", "Normal"),
    ("cost_metallic_roughness", "metallic_roughness", "Metallic/Roughness"),
    ("cost_emissive", "emissive", "Emissive"),
    ("cost_occlusion", "occlusion", "Occlusion"),
    ("cost_alpha", "alpha", "Alpha"),
    ("cost_data", "data", "Other Data"),
)


def settings_annotations():
    """Fresh property definitions; the operator and the PropertyGroup each get their own copy."""
    return {
        "epsilon": FloatProperty(
            name="Loss Bound", description="Perceptual loss bound epsilon per triangle (GMSD, paper Eq. 7)",
            default=DEFAULTS.epsilon, min=1e-4, max=0.5, precision=4, step=0.1),
        "resolution_mode": EnumProperty(
            name="Resolution", description="How the new texture's resolution is chosen",
            items=(("COST", "Relative Cost", "Resolution from a target cost relative to the input"),
                   ("EXPLICIT", "Explicit", "A fixed texture resolution")),
            default="COST"),
        "target_cost": FloatProperty(
            name="Relative Cost",
            description=("The new images' memory relative to the input's (0.25: a quarter of the pixels, half the "
                         "side); with Cost Measure Texels, the paper's relative texel count (Eq. 21)"),
            default=DEFAULTS.target_cost, min=0.01, max=4.0, precision=3),
        "cost_measure": EnumProperty(
            name="Cost Measure", description="What Relative Cost and the per-map costs measure",
            items=(("memory", "Image Memory",
                    "Each new image has the cost times its input image's pixels; the islands fill the image"),
                   ("texels", "Texels (Paper)",
                    "Texels the new UV map covers relative to the input's (paper Eq. 20-21, the evaluation's "
                    "cost); the image is as large as the packing at that texel density needs")),
            default=DEFAULTS.cost_measure),
        "resolution": IntProperty(
            name="Texture Size", description="Width and height of the new image in pixels",
            default=1024, min=8, max=16384),
        "iterations": IntProperty(
            name="Evaluations", description="Loss evaluations per triangle (Bayesian optimization budget)",
            default=DEFAULTS.iterations, min=10, max=1000),
        "screen_pixels": IntProperty(
            name="Screen Pixels",
            description=("Side of the per-triangle orthographic view (paper App. A); triangles spanning more "
                         "texels get one pixel per texel, up to Largest View"),
            default=DEFAULTS.screen_pixels, min=16, max=256),
        "max_screen_pixels": IntProperty(
            name="Largest View",
            description=("Largest side a per-triangle view grows to on a fine texture; lower bounds the time, "
                         "equal to Screen Pixels keeps every view at that size"),
            default=DEFAULTS.max_screen_pixels, min=16, max=256),
        "margin": IntProperty(
            name="Margin", description="Packing and bake margin in pixels of the new image",
            default=DEFAULTS.margin, min=0, max=64),
        "keep_stacks": BoolProperty(
            name="Keep Stacked Islands",
            description=("Islands that share texels in the input (mirrored halves, repeated parts) stay stacked "
                         "and pack as one, so the new images hold those texels once"),
            default=DEFAULTS.keep_stacks),
        "square_images": BoolProperty(
            name="Square Images",
            description=("Make every new image a square; off, the packing may choose a width-to-height ratio from "
                         "2:1 to 1:2 that holds the islands denser in the same memory"),
            default=DEFAULTS.square_images),
        "workers": IntProperty(
            name="Workers", description="Worker processes for the triangle-wise stage (0: one per core)",
            default=DEFAULTS.workers, min=0, max=256),
        "seed": IntProperty(name="Seed", description="Fixes every random choice", default=DEFAULTS.seed, min=0),
        "uv_map_name": StringProperty(
            name="UV Map", description="Name of the new UV map", default=DEFAULTS.uv_map_name),
        "image_name": StringProperty(
            name="Image", description="Name of the new image (empty: derived from the original image)",
            default=DEFAULTS.image_name),
        "use_material_copy": BoolProperty(
            name="Use in Material Copy",
            description="Assign a copy of the material that samples the new image through the new UV map",
            default=DEFAULTS.use_material_copy),
        **{name: FloatProperty(
            name=label, description=(f"Relative cost of the material's {label.lower()} maps, measured as Cost "
                                     "Measure says (0: the Relative Cost)"),
            default=0.0, min=0.0, max=4.0, precision=3) for name, _, label in ROLE_COST_FIELDS},
    }


def settings_from(props):
    """The OptimizeSettings that a PropertyGroup or operator's properties describe (ValueError if invalid).

    The per-map cost fields (:data:`ROLE_COST_FIELDS`) that are not 0 become ``role_costs``.
    """
    values = {name: getattr(props, name) for name in OptimizeSettings.__dataclass_fields__ if hasattr(props, name)}
    if props.resolution_mode == "COST":
        values["resolution"] = None
    values["role_costs"] = tuple((role, getattr(props, name)) for name, role, _ in ROLE_COST_FIELDS
                                 if getattr(props, name) > 0)
    return OptimizeSettings(**values)


class PerceptualUVSettings(bpy.types.PropertyGroup):
    __annotations__ = settings_annotations()


class PerceptualUVPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    def draw(self, context):
        from .core._jit import cache_dir

        self.layout.label(text=f"Compiled kernels are cached in {cache_dir()}")


classes = (PerceptualUVSettings, PerceptualUVPreferences)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.perceptual_uv = PointerProperty(type=PerceptualUVSettings)


def unregister():
    del bpy.types.Scene.perceptual_uv
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
