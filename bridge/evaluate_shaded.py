# SPDX-License-Identifier: GPL-3.0-or-later
"""Shaded evaluation of a UV map: the whole material under fixed lights, and q_r per map (issue 23 item 6).

The flat evaluation (:mod:`.evaluate`) compares the base colour alone. Here, at each target cost, EVERY map the
materials read through the reference UV map is re-baked onto the candidate UV map (:func:`.bake.bake_maps`, the
pipeline's bake), the objects get the material copies the pipeline makes (:func:`.material_copy.material_copies`:
every baked map read through the candidate UV map), and the same 20 dodecahedron views (:mod:`.evaluate`'s
cameras) of the input's full material and the copies' are compared by mean GMSD (Eq. 22, the same
``core.evaluation.perceptual_loss_of_views``):

- shaded q_r: Cycles on the CPU, :data:`SAMPLES` samples per pixel with a fixed seed (:data:`SEED`, not animated),
  no denoising, no adaptive sampling, few bounces, the 'Standard' view transform; a fixed light rig in world space
  (a key sun, a weaker fill sun from the opposite side and below, both with hard shadows, and a uniform grey world),
  so every face sees some light and a normal map's relief shows in every view. Cycles rather than EEVEE: on
  this project's machine (2 CPU cores, Mesa's software OpenGL) a 512 px view of spot at 16 samples takes about
  2 s with Cycles and 23 s with EEVEE (54 s for the first, which compiles the shaders), and 20 views x several
  costs x several methods are rendered per model. With a fixed seed Cycles gives bit-identical frames: two
  renders of the same material differ by nothing, and the input against its own same-size re-bake differs by
  the bake's rounding, with the sampling pattern shared by both sides (the floor, documented in
  ``tests/test_evaluate_shaded.py`` and docs/results).
- q_r per map: each map rendered as emission through its UV map, as the flat mode shows the base colour: colour
  and data maps by the workbench renderer with stored values (:class:`.render.WorkbenchRenderer`, the flat
  mode's renderer; the base colour's q is the flat mode's q_r); a tangent-space normal map as the world-space
  shading normal its Normal Map node gives (``0.5 n + 0.5`` as emission, Cycles, the 'Raw' view): its stored
  values are in a tangent frame that a new UV map turns, so they cannot be compared texel for texel, while the
  normal they give can. Slots that do not read a map show the same flat grey in both renders.

The objects are never changed: the renders use temporary proxies that share the meshes, and the baked images,
material copies and their node groups are removed afterwards (unless ``keep_images``).
"""
import contextlib
import time
import types

import bpy
import numpy as np
from mathutils import Vector

from ..core.cost import relative_cost, size_for_cost
from ..core.packing import image_sizes
from ..core.evaluation import perceptual_loss_of_views, symmetric_dirichlet
from .bake import bake_maps
from .evaluate import (_dodecahedron_views, _largest_size, _reported_size, _side, _size_label, checked_inputs,
                       image_aspect, mesh_arrays, reference_resolution)
from .map_reads import _reads, bake_kind
from .material import read_object_materials
from .material_copy import _raw_bytes, image_side, map_scale, material_copies, memory_resolution, scaled_size
from .render import WorkbenchRenderer

__all__ = ["SAMPLES", "SEED", "LIGHTS", "WORLD_COLOR", "SIZINGS", "ShadedRenderer", "material_records",
           "shaded_views", "shaded_reference", "map_views", "evaluate_shaded"]

SAMPLES = 16
"""Cycles samples per pixel of a shaded view."""
SEED = 0
"""Cycles' sampling seed (fixed: two renders of one scene are identical)."""
LIGHTS = (((0.45, -0.55, 0.70), 2.5), ((-0.50, 0.60, -0.40), 0.8))
"""The sun lamps: (direction towards the light in world space, strength in W/m^2): a key from above and a fill
from the opposite side and below."""
WORLD_COLOR = (0.15, 0.15, 0.15)
"""The world's uniform background light."""
EMISSION_SAMPLES = 4
"""Cycles samples per pixel of a per-map emission view (no lights: only the pixel filter averages)."""
SIZINGS = ("texels", "memory")
_PLAIN_GREY = (0.5, 0.5, 0.5, 1.0)


class ShadedRenderer(WorkbenchRenderer):
    """A temporary Cycles scene with the fixed light rig: add objects with their materials, render views.

    Parameters
    ----------
    width : int
        Film side in pixels.
    samples : int, optional
        Samples per pixel.
    seed : int, optional
        Sampling seed.
    emission : bool, optional
        No lights and the 'Raw' view: for materials that only emit (the per-map views). Otherwise the light rig
        and the 'Standard' view (display values, as a viewer shows the lit material).

    The cameras, the film, the temporary data's removal and :meth:`render` are those of
    :class:`.render.WorkbenchRenderer`; only the engine, the lights and the proxies differ.
    """

    def __init__(self, *, width, samples=SAMPLES, seed=SEED, emission=False):
        if int(samples) != samples or samples < 1:
            raise ValueError(f"samples must be a positive integer, got {samples!r}")
        self.samples, self.seed, self.emission = int(samples), int(seed), bool(emission)
        self._extra = []  # worlds and lamps: blocks the base class does not know how to remove
        super().__init__(width=width, texture_values="stored" if emission else "srgb")

    def close(self):
        """Remove every temporary data block (lamps and world included)."""
        for block in reversed(getattr(self, "_extra", [])):
            collection = bpy.data.worlds if isinstance(block, bpy.types.World) else bpy.data.lights
            with contextlib.suppress(ReferenceError, KeyError):
                collection.remove(block)
        if hasattr(self, "_extra"):
            self._extra.clear()
        super().close()

    def _configure_scene(self, antialiasing):
        super()._configure_scene(antialiasing)
        scene = self.scene
        scene.render.engine = "CYCLES"
        cycles = scene.cycles
        cycles.device = "CPU"
        cycles.samples = self.samples
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.seed, cycles.use_animated_seed = self.seed, False
        cycles.max_bounces, cycles.diffuse_bounces, cycles.glossy_bounces = 3, 1, 1
        cycles.transmission_bounces, cycles.transparent_max_bounces = 2, 4
        cycles.caustics_reflective = cycles.caustics_refractive = False
        cycles.sample_clamp_indirect = 10.0  # fireflies from rare glossy paths would dominate a view's GMSD
        world = bpy.data.worlds.new("perceptual_uv_world")
        self._extra.append(world)
        if world.node_tree is None:  # Blender 4.x; from 5.0 every world has its node tree
            world.use_nodes = True
        background = world.node_tree.nodes.get("Background")
        background.inputs["Color"].default_value = (*((0.0,) * 3 if self.emission else WORLD_COLOR), 1.0)
        background.inputs["Strength"].default_value = 0.0 if self.emission else 1.0
        scene.world = world
        if self.emission:
            return
        for index, (direction, strength) in enumerate(LIGHTS):
            lamp = bpy.data.lights.new(f"perceptual_uv_sun{index}", type="SUN")
            self._extra.append(lamp)
            lamp.energy, lamp.angle = float(strength), 0.0  # a hard shadow has no penumbra noise
            sun = self._new(bpy.data.objects, f"perceptual_uv_sun{index}", lamp)
            sun.rotation_mode = "QUATERNION"
            sun.rotation_quaternion = Vector(direction).normalized().to_track_quat("Z", "Y")  # shines along -Z
            scene.collection.objects.link(sun)

    def add_material_object(self, obj):
        """Show ``obj``'s mesh (no modifiers) with its world transform and its slots' materials.

        Returns
        -------
        bpy.types.Object
            The temporary proxy: it shares the mesh and has object-linked slots, so its materials can be
            replaced without touching ``obj``.
        """
        if obj is None or obj.type != "MESH":
            raise ValueError(f"'{getattr(obj, 'name', obj)}' is not a mesh object")
        proxy = self._new(bpy.data.objects, "perceptual_uv_shaded", obj.data)
        proxy.matrix_world = obj.matrix_world.copy()
        for slot, own in zip(proxy.material_slots, obj.material_slots):
            slot.link = "OBJECT"
            slot.material = own.material
        self.scene.collection.objects.link(proxy)
        return proxy

    def normal_material(self, image, uv_name):
        """An emission material showing the world-space normal ``image`` gives through a tangent-space Normal Map
        node on ``uv_name``, as ``0.5 n + 0.5``."""
        material = self._new(bpy.data.materials, "perceptual_uv_normal_view")
        if material.node_tree is None:  # Blender 4.x; from 5.0 every material has its node tree
            material.use_nodes = True
        tree = material.node_tree
        tree.nodes.clear()
        uv = tree.nodes.new("ShaderNodeUVMap")
        uv.uv_map = uv_name
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image, texture.interpolation, texture.extension = image, "Linear", "REPEAT"
        normal = tree.nodes.new("ShaderNodeNormalMap")
        normal.space, normal.uv_map = "TANGENT", uv_name
        encode = tree.nodes.new("ShaderNodeVectorMath")
        encode.operation = "MULTIPLY_ADD"
        encode.inputs[1].default_value = encode.inputs[2].default_value = (0.5, 0.5, 0.5)
        emission = tree.nodes.new("ShaderNodeEmission")
        output = tree.nodes.new("ShaderNodeOutputMaterial")
        tree.links.new(uv.outputs["UV"], texture.inputs["Vector"])
        tree.links.new(texture.outputs["Color"], normal.inputs["Color"])
        tree.links.new(normal.outputs["Normal"], encode.inputs[0])
        tree.links.new(encode.outputs["Vector"], emission.inputs["Color"])
        tree.links.new(emission.outputs["Emission"], output.inputs["Surface"])
        return material

    def plain_material(self):
        """An emission material of one flat grey (slots that do not read the map shown)."""
        material = self._new(bpy.data.materials, "perceptual_uv_plain_view")
        if material.node_tree is None:
            material.use_nodes = True
        tree = material.node_tree
        tree.nodes.clear()
        emission = tree.nodes.new("ShaderNodeEmission")
        emission.inputs["Color"].default_value = _PLAIN_GREY
        tree.links.new(emission.outputs["Emission"], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
        return material


def material_records(objects, reference_uv):
    """Every map the objects' materials read through ``reference_uv``, once per (image, bake kind).

    Returns
    -------
    list of perceptual_uv.bridge.material_roles.MaterialMap

    Raises
    ------
    ValueError
        When no material reads an image through ``reference_uv``.
    """
    records = {}
    for obj in objects:
        for reading in read_object_materials(obj, source_uv=reference_uv):
            for record in reading.maps:
                records.setdefault((record.image.as_pointer(), bake_kind(record)), record)
    if records:
        # the base colour first: its side is a point's ``resolution`` and sets the texel cost
        return sorted(records.values(), key=lambda record: record.role != "base_color")
    names = ", ".join(obj.name for obj in objects)
    raise ValueError(f"no material of {names} reads an image through UV map '{reference_uv}': nothing to evaluate")


def _slot_reads(objects, record, reference_uv):
    """Per object, per slot (one False for an object without slots): whether the slot's material reads
    ``record``'s image the way it is baked (:func:`.map_reads._reads`, what the bake itself goes by)."""
    return [_reads(obj, record, reference_uv) for obj in objects]


def shaded_views(objects, cameras, *, screen_pixels, baked=None, uv_name=None, reference_uv=None,
                 samples=SAMPLES):
    """Cycles views of the objects with their whole materials under the fixed lights.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
    cameras : sequence of perceptual_uv.bridge.render.Camera
    screen_pixels : int
    baked : dict, optional
        ``{(image pointer, bake kind): new image}``: the views show the material copies that read these images
        through ``uv_name`` instead of ``reference_uv`` (:func:`.material_copy.material_copies`); by default
        the objects' own materials.
    uv_name, reference_uv : str, optional
        With ``baked``: the candidate and the reference UV maps.
    samples : int, optional

    Returns
    -------
    list of (screen_pixels, screen_pixels, 4) float32 ndarrays
        Display values, row 0 at the bottom.
    """
    created = types.SimpleNamespace(materials=[], node_groups=[], slot_links=[])
    try:
        with ShadedRenderer(width=int(screen_pixels), samples=samples) as renderer:
            proxies = [renderer.add_material_object(obj) for obj in objects]
            if baked:
                material_copies(proxies, baked, uv_name, reference_uv, created)
            return [renderer.render(camera) for camera in cameras]
    finally:
        for block in created.materials:
            with contextlib.suppress(ReferenceError):
                bpy.data.materials.remove(block)
        for block in reversed(created.node_groups):
            with contextlib.suppress(ReferenceError):
                bpy.data.node_groups.remove(block)


def map_views(objects, record, cameras, *, screen_pixels, uv_name, image=None, reads=None):
    """Views of one map as emission through ``uv_name`` (see the module docstring).

    Parameters
    ----------
    objects : sequence of bpy.types.Object
    record : perceptual_uv.bridge.material_roles.MaterialMap
        The map; its own image is shown unless ``image`` is given.
    cameras : sequence of perceptual_uv.bridge.render.Camera
    screen_pixels : int
    uv_name : str
        UV map the image is read through.
    image : bpy.types.Image, optional
        The map re-baked on ``uv_name``.
    reads : list of list of bool
        Per object, per slot: whether the slot reads the map (:func:`_slot_reads`); others show flat grey.

    Returns
    -------
    list of (screen_pixels, screen_pixels, 4) float32 ndarrays
    """
    image = record.image if image is None else image
    if record.kind == "tangent_normal":
        with ShadedRenderer(width=int(screen_pixels), samples=EMISSION_SAMPLES, emission=True) as renderer:
            shown, plain = renderer.normal_material(image, uv_name), renderer.plain_material()
            for obj, slot_reads in zip(objects, reads):
                proxy = renderer.add_material_object(obj)
                for slot, read in zip(proxy.material_slots, slot_reads):
                    slot.material = shown if read else plain
            return [renderer.render(camera) for camera in cameras]
    with WorkbenchRenderer(width=int(screen_pixels), texture_values="stored") as renderer:
        plain = None
        for obj, slot_reads in zip(objects, reads):
            proxy = renderer.add_object(obj, uv_name=uv_name, image=image)  # one textured slot on a mesh copy
            if not all(slot_reads):
                if plain is None:
                    plain = renderer._new(bpy.data.materials, "perceptual_uv_plain")
                    plain.diffuse_color = _PLAIN_GREY
                # one slot per source slot again, and each face's material index from the source mesh (clearing
                # the copy's slots reset them)
                textured = proxy.data.materials[0]
                proxy.data.materials.clear()
                for read in slot_reads:
                    proxy.data.materials.append(textured if read else plain)
                indices = np.empty(len(obj.data.polygons), dtype=np.int32)
                obj.data.polygons.foreach_get("material_index", indices)
                proxy.data.polygons.foreach_set("material_index", indices)
        return [renderer.render(camera) for camera in cameras]


def _reference(objects, records, reads, cameras, reference_uv, *, screen_pixels, samples):
    return dict(shaded=shaded_views(objects, cameras, screen_pixels=screen_pixels, samples=samples),
                maps=[map_views(objects, record, cameras, screen_pixels=screen_pixels, uv_name=reference_uv,
                                reads=slot_reads) for record, slot_reads in zip(records, reads)])


def shaded_reference(objects, reference_uv, *, screen_pixels=512, view_count=None, samples=SAMPLES):
    """The input's views for :func:`evaluate_shaded` (its ``reference``), to render once for several UV maps.

    Returns
    -------
    dict
        ``shaded``: the views of the whole materials; ``maps``: per map of :func:`material_records`, its views.
    """
    objects = list(objects)
    records = material_records(objects, reference_uv)
    V, _, _ = mesh_arrays(objects, reference_uv)
    cameras = _dodecahedron_views(V)[:view_count]
    reads = [_slot_reads(objects, record, reference_uv) for record in records]
    return _reference(objects, records, reads, cameras, reference_uv, screen_pixels=int(screen_pixels),
                      samples=samples)


def _sizes(records, sizing, target, size, r_input, aspect):
    """Each map's new ``(width, height)``: the base colour's texel-cost ``size`` scaled by the map's own size
    (``texels``), or ``cost`` times the pixels of its own size (``memory``): in the shape ``aspect``, or without
    one each map's sides scaled by ``sqrt(cost)`` (a uniform downscale of every map)."""
    if sizing == "memory":
        if aspect is None:
            return [scaled_size(tuple(record.image.size), np.sqrt(target)) for record in records]
        return [image_sizes(memory_resolution(tuple(record.image.size), target), (aspect,))[0] for record in records]
    reference_side = np.sqrt(float(r_input[0]) * float(r_input[1]))
    return [scaled_size(size, map_scale(image_side(record.image), reference_side)) for record in records]


def evaluate_shaded(objects, uv_name, *, reference_uv, costs=(0.1, 0.2, 0.3, 0.5), screen_pixels=512,
                    sizing="texels", margin=None, reference=None, view_count=None, samples=SAMPLES,
                    keep_images=False, keep_views=False, aspect=None):
    """Shaded q_r and q_r per map of UV map ``uv_name`` at each target cost.

    Parameters
    ----------
    objects : sequence of bpy.types.Object
        Mesh objects; not modified.
    uv_name : str
        The candidate UV map.
    reference_uv : str
        The input UV map, through which the materials read their images.
    costs : sequence of float, optional
        Target costs (> 0).
    screen_pixels : int, optional
        Side of each view.
    sizing : {"texels", "memory"}, optional
        ``texels``: the base colour's side is the one whose relative texel cost (Eq. 20-21) is closest to the
        target, as in the flat mode, and every other map keeps its size relative to the base colour's input;
        ``memory``: every map gets ``cost`` times the pixels of its own input, in the shape ``aspect`` or, with
        none given, its own sides times ``sqrt(cost)`` (on the input UV map: a uniform downscale, what
        ``gltfpack -ts`` and ``gltf-transform resize`` do).
    margin : int, optional
        Bake margin in pixels of every map; by default ``max(2, side // 128)`` per map.
    reference : dict, optional
        The reference views from an earlier call (its ``reference`` when ``keep_views``), reused.
    view_count : int, optional
        Use only the first views of the 20 (fast tests).
    samples : int, optional
        Cycles samples per pixel of the shaded views.
    keep_images, keep_views : bool, optional
        Keep the baked images (``images``, a list per cost) / return the renders (``reference``, and ``rendered``
        in each point).
    aspect : float, optional
        Width over height of the image ``uv_name`` was packed for: every map's image at each cost has that
        shape (:func:`.evaluate.evaluate_uv_map`). By default :func:`.evaluate.image_aspect`'s for the texel
        sizing (the input texture's shape for the input UV map, a square for another), each map's own shape for
        the memory sizing.

    Returns
    -------
    dict
        ``mode`` "shaded", ``uv_map``, ``reference_uv``, ``screen_pixels``, ``views``, ``samples``, ``sizing``,
        ``reference_resolution``, ``e_iso`` (Eq. 24, as the flat mode), ``maps`` (role, image, kind, input size
        per map), ``aspect``, ``points``: per cost ``target_cost``, ``resolution`` (the base colour's side, or
        the first map's; ``[width, height]`` for an image that is not square), ``relative_cost`` (its realised
        texel cost, Eq. 21), ``memory_ratio`` (the maps' raw bytes after over before), ``q`` (shaded, Eq. 22),
        ``q_views``, ``maps`` (per map ``role``, ``image``, ``resolution``, ``q``), ``time_s``.

    Raises
    ------
    ValueError
        Empty objects, missing UV maps, no image read through ``reference_uv``, bad costs, screen size, sizing or
        view count.
    """
    objects, costs = checked_inputs(objects, costs, screen_pixels, (uv_name, reference_uv))
    if sizing not in SIZINGS:
        raise ValueError(f"sizing must be one of {SIZINGS}, got {sizing!r}")
    records = material_records(objects, reference_uv)
    try:
        r_input = reference_resolution(objects)
    except ValueError:  # no base-colour image: the largest map sets the texel cost's reference
        r_input = _largest_size([(int(record.image.size[0]), int(record.image.size[1])) for record in records])
    given_aspect, aspect = aspect, image_aspect(aspect, uv_name, reference_uv, r_input)
    V, F, uv = mesh_arrays(objects, uv_name)
    _, _, uv_ref = mesh_arrays(objects, reference_uv)
    cameras = _dodecahedron_views(V)
    if view_count is not None:
        if not 1 <= int(view_count) <= len(cameras):
            raise ValueError(f"view_count must be in [1, {len(cameras)}], got {view_count}")
        cameras = cameras[:int(view_count)]
    reads = [_slot_reads(objects, record, reference_uv) for record in records]
    common = dict(screen_pixels=int(screen_pixels))
    if reference is None:
        reference = _reference(objects, records, reads, cameras, reference_uv, samples=samples, **common)
    elif len(reference["shaded"]) != len(cameras) or len(reference["maps"]) != len(records):
        raise ValueError(f"the reference has {len(reference['shaded'])} views of {len(reference['maps'])} maps, "
                         f"not {len(cameras)} of {len(records)}")
    points, images = [], []
    for target in costs:
        start = time.perf_counter()
        size = size_for_cost(uv, target, reference_uv=uv_ref, reference_resolution=r_input, aspect=aspect)
        sizes = _sizes(records, sizing, target, size, r_input, given_aspect)
        c = float(relative_cost(uv, sizes[0] if sizing == "memory" else size, reference_uv=uv_ref,
                                reference_resolution=r_input))
        results = bake_maps(objects, records, source_uv=reference_uv, target_uv=uv_name, resolutions=sizes,
                            margin=[max(2, _side(*s) // 128) if margin is None else int(margin) for s in sizes],
                            names=[f"PUV_eval_{uv_name}_{record.role}_{_size_label(*s)}"
                                   for record, s in zip(records, sizes)])
        try:
            baked = {(result.record.image.as_pointer(), result.kind): result.image for result in results}
            views = shaded_views(objects, cameras, baked=baked, uv_name=uv_name, reference_uv=reference_uv,
                                 samples=samples, **common)
            q, per_view = perceptual_loss_of_views(reference["shaded"], views, full=True)
            per_map = []
            for index, (record, result) in enumerate(zip(records, results)):
                rendered = map_views(objects, record, cameras, uv_name=uv_name, image=result.image,
                                     reads=reads[index], **common)
                per_map.append(dict(role=record.role, image=record.image.name, resolution=_reported_size(*sizes[index]),
                                    q=float(perceptual_loss_of_views(reference["maps"][index], rendered))))
            # the report's raw bytes (material_copy.map_report): alpha counted when the bake kept it
            before = sum(_raw_bytes(*result.record.image.size, result.alpha, result.record.image.is_float)
                         for result in results)
            after = sum(_raw_bytes(*result.image.size, result.alpha, result.image.is_float) for result in results)
        finally:
            if keep_images:
                images.append([result.image for result in results])
            else:
                for result in results:
                    bpy.data.images.remove(result.image)
        points.append(dict(target_cost=target, resolution=_reported_size(*sizes[0]), relative_cost=c,
                           memory_ratio=after / before if before else None, q=float(q),
                           q_views=[float(x) for x in per_view], maps=per_map,
                           time_s=time.perf_counter() - start))
        if keep_views:
            points[-1]["rendered"] = views
    result = dict(mode="shaded", uv_map=uv_name, reference_uv=reference_uv, screen_pixels=int(screen_pixels),
                  views=len(cameras), samples=int(samples), sizing=sizing,
                  reference_resolution=_reported_size(*r_input), aspect=aspect,
                  e_iso=float(symmetric_dirichlet(V, F, uv)),
                  maps=[dict(role=record.role, image=record.image.name, kind=record.kind,
                             input_size=[int(record.image.size[0]), int(record.image.size[1])])
                        for record in records], points=points)
    if keep_images:
        result["images"] = images
    if keep_views:
        result["reference"] = reference
    return result
