"""Install a built extension zip into the user repository, enable, probe, disable, probe; print JSON.

Run with the bpy module's Python and BLENDER_USER_RESOURCES pointing at a temporary folder, e.g.
``BLENDER_USER_RESOURCES=/tmp/x python extension_lifecycle.py dist/perceptual_uv-0.1.0-linux_x64.zip``.
"""
import json
import sys

import bpy

MODULE = "bl_ext.user_default.perceptual_uv"


def uv_menu_has_entry():
    draw_funcs = getattr(bpy.types.IMAGE_MT_uvs.draw, "_draw_funcs", [])
    return any(getattr(func, "__module__", "").startswith(MODULE) for func in draw_funcs)


def probe():
    return {
        "addon_enabled": MODULE in bpy.context.preferences.addons,
        "operator": hasattr(bpy.types, "UV_OT_perceptual_optimize"),
        "operator_label": getattr(getattr(bpy.types, "UV_OT_perceptual_optimize", None), "bl_label", None),
        "panel": hasattr(bpy.types, "IMAGE_PT_perceptual_uv"),
        "panel_space": getattr(getattr(bpy.types, "IMAGE_PT_perceptual_uv", None), "bl_space_type", None),
        "settings_group": bpy.types.PropertyGroup.bl_rna_get_subclass_py("PerceptualUVSettings") is not None,
        "preferences": bpy.types.AddonPreferences.bl_rna_get_subclass_py("PerceptualUVPreferences") is not None,
        "scene_property": "perceptual_uv" in bpy.types.Scene.bl_rna.properties,
        "uv_menu_entry": uv_menu_has_entry(),
        "modules": sorted(name for name in sys.modules if name.startswith(MODULE)),
    }


result = {}
status = bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default", enable_on_install=True)
result["install"] = sorted(status)
result["enabled"] = probe()
import scipy, numba  # noqa: E401,E402  (the bundled wheels must import inside Blender)
result["scipy"], result["numba"] = scipy.__version__, numba.__version__
result["site_packages"] = bpy.utils.user_resource("EXTENSIONS", path=".local")

# The startup cube has a UV map but no image texture: poll refuses it instead of the operator crashing.
result["active_object"] = bpy.context.active_object.name
result["poll_untextured_cube"] = bpy.ops.uv.perceptual_optimize.poll()

bpy.ops.preferences.addon_disable(module=MODULE)
result["disabled"] = probe()
print("RESULT " + json.dumps(result))
