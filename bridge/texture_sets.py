# SPDX-License-Identifier: GPL-3.0-or-later
"""Optimize objects one texture at a time: the job behind the command line's ``optimize`` and the Optimize UVs
button, whatever number of textures the objects show.

A run (:func:`.pipeline.optimize_objects`) lays one new UV map out for one image. :func:`iter_optimize_textures`
groups the objects by the texture they show (:func:`texture_groups`), splits an object whose slots show several
textures into temporary parts (:mod:`.texture_parts`), refuses before the first run what a later run would
refuse, runs one texture after the other and reports their progress as one, merges the parts back, and on a
cancel or an error removes what every run made. :func:`combined_report` is the report of a job of several runs.
"""
import contextlib
import dataclasses
import time

import bpy

from ..core.progress import run_generator
from .pipeline import Progress, check_objects, optimize_objects
from .texture_parts import iter_split_by_texture, merge_parts, remove_parts

__all__ = ["texture_groups", "groups_and_parts", "iter_groups_and_parts", "part_labels", "iter_optimize_textures",
           "combined_report"]


def texture_groups(objects):
    """The mesh objects among ``objects`` grouped by the image texture they show, in the images' name order.

    The texture is the one that frames a run (:func:`.material.loss_image_nodes`), a mesh's the one of its first
    slot that has one: the base colour's image, and for meshes none of whose materials has one, their largest
    map's (a part with a normal or roughness map and a constant colour is a texture of its own) if they read one
    through their active UV map; meshes that read no image so (an armature's bone shape, a helper, an untextured
    part beside textured ones, a part whose only map is an occlusion map on a second UV map) are not part of the
    model.

    Returns
    -------
    list of (bpy.types.Image, list of bpy.types.Object)

    Raises
    ------
    ValueError
        No mesh among ``objects`` shows an image texture.
    """
    from .material import loss_image_nodes, read_object_materials

    first_image = {}  # each mesh in the group of its first slot's texture

    def add_first_images(meshes):
        slots = [(obj, slot.material) for obj in meshes for slot in obj.material_slots]
        for (obj, _), node in zip(slots, loss_image_nodes(material for _, material in slots)):
            if node is not None:
                first_image.setdefault(obj.name, (obj, node.image))

    def reads_through_its_uv_map(obj):  # an occlusion map on a second UV map alone frames no run
        return len(obj.data.uv_layers) and any(reading.maps for reading in read_object_materials(obj))

    meshes = [obj for obj in objects if obj.type == "MESH"]
    add_first_images(meshes)
    add_first_images([obj for obj in meshes if obj.name not in first_image and reads_through_its_uv_map(obj)])
    groups = {}
    for obj, image in first_image.values():
        groups.setdefault(image.name, (image, []))[1].append(obj)
    if not groups:
        empty = sorted({slot.material.name for obj in meshes for slot in obj.material_slots if slot.material
                        and not any(node.type == "OUTPUT_MATERIAL" for node in getattr(slot.material.node_tree,
                                                                                         "nodes", ()))})
        why = (f" ({len(empty)} of their materials have no shader nodes, e.g. '{empty[0]}': an importer left them "
               "empty, as Blender's USD importer does with MaterialX materials)" if empty else "")
        raise ValueError("no mesh in the file has a material that reads an image texture through a UV map: there "
                         f"is no texture to optimize for{why}")
    return [groups[name] for name in sorted(groups)]


def groups_and_parts(objects):
    """The runs' groups of ``objects``, each with the texture it shows (:func:`texture_groups`), and the
    temporary parts of the objects whose slots show several textures (:func:`.texture_parts.split_by_texture`:
    one run per texture, merged back after the runs). The other users of a split object's mesh (linked
    duplicates) are in no group: the mesh is optimized once, through its first user.

    See Also
    --------
    iter_groups_and_parts : the same, one part per step.
    """
    return run_generator(iter_groups_and_parts(objects))


def iter_groups_and_parts(objects):
    """Generator: :func:`groups_and_parts`, yielding a :class:`.pipeline.Progress` of the ``read`` stage after
    each part it makes (a part copies its object's whole mesh); returns ``(groups, parts)``. Closing it removes
    the parts made so far."""
    parts, split = [], set()
    meshes = [obj for obj in objects if obj.type == "MESH"]
    try:
        for obj in meshes:
            if obj.data.name not in split:
                made = yield from iter_split_by_texture(obj)
                if made:
                    parts += made
                    split.add(obj.data.name)
        groups = texture_groups([obj for obj in meshes if obj.data.name not in split] + [p.part for p in parts])
    except BaseException:
        remove_parts(parts)
        raise
    return groups, parts


def part_labels(parts):
    """How a message names each part (by its object's name): its object and slots."""
    return {part.part.name: f"{part.original.name} (slot{'s' if len(part.slots) > 1 else ''} "
                            f"{', '.join(str(slot + 1) for slot in part.slots)})" for part in parts}


def _iter_check_groups(groups, source_uv):
    """Generator: every refusal of the runs on ``groups`` that needs no mesh reading, before the first starts (one
    that fails after others have run would have cost their time for nothing); a ``read`` step per group."""
    from .material_copy import read_maps
    from .read_objects import source_image

    shown_by = {}
    for number, objects in enumerate(groups):
        image = source_image(objects)
        for obj in objects:
            other = shown_by.setdefault(obj.data.name, (obj, image))
            if other[1] != image:
                raise ValueError(f"mesh '{obj.data.name}' is shared by objects that show different textures "
                                 f"('{other[0].name}' shows '{other[1].name}', '{obj.name}' shows '{image.name}'): "
                                 "one mesh gets one new UV map; give the objects meshes of their own (Object > "
                                 "Relations > Make Single User > Object & Data) or optimize them one at a time")
        objects, _, group_uv = check_objects(objects, source_uv)
        read_maps(objects, group_uv, image)
        yield Progress("read", number + 1, len(groups), f"Checking the texture '{image.name}'")


def iter_optimize_textures(objects, settings, *, source_uv=None, output_dir=None):
    """Generator: optimize ``objects`` one texture at a time (:func:`.pipeline.optimize_objects` per texture).

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        The objects to optimize; meshes that show no texture are left as they are.
    settings : perceptual_uv.core.settings.OptimizeSettings
    source_uv, output_dir
        As :func:`.pipeline.optimize_objects` takes them, for every run.

    Yields
    ------
    Progress
        The runs' steps; with several textures the message starts with the texture's number and name, and the
        fraction and time left are the whole job's (the runs weighed by their faces).

    Returns
    -------
    list of (list of bpy.types.Object, PipelineResult)
        Per texture, the objects its run optimized (an object whose slots show several textures in each of
        their runs, with one new UV map) and the run's result; ``report["objects"]`` names objects, not parts.

    Raises
    ------
    ValueError
        Before the first run, whatever a run would refuse (:func:`.pipeline.check_objects`, the maps'
        refusals, a mesh shared by objects of two textures). A cancel (closing the generator) or an error
        removes what every run made.
    """
    groups, parts = yield from iter_groups_and_parts(objects)
    labels = part_labels(parts)
    runs = []
    try:
        if len(groups) > 1:
            yield from _iter_check_groups([group for _, group in groups], source_uv)
        weights = [sum(len(obj.data.polygons) for obj in group) or 1 for _, group in groups]
        started = time.perf_counter()
        for number, (image, group) in enumerate(groups):
            run = optimize_objects(group, settings, source_uv=source_uv, output_dir=output_dir)
            if len(groups) == 1:
                result = yield from run
            else:
                names = ", ".join(labels.get(obj.name, obj.name) for obj in group)
                result = yield from _relayed(run, f"Texture {number + 1} of {len(groups)} ('{image.name}' on "
                                                  f"{names}): ", sum(weights[:number]), weights[number],
                                             sum(weights), started)
            runs.append((group, result))
        if parts:
            runs = _merge(parts, runs, settings.epsilon)
            parts = []
    except BaseException:
        for _, result in reversed(runs):
            with contextlib.suppress(ReferenceError):  # a part's objects went with a failed merge
                result.discard()
        raise
    finally:
        remove_parts(parts)
    return runs


def _relayed(run, prefix, before, weight, total, started):
    """Generator: ``run``'s steps as steps of the whole job (``before`` of ``total`` faces done before it,
    ``weight`` its own); returns its result. Closing it closes ``run``."""
    try:
        while True:
            try:
                progress = next(run)
            except StopIteration as finished:
                return finished.value
            fraction = (before + weight * progress.fraction) / total
            elapsed = time.perf_counter() - started
            left = elapsed * (1.0 - fraction) / fraction if fraction >= 0.01 else None
            yield dataclasses.replace(progress, message=prefix + progress.message, fraction=fraction,
                                      seconds_left=left)
    except BaseException:
        run.close()
        raise


def _merge(parts, runs, epsilon):
    """Move the parts' results onto their objects (:func:`.texture_parts.merge_parts`, which removes the parts)
    and return ``runs`` with each part replaced by its object and the other users of its mesh, in the runs'
    objects and their reports."""
    run_of = {obj.name: result for objects, result in runs for obj in objects}
    originals = {part.part.name: _mesh_users(part.original) for part in parts}
    names = {part.part.name: part.original.name for part in parts}
    (source_uv,) = {run_of[part.part.name].report["source_uv_map"] for part in parts}
    merged = []
    for objects, result in runs:
        kept = []
        for obj in objects:
            for replaced in originals.get(obj.name, [obj]):
                if replaced not in kept:
                    kept.append(replaced)
        result.report["objects"] = list(dict.fromkeys(names.get(name, name) for name in result.report["objects"]))
        merged.append((kept, result))
    merge_parts(parts, [run_of[part.part.name].uv_map for part in parts],
                {material for _, result in runs for material in result.materials}, source_uv=source_uv,
                epsilon=epsilon)
    return merged


def _mesh_users(obj):
    """``obj`` and the other objects of the file that use its mesh, ``obj`` first."""
    return [obj] + [other for other in bpy.context.scene.objects if other.data == obj.data and other != obj]


_SUMMED = ("faces", "vertices", "optimized_triangles", "skipped_triangles", "unevaluated_triangles",
           "flipped_triangles", "restored_charts", "stacked_charts")
_SETTINGS = ("epsilon", "target_cost", "cost_measure", "seed", "evaluations_per_triangle")


def combined_report(reports):
    """The report of one ``optimize`` over several textures, from each texture's run report.

    ``textures`` holds the runs' reports as they are (each with its ``resolution``, ``relative_cost``, ``image``,
    ...); the top level has what the file as a whole has: the objects, the counts and times summed, the settings,
    ``triangles_within_bound`` over all optimized triangles, every map (``maps``) with the memory (``memory_ratio``,
    ``image_memory`` {``before``, ``after``} in raw bytes) and file ratios over all of them, ``images`` and
    ``image_files`` per texture, ``uv_map`` when the runs share its name (else None), and the notes and warnings,
    each prefixed with its texture.

    Parameters
    ----------
    reports : sequence of dict
        The runs' reports (:class:`.pipeline.PipelineResult`), in run order.

    Returns
    -------
    dict
    """
    maps = [entry for report in reports for entry in report["maps"]]
    before = sum(entry["raw_bytes_before"] for entry in maps)
    after = sum(entry["raw_bytes_after"] for entry in maps)
    files_before = [entry["file_bytes_before"] for entry in maps]
    files_after = [entry["file_bytes_after"] for entry in maps]
    optimized = sum(report["optimized_triangles"] for report in reports)
    times = {}
    for report in reports:
        for key, value in report["times_s"].items():
            times[key] = round(times.get(key, 0.0) + value, 3)
    overlaps = {}
    for report in reports:
        for key, value in report["overlapping_pairs"].items():
            overlaps[key] = overlaps.get(key, 0) + value
    uv_maps = {report["uv_map"] for report in reports}

    def labelled(key):  # by the texture's input image (the first map's)
        return [f"texture '{report['maps'][0]['image']}': {line}" for report in reports
                for line in report.get(key, [])]

    return {
        "objects": list(dict.fromkeys(name for report in reports for name in report["objects"])),
        **{key: sum(report[key] for report in reports) for key in _SUMMED},
        **{key: reports[0][key] for key in _SETTINGS},
        "times_s": times,
        "overlapping_pairs": overlaps,
        "triangles_within_bound": (sum(report["triangles_within_bound"] * report["optimized_triangles"]
                                       for report in reports) / optimized if optimized else None),
        "uv_map": uv_maps.pop() if len(uv_maps) == 1 else None,
        "images": [report["image"] for report in reports],
        "image_files": [report["image_file"] for report in reports],
        "maps": maps,
        "image_memory": {"before": before, "after": after},
        "memory_ratio": after / before if before else None,
        "file_ratio": (sum(files_after) / sum(files_before) if None not in files_before + files_after
                       and sum(files_before) else None),
        "notes": labelled("notes"),
        "warnings": labelled("warnings"),
        "textures": list(reports),
    }
