"""The reports of :mod:`.compare`: each model's markdown table, the summary over models, the q_r plots, and the
figures in them (ours against the baselines at the issue's costs, q at equal image memory, the pixel saving's
text).

Every function reads the per-model results as :func:`.compare.compare_model` writes them (``<model>.json``:
``table`` and, per method, ``points`` with ``target_cost``, ``relative_cost``, ``q`` and, in the shaded mode,
``memory_ratio`` and ``maps``), so ``--summary`` rebuilds every table without measuring again.
"""
import json
import pathlib

import numpy as np

__all__ = ["BASELINES", "WIN_COSTS", "SAVING_REFERENCE_COST", "q_at_memory", "memory_figures", "memory_verdict",
           "wins", "model_markdown", "write_summary", "plot_curves", "render_crops"]

BASELINES = ("input", "repacked", "ANGLE_BASED", "CONFORMAL", "MINIMUM_STRETCH", "SSPOP")
"""The methods the issue's target says ours must beat at c_r = 0.2, 0.3 and 0.5."""
SAVING_REFERENCE_COST = 0.5
"""The input's cost whose q_r the pixel saving asks ours to reach."""
WIN_COSTS = (0.2, 0.3, 0.5)
"""The costs (c_r, or image memory in the shaded mode) at which ours is compared with every other method."""


def _is_ours(method):
    """Ours and its variants (``ours_*``, ``paper``): left out where ours is compared with the other methods."""
    return method.startswith("ours") or method == "paper"


def q_at_memory(points, memory, *, tolerance=0.02):
    """A method's shaded q at image memory ``memory``: log q interpolated linearly in memory between the two
    measured points around it (as :func:`core.evaluation.pixel_saving` interpolates over c_r); a point within
    ``tolerance`` (relative) of ``memory`` is taken as it is; None outside the measured range."""
    measured = sorted((p["memory_ratio"], p["q"]) for p in points if p.get("memory_ratio") and p["q"] > 0)
    for ratio, q in measured:
        if abs(ratio - memory) <= tolerance * memory:
            return float(q)
    for (m0, q0), (m1, q1) in zip(measured, measured[1:]):
        if m0 < memory < m1:
            return float(np.exp(np.interp(memory, [m0, m1], [np.log(q0), np.log(q1)])))
    return None


def memory_figures(results, memories=WIN_COSTS):
    """The shaded comparison at equal image memory (what a texture budget fixes; the methods' points are at
    texel costs, and the same c_r takes different memory per method): per method q at each of ``memories``
    (:func:`q_at_memory`); the memory at which ours reaches the input's q at memory 0.5 (the input at a cost c
    is the uniform downscale to c of its memory), with :func:`core.evaluation.pixel_saving` over ours' memory
    ratios; per memory the other methods whose q is not above ours' (``beaten_by``) and those whose points do not
    reach that memory (``unmeasured``)."""
    from ..core.evaluation import pixel_saving

    q = {method: [q_at_memory(res["points"], m) for m in memories] for method, res in results.items()}
    saving = None
    target = q_at_memory(results["input"]["points"], SAVING_REFERENCE_COST) if "input" in results else None
    if target is not None and "ours" in results:
        points = [p for p in results["ours"]["points"] if p.get("memory_ratio") and p["q"] > 0]
        found = pixel_saving([p["memory_ratio"] for p in points], [p["q"] for p in points], target,
                             reference_cost=SAVING_REFERENCE_COST)
        saving = dict(input_q=target, memory=found.relative_cost, position=found.bracketed)
    beaten, unmeasured = {}, {}
    others = [method for method in q if not _is_ours(method)]
    if "ours" in q:
        for index, m in enumerate(memories):
            if q["ours"][index] is not None:
                beaten[str(m)] = [method for method in others
                                  if q[method][index] is not None and q[method][index] <= q["ours"][index]]
                unmeasured[str(m)] = [method for method in others if q[method][index] is None]
    return dict(memories=list(memories), q=q, saving=saving, beaten_by=beaten, unmeasured=unmeasured)


def memory_verdict(figures, memory):
    """"yes" or "no: <methods>" for ours at ``memory``, naming the methods not measured there."""
    beaten, unmeasured = figures["beaten_by"][memory], figures["unmeasured"][memory]
    verdict = "yes" if not beaten else "no: " + ", ".join(beaten)
    return verdict + (f" ({', '.join(unmeasured)} not measured there)" if unmeasured else "")


def wins(results, costs=WIN_COSTS):
    """For each cost in ``costs``: the baselines whose q_r is not above ours (empty = ours is best)."""
    if "ours" not in results:
        return {}
    ours = {p["target_cost"]: p["q"] for p in results["ours"]["points"]}
    losses = {}
    for c in costs:
        if c not in ours:
            continue
        losses[str(c)] = [m for m in BASELINES if m in results and any(
            p["target_cost"] == c and p["q"] <= ours[c] for p in results[m]["points"])]
    return losses


def model_markdown(table, results, costs):
    lines = [f"## {table['model']}", "",
             f"#V {table['vertices']} / #F {table['faces']}, input r {table['input_resolution']}, c_input "
             f"{table['input_cost']:.0f}, epsilon {table['epsilon']}, {table['evaluations']} evaluations per "
             f"triangle{_seed_text(table)}, t_triangle {_fmt_time(table['t_triangle'])} / t_mesh "
             f"{_fmt_time(table['t_mesh'])}, "
             f"q at {table['screen_pixels']} px (20 views)", "",
             "| method | " + " | ".join(f"q @ c_r={c}" for c in costs) + " | E_iso / area (Eq. 24; 1 = isometric) |",
             "|---" * (len(costs) + 2) + "|"]
    for method, res in results.items():
        by_cost = {p["target_cost"]: p for p in res["points"]}
        lines.append(f"| {method} | " + " | ".join(f"{by_cost[c]['q']:.4g} (r {by_cost[c]['resolution']})"
                                                   for c in costs) + f" | {res['e_iso'] / table['surface_area']:.4g} |")
    for method, reason in table.get("failures", {}).items():
        lines.append(f"| {method} | failed: {reason} |" + " |" * len(costs))
    if table.get("shaded"):
        lines += ["", "Shaded q_r (whole material, Cycles, fixed lights); per map q_r and the maps' image memory "
                      "relative to the input's:", "",
                  "| method | c_r | memory | shaded q | per map |", "|---|---|---|---|---|"]
        for method, res in results.items():
            for p in sorted(res["points"], key=lambda p: p["target_cost"]):
                per_map = ", ".join(f"{m['role']} {m['q']:.3g} (r {m['resolution']})" for m in p.get("maps", []))
                lines.append(f"| {method} | {p['target_cost']:g} | {p.get('memory_ratio') or 0:.3f} | {p['q']:.4g} | "
                             f"{per_map} |")
    if table.get("shaded"):
        figures = memory_figures(results)
        lines += ["", "At equal image memory (log q_r interpolated linearly in memory between a method's measured "
                      "points; - outside them):", "",
                  "| method | " + " | ".join(f"q @ memory {m:g}" for m in figures["memories"]) + " |",
                  "|---" * (len(figures["memories"]) + 1) + "|"]
        lines += [f"| {method} | " + " | ".join(_q(value) for value in values) + " |"
                  for method, values in figures["q"].items()]
        saving = figures["saving"]
        if saving:
            lines += ["", f"Ours reaches the input's (the uniform downscale's) shaded q at memory "
                          f"{SAVING_REFERENCE_COST} ({saving['input_q']:.4g}) at memory "
                          f"{_saving_text(dict(saving, relative_cost=saving['memory']))}."]
        for m in figures["beaten_by"]:
            lines.append(f"Ours lowest at memory {m}: {memory_verdict(figures, m)}.")
    bound = {m: r["above_bound"] for m, r in results.items() if "above_bound" in r}
    if bound:
        lines += ["", f"Textured triangles with E > epsilon, at the mesh-wise fit's targets / after the fit (of "
                      f"{next(iter(bound.values()))['textured_triangles']} textured): "
                      + "; ".join(f"{m} {b['targets']:.1%} / {b['fit']:.1%}" for m, b in bound.items()) + "."]
    if table.get("reused"):
        lines += ["", f"Taken from the previous run of this model, not recomputed: {', '.join(table['reused'])}."]
    saving = table["pixel_saving"]
    if saving:
        lines += ["", f"Pixel saving: ours reaches the input's q_r at c_r = {SAVING_REFERENCE_COST} "
                      f"({saving['input_q']:.4g}) at c_r = {_saving_text(saving)} ({saving['position']})."]
    for c, beaten in table["beaten_by"].items():
        lines.append(f"At c_r = {c}: " + ("ours has the lowest q_r." if not beaten else
                                           f"ours is NOT below {', '.join(beaten)}."))
    return "\n".join(lines) + "\n"


def write_summary(folder):
    """``summary.md`` in ``folder``: a Table-1 style table and the pixel saving of every ``<model>.json``."""
    folder = pathlib.Path(folder)
    rows = []
    for file in sorted(folder.glob("*.json")):
        data = json.loads(file.read_text())
        if "table" in data:
            rows.append(data)
            # the per-model tables follow the current format without re-running the model
            costs = [p["target_cost"] for p in next(iter(data["results"].values()))["points"]]
            file.with_suffix(".md").write_text(model_markdown(data["table"], data["results"], costs))
    lines = ["# Summary of the comparisons", "",
             "Generated by `python -m perceptual_uv.bench.compare --summary` from the per-model JSON files.", "",
             "| model | #V / #F | r | c_input | t_triangle / t_mesh | q_r@0.3 input | q_r@0.3 best other method | "
             "q_r@0.3 ours | c_r where ours = input@0.5 | ours below input, repacked, Blender's unwraps and SSPOP "
             "at 0.2 / 0.3 / 0.5 |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    fractions = []
    for data in rows:
        t, results = data["table"], data["results"]
        q03 = {m: next((p["q"] for p in r["points"] if p["target_cost"] == 0.3), None) for m, r in results.items()}
        # every other method, SSP included although the target leaves it out (``BASELINES``)
        baseline = min(((q, m) for m, q in q03.items() if m != "input" and not _is_ours(m) and q is not None),
                       default=None)
        saving = t["pixel_saving"]
        if saving and saving["position"] != "above":
            fractions.append(saving["relative_cost"])
        wins = " / ".join("yes" if not t["beaten_by"].get(str(c)) else "no: " + ", ".join(t["beaten_by"][str(c)])
                          for c in WIN_COSTS if str(c) in t["beaten_by"])
        lines.append(
            f"| {t['model']} | {t['vertices']} / {t['faces']} | {t['input_resolution']} | {t['input_cost']:.0f} | "
            f"{_fmt_time(t['t_triangle'])} / {_fmt_time(t['t_mesh'])} | {_q(q03.get('input'))} | "
            f"{'-' if baseline is None else f'{baseline[0]:.3g} ({baseline[1]})'} | {_q(q03.get('ours'))} | "
            f"{'-' if not saving else _saving_text(saving)} | {wins or '-'} |")
    if fractions:
        missed = len(rows) - len(fractions)
        lines += ["", f"Mean relative cost at which ours matches the input's q_r at c_r = 0.5: "
                      f"{np.mean(fractions):.3f} over the {len(fractions)} models where it does (target <= 0.25)"
                      + (f"; on {missed} of {len(rows)} models ours never reaches it." if missed else ".")]
    shaded = [data for data in rows if data["table"].get("shaded")]
    if shaded:
        lines += ["", "Shaded, at equal image memory (each method's q interpolated between its measured points, "
                      "`bench.compare_report.memory_figures`):", "",
                  "| model | q @ memory 0.3: input (= uniform downscale) | best other method | ours | memory where "
                  "ours = input @ 0.5 | ours lowest at memory |", "|---|---|---|---|---|---|"]
        memories = []
        for data in shaded:
            figures = memory_figures(data["results"])
            index = figures["memories"].index(0.3)
            q03 = {m: values[index] for m, values in figures["q"].items()}
            others = min(((q, m) for m, q in q03.items() if m != "input" and not _is_ours(m) and q is not None),
                         default=None)
            saving = figures["saving"]
            if saving and saving["position"] != "above":
                memories.append(saving["memory"])
            wins = " / ".join(f"{m}: {memory_verdict(figures, m)}" for m in figures["beaten_by"])
            lines.append(f"| {data['table']['model']} | {_q(q03.get('input'))} | "
                         f"{'-' if others is None else f'{others[0]:.3g} ({others[1]})'} | {_q(q03.get('ours'))} | "
                         f"{'-' if not saving else _saving_text(dict(saving, relative_cost=saving['memory']))} | "
                         f"{wins or '-'} |")
        if memories:
            lines += ["", f"Mean memory at which ours matches the input's shaded q at memory 0.5: "
                          f"{np.mean(memories):.3f} over {len(memories)} of {len(shaded)} models."]
    (folder / "summary.md").write_text("\n".join(lines) + "\n")
    return "\n".join(lines)


def plot_curves(results, file, title, screen, x="relative_cost"):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5), dpi=90)
    for method, res in results.items():
        points = sorted(res["points"], key=lambda p: p[x])
        ax.plot([p[x] for p in points], [p["q"] for p in points], "o-", label=method,
                lw=2 if method == "ours" else 1, ms=3)
    ax.set_yscale("log")
    ax.set_xlabel("relative cost $c_r$" if x == "relative_cost" else "image memory (relative to the input's)")
    ax.set_ylabel(f"$q_r$ ({'shaded, ' if x == 'memory_ratio' else ''}mean GMSD, 20 views, {screen} px)")
    ax.set_title(title)
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(file)
    plt.close(fig)


def _seed_text(table):
    """``", seed N"`` for a run with the triangle-wise stage's seed N other than 0, else nothing."""
    return f", seed {table['seed']}" if table.get("seed") else ""


def _fmt_time(t):
    return "-" if t is None else f"{t:.1f} s"


def _q(value):
    return "-" if value is None else f"{value:.3g}"


def _saving_text(saving):
    if saving["position"] == "above":
        return "not reached"
    return f"{saving['relative_cost']:.3f}" + (" (bound)" if saving["position"] == "below" else "")


def render_crops(objects, names, source, reference, file, screen):
    """The centre of the first view (half its side): the reference, then the input and ours re-baked at c_r = 0.3
    (the UV maps ``names["input"]`` and ``names["ours"]`` of ``objects``), side by side in ``file``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import bpy

    from ..bridge.evaluate import evaluate_uv_map, render_views

    panels = [("reference", reference[0])]
    for method in ("input", "ours"):
        if method not in names:
            continue
        res = evaluate_uv_map(objects, names[method], reference_uv=source, costs=(0.3,), screen_pixels=screen,
                              reference_views=reference, keep_images=True)
        image = res["images"][0]
        view = render_views(objects, uv_name=names[method], image=image, screen_pixels=screen)[0]
        bpy.data.images.remove(image)
        panels.append((f"{method} c_r=0.3", view))
    h = screen // 4
    fig, axes = plt.subplots(1, len(panels), figsize=(3 * len(panels), 3), dpi=80)
    for ax, (label, view) in zip(np.atleast_1d(axes), panels):
        ax.imshow(view[::-1][screen // 2 - h:screen // 2 + h, screen // 2 - h:screen // 2 + h, :3],
                  interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(file)
    plt.close(fig)
