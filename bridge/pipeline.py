# SPDX-License-Identifier: GPL-3.0-or-later
"""The whole method on Blender objects, as a generator that yields progress.

``optimize_objects(objects, settings)`` is driven one slice at a time by the modal operator (one ``next`` per
timer tick), run to the end by ``execute`` and by the batch CLI, and closed (``.close()``) to cancel: whatever
it created so far (UV map, images, material copies and their node groups, face attribute) is removed again, so a
cancelled or failed run leaves the file exactly as it was (and deletes the new images' files if they were saved
already). The original UV map, images, materials and mesh are never modified.

Every map of the material moves and the loss sees every map (:mod:`.material_copy`).
"""
import contextlib
import dataclasses
import os
import time

import bpy
import numpy as np

from ..core import cost as texel_cost
from ..core.progress import InThread, RunProgress, format_seconds, relay_stage, report_while_waiting
from .image_file import image_size, iter_save_or_pack
from .loss_overlay import write_loss_attributes
from .material_copy import (COPY_PROPERTY, MIN_RESOLUTION, file_bytes, image_side, image_stem, iter_loss_planes_of,
                            map_report, map_scale, material_copies, memory_resolution, read_maps,
                            resolve_source_uv, scaled_size, uv_maps_reading)
from .read_objects import (READ_STEPS, iter_import_stages, iter_read_objects, one_object_per_mesh, source_image,
                           target_problem)

__all__ = ["Progress", "STAGE_SHARES", "PipelineResult", "optimize_objects", "check_objects", "run_to_end",
           "COPY_PROPERTY"]


@dataclasses.dataclass(frozen=True)
class Progress:
    """One step of a run: ``stage`` name, ``done`` of ``total`` units of it, and a line for the status bar.

    ``fraction`` is the whole run's fraction done and ``seconds_left`` its estimated time left (None until a
    hundredth of the run is done by this run), from :data:`STAGE_SHARES` (``core.progress.RunProgress``).
    """

    stage: str
    done: int
    total: int
    message: str
    fraction: float = 0.0
    seconds_left: float | None = None

    def line(self):
        """``message`` followed by the whole run's progress: "...: 120/5856 · 12 % of the run, 4 min 05 s left"."""
        left = f", {format_seconds(self.seconds_left)} left" if self.seconds_left is not None else ""
        return f"{self.message} · {self.fraction:.0%} of the run{left}"


# Expected share of a run's time per stage, in the order they run: the mean shares over the tuning set (spot,
# CesiumMan, WaterBottle, Avocado, tea_set_01, wooden_bookshelf_worn) at the default settings on 2 workers
# (bench/pipeline.py at 910fb37; README "How long it takes").
STAGE_SHARES = {"read": 0.01, "triangle": 0.831, "mesh": 0.115, "pack": 0.006, "bake": 0.038, "loss": 0.0, "done": 0.0}


@dataclasses.dataclass
class PipelineResult:
    """What a finished run made and measured; ``report`` is the JSON report of DESIGN's contract."""

    uv_map: str
    image: "bpy.types.Image"
    materials: list
    report: dict
    images: list = dataclasses.field(default_factory=list)  # every new image, the base colour's first
    discard: object = None  # discard(): remove everything the run added (a later run of the same job failed)


def _unique_uv_name(objects, wanted):
    name, counter = wanted, 1
    while any(name in obj.data.uv_layers for obj in objects):
        name, counter = f"{wanted}.{counter:03d}", counter + 1
    return name


MAX_UV_MAPS = 8  # Blender's limit per mesh
LOW_COVERAGE = 0.25  # below it the image holds more than 4 times the texels the cost counts
SHARED_TEXELS = 1.1  # above it the input's islands share a tenth of their texels or more (tiled, laid on each other)



class _Created:
    """Everything a run adds to the file, so that a cancel or an error can take it away again."""

    def __init__(self):
        self.uv_layers = []      # (mesh, name)
        self.attributes = []     # (mesh, name)
        self.images = []
        self.materials = []
        self.node_groups = []    # groups of the material copies that hold re-pointed nodes
        self.slot_links = []     # (object, slot index, previous material, previous link)
        self.files = []          # image files written to disk

    def remove_all(self):
        for obj, index, material, link in reversed(self.slot_links):
            slot = obj.material_slots[index]
            slot.material = None
            slot.link = link
            slot.material = material
        for mesh, name in self.uv_layers:
            if name in mesh.uv_layers:
                mesh.uv_layers.remove(mesh.uv_layers[name])
        for mesh, name in self.attributes:
            if name in mesh.attributes:
                mesh.attributes.remove(mesh.attributes[name])
        for block in self.materials:
            bpy.data.materials.remove(block)
        for block in reversed(self.node_groups):
            with contextlib.suppress(ReferenceError):
                bpy.data.node_groups.remove(block)
        for block in self.images:
            bpy.data.images.remove(block)
        for path in self.files:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)




def check_objects(objects, source_uv=None):
    """The refusals of :func:`optimize_objects` that come before it reads anything (ValueError with the reason),
    also for a caller that starts several runs and must refuse before the first.

    Returns
    -------
    objects : list of bpy.types.Object
        One object per mesh (:func:`.read_objects.one_object_per_mesh`).
    notes : list of str
        On the objects that share a mesh, and on the UV map chosen.
    source_uv : str
        The input UV map's name: ``source_uv`` when given, else :func:`resolve_source_uv`'s, or the one UV map
        the texture is read through when that is another.
    """
    objects = list(objects)
    if not objects:
        raise ValueError("no objects to optimize")
    for obj in objects:
        problem = target_problem(obj)
        if problem:
            raise ValueError(problem)
    objects, shared_notes = one_object_per_mesh(objects)
    given = source_uv
    source_uv = resolve_source_uv(objects, source_uv)
    if given is None:  # none named: the UV map the texture is read through, when that is one other map
        image = source_image(objects)
        read = uv_maps_reading(objects, image)
        if len(read) == 1 and source_uv not in read and all(next(iter(read)) in obj.data.uv_layers
                                                             for obj in objects):
            (other,) = read
            shared_notes.append(f"the texture '{image.name}' is read through UV map '{other}', not the active "
                                f"'{source_uv}': '{other}' is the one optimized")
            source_uv = other
    for obj in objects:
        if source_uv not in obj.data.uv_layers:
            names = ", ".join(f"'{layer.name}'" for layer in obj.data.uv_layers)
            raise ValueError(f"mesh '{obj.data.name}' has no UV map '{source_uv}' (its UV maps: {names}); the "
                             "objects optimized together need one UV map of the same name: rename it, or optimize "
                             "the objects separately (--object, or select them one at a time)")
        if len(obj.data.uv_layers) >= MAX_UV_MAPS:
            raise ValueError(f"mesh '{obj.data.name}' already has {len(obj.data.uv_layers)} UV maps, the most "
                             f"Blender allows; remove one it does not need (Object Data > UV Maps) first")
    return objects, shared_notes, source_uv


def optimize_objects(objects, settings, *, source_uv=None, output_dir=None):
    """Optimize the UV map of ``objects`` (sharing one base-colour image) and bake every map onto it.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects whose base colour comes from the same image (one object, or several sharing an atlas).
    settings : perceptual_uv.core.settings.OptimizeSettings
    source_uv : str, optional
        Name of the input UV map; default the active UV map of the first object, or, when the slots hold the
        material copies of an earlier run, the UV map those copies read (optimizing what the material shows; an
        explicit other map is refused with the map to use).
    output_dir : str, optional
        Folder for the new images; default next to the .blend, or packed when the file is unsaved.

    Yields
    ------
    Progress

    Returns
    -------
    PipelineResult
        Through ``StopIteration.value``; :func:`run_to_end` returns it directly. ``image`` is the base colour's
        new image, ``images`` every new image (one per map the materials read through ``source_uv``: base
        colour, normal, packed data, emissive, ...), ``report["maps"]`` per map its role, input and new size, raw
        and file bytes before and after, ``report["memory_ratio"]`` the maps' raw bytes after over before (the
        cost a user sets with ``settings.cost_measure`` "memory", within rounding), ``report["relative_cost"]``
        the base colour's relative texel cost (Eq. 21; the cost set with "texels"), ``report["cost_measure"]``
        which of the two ``target_cost`` set (None with an explicit resolution).

    Raises
    ------
    ValueError
        Before anything is changed, with the reason: among others a map that cannot be re-baked (UDIM tiles, a
        movie or sequence, no pixels, coordinates through a texture transform).

    References
    ----------
    Sun et al. 2022: Sec. 4.1 (triangle-wise), Sec. 4.2 and App. B (mesh-wise), Sec. 5.1 (packing with
    translations and 90-degree rotations, resolution from the target cost, Eq. 20-21, or from image memory).
    """
    from .mesh_io import write_uv_layer

    objects, shared_notes, source_uv = check_objects(objects, source_uv)

    started = time.perf_counter()
    times = {}
    created = _Created()
    run = RunProgress(STAGE_SHARES)

    def step(stage, done, total, message):
        fraction, seconds_left = run.update(stage, done, total)
        return Progress(stage, done, total, message, fraction, seconds_left)

    try:
        yield from iter_import_stages(step)
        from ..core.charts import uv_topology
        from ..core.result_cache import result_key
        from ..core.stacks import packing_islands, stacked_charts, stacked_faces
        from ..core.textured import above_bound
        from .bake import iter_bake_maps
        from .meshwise_stage import iter_meshwise_stage, meshwise_key
        from .trianglewise_stage import iter_trianglewise_stage

        started = time.perf_counter()  # the run's times leave out loading the modules
        yield step("read", 0, READ_STEPS, "Reading the mesh")
        image, validated, notes = yield from iter_read_objects(objects, source_uv, settings, step)
        yield step("read", 4, READ_STEPS, "Reading the material's maps")
        records, map_notes = read_maps(objects, source_uv, image)  # refused here, before the run
        notes += map_notes
        mesh, texture, faces = validated.mesh, validated.texture, validated.faces
        V, F, uv_in = mesh.V, mesh.F, mesh.uv
        yield step("read", 4, READ_STEPS, "Finding the UV islands")
        topology = uv_topology(F, uv_in)
        _check_islands_fit(uv_in, topology.face_chart, records[0], settings)  # refused here, before the run
        # Every map the loss sees, the loss image's first.
        planes = yield from relay_stage(iter_loss_planes_of(records, texture), "read", "Building the loss's planes",
                                        time.perf_counter(), step)
        height, width = texture.shape[:2]
        m = len(F)
        reuse = texel_cost.texel_reuse(uv_in, (height, width))
        per_object = [mesh.object_index == index for index in range(len(objects))]

        yield step("read", 5, READ_STEPS, "Looking for the results of an earlier run")
        clock = time.perf_counter()

        def keys():  # hashing the maps takes a few tenths of a second at 2048 px; hashlib lets other threads run
            triangle_key = result_key(V, F, uv_in, *planes, faces, epsilon=settings.epsilon,
                                      evaluations=settings.iterations, screen_pixels=settings.screen_pixels,
                                      max_screen_pixels=settings.max_screen_pixels, seed=settings.seed)
            return triangle_key, meshwise_key(triangle_key, texture, keep_stacks=settings.keep_stacks)

        hashing = InThread(keys)
        for _ in hashing.wait():
            yield step("read", 5, READ_STEPS, "Looking for the results of an earlier run")
        key, mesh_key = hashing.join()
        triangles, triangle_notes = yield from iter_trianglewise_stage(V, F, uv_in, planes, faces, key, settings, run,
                                                                       step, clock)
        notes += triangle_notes
        times["triangle"] = time.perf_counter() - clock
        unevaluated = int(np.count_nonzero(triangles.unevaluated))
        if unevaluated:
            notes.append(f"the loss of {unevaluated} triangle(s) could not be evaluated (NaN or infinite); they keep "
                         "their input shape and size")

        clock = time.perf_counter()
        finding = step("mesh", 0, 1, "Finding the UV islands that share texels")
        yield finding
        input_charts = topology.face_chart
        stacks = None
        if settings.keep_stacks:  # in a thread: about 0.2 s on sofa_03's 166 islands
            stacks = yield from report_while_waiting(InThread(stacked_charts, uv_in, input_charts).wait(), finding)
        meshwise, meshwise_notes = yield from iter_meshwise_stage(validated, planes, triangles, topology, stacks,
                                                                  mesh_key, settings, run, step, clock)
        notes += meshwise_notes
        uv_fit, restored, losses, textured = meshwise.uv, meshwise.restored, meshwise.losses, meshwise.textured
        if restored.size:
            notes.append(f"{restored.size} UV island(s) folded over themselves in the mesh-wise fit (it is locally "
                         "injective only) and keep their input layout, scaled to their new size")
        stacked = 0 if stacks is None else int(np.count_nonzero(np.bincount(stacks)[stacks] > 1))
        if stacked:
            notes.append(f"{stacked} UV islands share texels in the input ({len(np.unique(stacks))} stacks and single "
                         "islands in all) and stay stacked: each stack keeps its input layout, scaled to the size the "
                         "fit gives its islands together, and packs as one island (--unstack, or Keep Stacked "
                         "Islands off, gives every island texels of its own)")
        times["mesh"] = time.perf_counter() - clock

        yield step("pack", 0, 1, "Packing islands")
        clock = time.perf_counter()
        # With the cost in image memory every map's side follows from its own input size; the charts fill the
        # first map's (the loss image's). With the texel cost (Eq. 20-21) the packing sets the side.
        by_memory = settings.resolution is None and settings.cost_measure == "memory"
        sides_by_memory = [_memory_side(record, settings) for record in records] if by_memory else None
        islands = input_charts if stacks is None else packing_islands(input_charts,
                                                                      stacked_faces(input_charts, stacks))
        packing = yield from _pack(mesh.uv, uv_fit, islands, (width, height), settings,
                                   step, resolution=sides_by_memory[0] if by_memory else None)
        # What the UV map stores (float32), so the report's figures are those of the saved map.
        uv_out = packing.uv.astype(np.float32).astype(np.float64)
        size = packing.size
        reuse_out = texel_cost.texel_reuse(uv_out, size)
        # The islands' UV area; stacked islands cover their texels once, so with stacks the texels they cover.
        coverage = texel_cost.uv_area(uv_out) / (reuse_out if stacked else 1.0)
        uv_name = _unique_uv_name(objects, settings.uv_map_name)
        for obj, rows in zip(objects, per_object):
            write_uv_layer(obj, uv_name, uv_out[rows], mesh.tri_loops[rows])
            created.uv_layers.append((obj.data, uv_name))
        if reuse > SHARED_TEXELS * reuse_out:
            notes.append(f"the input's UV islands use each texel they cover {reuse:.1f} times on average (tiled UVs or "
                         f"islands laid on the same texels), the new UV map's {reuse_out:.1f} times: it needs about "
                         f"{reuse / reuse_out:.1f} times the input's image memory for the input's texel density, and "
                         "at a lower cost, downscaling the input's images may keep more detail")
        if coverage < LOW_COVERAGE:
            notes.append(f"the packed UV islands cover {coverage:.0%} of the {size[0]} x {size[1]} image: it "
                         f"holds {1 / coverage:.0f} times the texels the islands use. An island far longer than it "
                         "is wide sets the packing scale; a seam across it lets the islands pack tighter")
        times["pack"] = time.perf_counter() - clock

        clock = time.perf_counter()
        reference_cost = texel_cost.relative_cost(uv_out, size, reference_uv=uv_in,
                                                  reference_resolution=(width, height))
        if by_memory and reference_cost > 1:
            notes.append(f"the new {size[0]} x {size[1]} image has {reference_cost:.2f} times the input's "
                         "texels per surface area (relative texel cost, Eq. 21): the input's islands take "
                         f"{texel_cost.uv_area(uv_in):.0%} of its image. A cost of about "
                         f"{settings.target_cost / reference_cost:.2g} keeps the input's texel density")
        sizes, margins, names = _new_images(records, image, size, reference_cost, settings, sides_by_memory)
        # In the background process (the modal operator) the generator yields every 0.1 s while Cycles bakes;
        # in this process each map's bake is one step.
        where = " in a background process" if settings.bake_in_background else ""
        stage = iter_bake_maps(objects, records, source_uv=source_uv, target_uv=uv_name, resolutions=sizes,
                               margin=margins, names=names, in_background=settings.bake_in_background)

        def bake_message(done, total):
            if done < total:
                return (f"Baking the {records[done].role.replace('_', ' ')} map ({done + 1}/{total}){where}: "
                        f"{sizes[done][0]} x {sizes[done][1]}")
            return "Making the new images"

        with contextlib.closing(stage):  # a cancel stops the background process at once
            bakes = yield from relay_stage(stage, "bake", None, clock, step, message=bake_message)
        created.images.extend(result.image for result in bakes)
        baked = {(result.record.image.as_pointer(), result.kind): result.image for result in bakes}
        new_image = bakes[0].image
        times["bake"] = time.perf_counter() - clock

        yield step("loss", 0, 1, "Writing the loss per triangle")
        for obj, rows in zip(objects, per_object):
            write_loss_attributes(obj, mesh.tri_polygons[rows], losses[rows], settings.epsilon, created.attributes)

        yield step("loss", 0, 1, "Making the material copies")
        materials = (material_copies(objects, baked, uv_name, source_uv, created) if settings.use_material_copy
                     else [])
        maps_report, warnings = yield from _iter_save_images(bakes, output_dir, created, step)
        saved = maps_report[0]["new_image_file"]
        before = sum(entry["raw_bytes_before"] for entry in maps_report)
        after = sum(entry["raw_bytes_after"] for entry in maps_report)
        files_before = [entry["file_bytes_before"] for entry in maps_report]
        files_after = [entry["file_bytes_after"] for entry in maps_report]
        times["total"] = time.perf_counter() - started

        report = {
            "objects": [obj.name for obj in objects],
            "faces": int(m),
            "vertices": int(len(V)),
            "epsilon": settings.epsilon,
            "target_cost": settings.target_cost if settings.resolution is None else None,
            "cost_measure": settings.cost_measure if settings.resolution is None else None,
            "resolution": [int(side) for side in size],
            "input_resolution": [int(width), int(height)],
            "relative_cost": reference_cost,
            "image_coverage": float(coverage),
            "input_texel_reuse": float(reuse),
            "texel_reuse": float(reuse_out),
            "times_s": {key: round(value, 3) for key, value in times.items()},
            "flipped_triangles": int(meshwise.flipped),
            "overlapping_pairs": _overlap_report(uv_out, input_charts),
            "restored_charts": int(restored.size),
            "stacked_charts": stacked,
            "triangles_within_bound": float(np.mean(losses[faces] <= settings.epsilon)),
            "textured_above_bound": above_bound(uv_in[faces], planes, settings.epsilon, textured=textured.any(axis=0),
                                                targets=meshwise.target_losses, fit=losses[faces]),
            "unevaluated_triangles": unevaluated,
            "optimized_triangles": int(len(faces)),
            "skipped_triangles": int(m - len(faces)),
            "uv_map": uv_name,
            "source_uv_map": source_uv,
            "image": new_image.name,
            "image_file": saved,
            "materials": [material.name for material in materials],
            "maps": maps_report,
            "memory_ratio": after / before if before else None,
            "file_ratio": (sum(files_after) / sum(files_before) if None not in files_before + files_after
                           and sum(files_before) else None),
            "seed": settings.seed,
            "evaluations_per_triangle": settings.iterations,
            "notes": shared_notes + notes,
            "warnings": warnings,
        }
        yield step("done", 1, 1, "Done")
        return PipelineResult(uv_map=uv_name, image=new_image, materials=materials, report=report,
                              images=[result.image for result in bakes], discard=created.remove_all)
    except BaseException:
        created.remove_all()
        raise


def _overlap_report(uv, face_chart):
    """Triangle pairs whose packed UV images overlap, within and between charts (core.overlap)."""
    from ..core.overlap import count_overlaps

    overlaps = count_overlaps(uv, face_chart)
    return {"total": int(overlaps.total), "within_charts": int(overlaps.within_charts),
            "between_charts": int(overlaps.between_charts)}


def _new_images(records, image, size, reference_cost, settings, sides_by_memory=None):
    """Size ``(width, height)``, margin (pixels) and name of each map's new image, in the order of ``records``.

    The first map (the loss image ``image``) gets the packing's ``size``; every other map the same shape, scaled
    by its side over the first map's: ``sides_by_memory`` (one per map) when the cost is image memory, else the
    same relative cost, each relative to its own input size (:func:`.material_copy.map_scale`), a role's cost
    (``settings.role_costs``) overriding the run's. Margins scale with the width; names follow
    ``settings.image_name`` or the input image's.
    """
    from ..core.settings import role_cost

    sizes, margins, names = [], [], []
    for number, record in enumerate(records):
        override = role_cost(settings.role_costs, record.role)
        if sides_by_memory is not None:
            scale = sides_by_memory[number] / sides_by_memory[0]
        elif number == 0 and override is None:
            scale = 1.0
        else:
            scale = map_scale(image_side(record.image), image_side(image), role_cost=override,
                              reference_cost=reference_cost)
        map_size = scaled_size(size, scale)
        sizes.append(map_size)
        margins.append(0 if settings.margin == 0 else max(1, round(settings.margin * map_size[0] / size[0])))
        if number == 0:
            names.append(settings.image_name or f"{image_stem(image)}_perceptual")
        elif settings.image_name:
            names.append(f"{settings.image_name}_{record.role}")
        else:
            names.append(f"{image_stem(record.image)}_perceptual")
    return sizes, margins, names


def _iter_save_images(bakes, output_dir, created, step):
    """Generator: save (or pack) each baked image, yielding ``step``'s "loss" steps while it writes; returns the
    report's entry per map (:func:`.material_copy.map_report`, with the file and its bytes) and the warnings.
    Each saved file goes into ``created.files``, so that a cancelled run deletes it."""
    warnings, entries = [], []
    for number, result in enumerate(bakes):
        saving = step("loss", number, len(bakes), f"Saving the {result.record.role.replace('_', ' ')} map "
                      f"({number + 1}/{len(bakes)})")
        yield saving
        # The report's sizes are read before the save: afterwards the image is the PNG's, read again on use.
        entry = map_report(result, None)
        path, warning = yield from report_while_waiting(iter_save_or_pack(result.image, output_dir), saving)
        entry.update(new_image_file=path, file_bytes_after=file_bytes(result.image))
        if path:
            created.files.append(path)
        if warning:
            warnings.append(warning)
        entries.append(entry)
    return entries, warnings


def _memory_side(record, settings):
    """The side of a map's new image when ``target_cost`` is image memory: its role's cost or the run's."""
    from ..core.settings import role_cost

    override = role_cost(settings.role_costs, record.role)
    return memory_resolution(image_size(record.image), settings.target_cost if override is None else override)


def _memory_aspects(side, settings):
    """The shapes the new image may take with the side the image memory gives: those of
    :data:`.core.packing.IMAGE_ASPECTS` (a square alone with ``settings.square_images``) whose image at ``side``
    has at least ``MIN_RESOLUTION`` pixels on each side; the square always (``side`` is at least that)."""
    from ..core.packing import IMAGE_ASPECTS, image_sizes

    aspects = (1.0,) if settings.square_images else IMAGE_ASPECTS
    return tuple(aspect for aspect, size in zip(aspects, image_sizes(side, aspects))
                 if aspect == 1.0 or min(size) >= MIN_RESOLUTION)


def _check_islands_fit(uv_in, face_chart, record, settings):
    """Refuse (ValueError), before the run, a run whose islands fit no image the packing may take at any scale:
    more of them than :func:`core.packing.island_capacity` allows in each size :func:`_pack` tries with the side
    set by the image memory or the explicit resolution (the texel cost grows the image as the packing needs)."""
    from ..core.packing import image_sizes, island_capacity
    from ..core.stacks import packing_islands, stacked_charts, stacked_faces

    if settings.resolution is not None:
        sizes = [(settings.resolution, settings.resolution)]
    elif settings.cost_measure == "memory":
        side = _memory_side(record, settings)
        sizes = image_sizes(side, _memory_aspects(side, settings))
    else:
        return
    width, height = max(sizes, key=lambda size: island_capacity(*size, settings.margin))
    capacity = island_capacity(width, height, settings.margin)
    count = int(face_chart.max()) + 1
    if count > capacity and settings.keep_stacks:  # the islands that share texels pack as one
        count = int(packing_islands(face_chart, stacked_faces(face_chart, stacked_charts(uv_in, face_chart))).max()) + 1
    if count > capacity:
        raise ValueError(f"the {count} UV islands do not fit a {width} x {height} px image with a {settings.margin} "
                         f"px margin at any scale (it holds {capacity}): lower the margin or give the image more "
                         "pixels (a higher cost or resolution)")


def _pack(uv_in, uv_fit, face_chart, input_size, settings, step, *, resolution=None):
    """Generator: pack the fitted charts on the new image's pixel grid (``core.packing``), yielding ``step``'s
    "pack" step after each try; returns the packing. The image size follows.

    With a target texel cost the charts keep the texel density that meets it (Eq. 20-21: ``d^2`` texels per unit
    of fitted UV area), and the image is as small as their packing; with the side the image memory gives
    (``resolution``) they fill that many pixels as densely as they can. Either way the image takes the shape of
    :data:`.core.packing.IMAGE_ASPECTS` that does it best, unless ``settings.square_images``. An explicit
    ``settings.resolution`` is filled as the square it names.
    """
    from ..core.packing import IMAGE_ASPECTS, iter_pack_charts

    def packed(aspects, **size):
        stage = iter_pack_charts(uv_fit, face_chart, margin=settings.margin, aspects=aspects, **size)
        while True:
            try:
                next(stage)
            except StopIteration as finished:
                return finished.value
            yield step("pack", 0, 1, "Packing islands")

    square = (1.0,)
    if settings.resolution is not None:
        return (yield from packed(square, resolution=settings.resolution))
    if resolution is not None:
        return (yield from packed(_memory_aspects(resolution, settings), resolution=resolution))
    aspects = square if settings.square_images else IMAGE_ASPECTS
    reference = texel_cost.texel_cost(uv_in, input_size)
    density = np.sqrt(settings.target_cost * reference / texel_cost.uv_area(uv_fit))
    packing = yield from packed(aspects, texels_per_unit=density)
    if min(packing.size) < MIN_RESOLUTION:
        packing = yield from packed(square, texels_per_unit=density)
    if min(packing.size) < MIN_RESOLUTION:
        packing = yield from packed(square, resolution=MIN_RESOLUTION)
    return packing


def run_to_end(generator):
    """Drive a pipeline generator to completion and return its result."""
    from ..core.progress import run_generator

    return run_generator(generator)
