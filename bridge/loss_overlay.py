# SPDX-License-Identifier: GPL-3.0-or-later
"""The loss overlay: each polygon's perceptual loss E as a face attribute and a colour, for the viewport.

A run writes them on the optimized mesh (the Show Loss operator displays the colour); a glTF export leaves them
out (:mod:`.gltf_export`): they are for Blender, not part of the asset.
"""
import numpy as np

__all__ = ["LOSS_ATTRIBUTE", "LOSS_COLOR_ATTRIBUTE", "loss_ramp", "write_loss_attributes", "write_polygon_losses"]

LOSS_ATTRIBUTE = "perceptual_loss"
LOSS_COLOR_ATTRIBUTE = "perceptual_loss_color"


def loss_ramp(losses, epsilon):
    """Overlay colours: green at E = 0, yellow at E = epsilon, red from 2 epsilon on.

    Parameters
    ----------
    losses : (k,) array_like
    epsilon : float

    Returns
    -------
    (k, 4) float32 ndarray
        Linear RGBA.
    """
    t = np.clip(np.asarray(losses, dtype=np.float64) / (2.0 * epsilon), 0.0, 1.0)
    rgba = np.ones((len(t), 4), dtype=np.float32)
    rgba[:, 0] = np.minimum(1.0, 2.0 * t)
    rgba[:, 1] = np.minimum(1.0, 2.0 - 2.0 * t)
    rgba[:, 2] = 0.0
    return rgba


def write_loss_attributes(obj, tri_polygons, losses, epsilon, created):
    """Per polygon, the largest E of its triangles: a float face attribute, and a colour for the overlay.

    Parameters
    ----------
    obj : bpy.types.Object
        A mesh object; attributes of these names that it has already are replaced.
    tri_polygons : (k,) array_like of int
        The polygon of each triangle.
    losses : (k,) ndarray
        E per triangle.
    epsilon : float
        The bound, for :func:`loss_ramp`.
    created : list
        Gets ``(mesh, name)`` of each attribute made, so that a cancelled run can remove them.
    """
    mesh = obj.data
    polygon_loss = np.zeros(len(mesh.polygons), dtype=np.float32)
    np.maximum.at(polygon_loss, tri_polygons, losses.astype(np.float32))
    write_polygon_losses(mesh, polygon_loss, epsilon, created)


def write_polygon_losses(mesh, polygon_loss, epsilon, created):
    """The overlay's attributes of ``mesh`` from E per polygon (``polygon_loss``, (p,) float32): the float face
    attribute and its colour on every corner of the polygon (:func:`write_loss_attributes`' second half)."""
    for name in (LOSS_ATTRIBUTE, LOSS_COLOR_ATTRIBUTE):
        if name in mesh.attributes:
            mesh.attributes.remove(mesh.attributes[name])
    attribute = mesh.attributes.new(LOSS_ATTRIBUTE, "FLOAT", "FACE")
    created.append((mesh, LOSS_ATTRIBUTE))
    attribute.data.foreach_set("value", polygon_loss)
    # Colour attributes live on points or corners: every corner of a polygon gets its polygon's colour.
    loop_totals = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", loop_totals)
    loop_polygon = np.repeat(np.arange(len(mesh.polygons)), loop_totals)
    colors = mesh.attributes.new(LOSS_COLOR_ATTRIBUTE, "BYTE_COLOR", "CORNER")
    created.append((mesh, LOSS_COLOR_ATTRIBUTE))
    colors.data.foreach_set("color", loss_ramp(polygon_loss, epsilon)[loop_polygon].ravel())
