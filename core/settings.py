"""The options of one optimization run, shared by the operator, the sidebar, the CLI and the pipeline."""
import dataclasses

__all__ = ["OptimizeSettings", "COST_ROLES", "COST_MEASURES", "MODEL_SUFFIXES", "suffix_listing", "role_cost"]

# The model files a run reads (``bridge.mesh_io.import_model``), lower case: here, where the command line and the
# batch orchestrator can check an input without importing ``bridge``.
MODEL_SUFFIXES = (".blend", ".glb", ".gltf", ".obj", ".fbx", ".usd", ".usda", ".usdc", ".usdz")


def suffix_listing(suffixes):
    """``(".a", ".b", ".c")`` as a message lists them: ``".a, .b or .c"``."""
    return suffixes[0] if len(suffixes) == 1 else ", ".join(suffixes[:-1]) + " or " + suffixes[-1]

# The map roles of ``bridge.material_roles.ROLES`` (kept equal by a test; core does not import bridge), and
# "normal" for the three normal-map roles at once.
COST_ROLES = ("base_color", "alpha", "normal_tangent", "normal_object", "normal_world", "emissive",
              "metallic_roughness", "occlusion", "data", "normal")

# What ``target_cost`` measures: the material's image memory relative to the input's, or the paper's texel cost.
COST_MEASURES = ("memory", "texels")


def role_cost(role_costs, role):
    """The relative cost ``role_costs`` sets for maps of ``role``, or None (the run's cost applies).

    A role's own entry wins over "normal" for the normal-map roles.
    """
    costs = dict(role_costs)
    if role in costs:
        return costs[role]
    if role.startswith("normal_") and "normal" in costs:
        return costs["normal"]
    return None


@dataclasses.dataclass(frozen=True)
class OptimizeSettings:
    """Options of "Optimize UVs"; the defaults are the paper's settings where it has one.

    Attributes
    ----------
    epsilon : float
        Perceptual loss bound per triangle (GMSD), Eq. 7 and 12-14; the paper uses 0.01.
    target_cost : float or None
        Target relative cost of the result, as ``cost_measure`` measures it; ignored when ``resolution`` is set.
    cost_measure : str
        "memory" (default): ``target_cost`` is the material's image memory relative to the input's, each map's
        new side ``round(sqrt(c * width * height))`` of its own input image (``c`` its role's cost, see
        ``role_costs``) and the charts packed to fill the base colour's. "texels": the paper's relative texel
        cost c_r (Eq. 20-21), the charts packed at the texel density that meets it.
    resolution : int or None
        Explicit side of the new square image instead of a target cost.
    iterations : int
        Loss evaluations per triangle in the Bayesian optimization (the paper: 100, Fig. 15).
    screen_pixels : int
        Side of the per-triangle orthographic view (App. A: 64); a triangle spanning more input texels across
        it gets one pixel per texel, up to ``max_screen_pixels``.
    max_screen_pixels : int
        Largest side a view grows to (at most 256, ``core.camera.MAX_SCREEN_PIXELS``); equal to
        ``screen_pixels``, every view keeps App. A's fixed size. The time of a view grows with its pixel count,
        so this bounds the triangle-wise stage on large textures, at the price of views coarser than the texels.
    margin : int
        Gap between packed islands and bake margin, in pixels of the new image.
    keep_stacks : bool
        UV islands that share texels in the input (mirrored halves, repeated parts, islands laid on each other)
        stay stacked: they keep their input layout together, scaled to the size the method gives them, and
        pack as one island (``core.stacks``), so the new images hold their texels once. Off, every island gets
        texels of its own.
    square_images : bool
        Every new image is a square. Off (the default), the packing chooses the image's width-to-height ratio
        among :data:`.packing.IMAGE_ASPECTS` (2:1 to 1:2): the one that holds the islands at the highest texel
        density for the image memory, or in the fewest pixels for the texel cost; every map of the material gets
        that shape. An explicit ``resolution`` is always a square.
    workers : int
        Worker processes for the triangle-wise stage; 0 means one per core.
    seed : int
        Fixes every random choice: two runs with the same seed give the same UVs.
    uv_map_name : str
        Name of the new UV map.
    image_name : str
        Name of the new image; empty means "<original image>_perceptual".
    use_material_copy : bool
        Assign copies of the materials that sample the new image through the new UV map.
    scheduler : str or None
        Address of a Dask scheduler: the triangle-wise stage and the loss passes run as tasks of that cluster
        (command line only; the results are those of a local run).
    reuse_triangle_results : bool
        Reuse the triangle-wise results of an earlier run on the same mesh, UV map, texture and triangle-wise
        settings (epsilon, evaluations, view sizes, seed), kept in memory and in a per-user cache folder, or
        the triangles done by such a run that was stopped (the stage goes on from them); and its mesh-wise fit
        when ``keep_stacks`` is the same too (the cost, margin, names and sizes change only what follows).
    role_costs : tuple of (str, float)
        Per-role override of the relative cost of the material's other maps, e.g. ``(("normal", 0.2),)``. By
        default every map gets the same relative cost as the base colour, each relative to its own input size (a
        1k normal map beside a 2k base colour stays half the side). With ``cost_measure`` "memory" a map's side is
        ``round(input_side * sqrt(c))``, ``input_side = sqrt(width * height)``, ``c`` its role's cost or
        ``target_cost``. With "texels" (or an explicit ``resolution``) it is ``resolution * input_side /
        reference_side``, multiplied by ``sqrt(c / c_ref)`` for an override ``c``, ``c_ref`` the base colour's
        measured relative texel cost, so the map's relative texel cost is ``c``. Roles: :data:`COST_ROLES`
        ("normal" stands for the three normal-map roles); costs in (0, 4].
    bake_in_background : bool
        Bake the maps with Cycles in a background Blender process (``bridge.bake_process``) while the pipeline
        generator keeps yielding every 0.1 s, instead of one uninterrupted bake call per map in this process:
        the same pixels, for the start-up of one process (a few seconds). The modal operator sets it, so the
        interface never waits for a bake; the command line and batch bake in their own process by default.
    """

    epsilon: float = 0.01
    target_cost: float = 0.3
    cost_measure: str = "memory"
    resolution: int | None = None
    iterations: int = 100
    screen_pixels: int = 64
    max_screen_pixels: int = 256
    margin: int = 4
    keep_stacks: bool = True
    square_images: bool = False
    workers: int = 0
    seed: int = 0
    uv_map_name: str = "PerceptualUV"
    image_name: str = ""
    use_material_copy: bool = True
    reuse_triangle_results: bool = True
    scheduler: str | None = None
    role_costs: tuple = ()
    bake_in_background: bool = False

    def __post_init__(self):
        checks = [
            (0 < self.epsilon < 1, f"epsilon {self.epsilon}: must be in (0, 1)"),
            (self.resolution is not None or 0 < self.target_cost <= 4,
             f"target cost {self.target_cost}: must be in (0, 4]"),
            (self.cost_measure in COST_MEASURES,
             f"cost measure {self.cost_measure!r}: must be 'memory' (the images' memory relative to the input's) "
             "or 'texels' (the paper's relative texel cost, Eq. 21)"),
            (self.resolution is None or 8 <= self.resolution <= 16384,
             f"resolution {self.resolution}: must be in [8, 16384]"),
            (self.iterations >= 10, f"iterations {self.iterations}: at least 10 evaluations per triangle"),
            (16 <= self.screen_pixels <= 256 and self.screen_pixels % 2 == 0,
             f"screen pixels {self.screen_pixels}: must be even and in [16, 256]"),
            (self.screen_pixels <= self.max_screen_pixels <= 256 and self.max_screen_pixels % 2 == 0,
             f"largest view {self.max_screen_pixels}: must be even and in [screen pixels ({self.screen_pixels}), "
             "256]"),
            (0 <= self.margin <= 64, f"margin {self.margin}: must be in [0, 64] pixels"),
            (self.workers >= 0, f"workers {self.workers}: must be >= 0"),
            (self.seed >= 0, f"seed {self.seed}: must be >= 0"),
            (bool(self.uv_map_name.strip()), "the new UV map needs a name"),
        ]
        roles = [pair[0] if isinstance(pair, (tuple, list)) and len(pair) == 2 else None for pair in self.role_costs]
        checks += [
            (all(role is not None for role in roles),
             f"role costs {self.role_costs!r}: must be (role, relative cost) pairs"),
            (all(role in COST_ROLES for role in roles if role is not None),
             f"role costs: unknown role in {', '.join(map(str, roles))}; roles are {', '.join(COST_ROLES)}"),
            (len(set(roles)) == len(roles), f"role costs: a role is given twice in {', '.join(map(str, roles))}"),
        ]
        for pair, role in zip(self.role_costs, roles):
            if role is not None:
                cost = pair[1]
                checks.append((isinstance(cost, (int, float)) and not isinstance(cost, bool) and 0 < cost <= 4,
                               f"cost for {role} {cost!r}: must be in (0, 4]"))
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
