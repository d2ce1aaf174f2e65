# SPDX-License-Identifier: GPL-3.0-or-later
"""Find the image texture that feeds a material's base colour."""

__all__ = ["base_color_image_node"]


def _upstream_image_node(socket, seen):
    for link in socket.links:
        node = link.from_node
        if node in seen:
            continue
        seen.add(node)
        if node.type == "TEX_IMAGE" and node.image is not None:
            return node
        for upstream in node.inputs:
            found = _upstream_image_node(upstream, seen)
            if found is not None:
                return found
    return None


def base_color_image_node(material):
    """The Image Texture node whose image feeds ``material``'s base colour, or None.

    Follows links upstream from the Principled BSDF's "Base Color" (or, failing that, from the active
    Material Output's surface), through mix and colour nodes, to the first Image Texture node with an image.
    """
    if material is None or material.node_tree is None:
        return None
    nodes = material.node_tree.nodes
    sockets = [node.inputs["Base Color"] for node in nodes if node.type == "BSDF_PRINCIPLED"]
    sockets += [node.inputs["Surface"] for node in nodes if node.type == "OUTPUT_MATERIAL" and node.is_active_output]
    for socket in sockets:
        found = _upstream_image_node(socket, set())
        if found is not None:
            return found
    return None
