"""The general policy's section: its suite's cells against the bars of ``report.general``, every seed and the
baselines, as Markdown rows."""

from __future__ import annotations

from replicate.core.params import Cell, run_config
from replicate.core.sections import EVENTS
from replicate.pipeline.report.rules import fmt

YARDSTICKS = ("naive_tuned", "lloyd_tuned", "geodesic_lloyd", "best_layout")


def seed_coverages(cell: dict) -> dict[str, float]:
    """{seed: mean coverage} of a suite cell: every trained seed's policy (the kept policy alone in a file
    without seeds)."""
    seeds = cell.get("seeds") or {"kept": {"coverage": cell["coverage"], "max_outside_m": cell["max_outside_m"]}}
    return {label: r["coverage"]["mean"] for label, r in seeds.items()}


def one_seed(cells: list[dict], label: str) -> list[dict]:
    """The suite's cells as if ``label`` were the only seed."""
    return [{**c, "coverage": c["seeds"][label]["coverage"], "max_outside_m": c["seeds"][label]["max_outside_m"],
             "seeds": {label: c["seeds"][label]}} for c in cells]


def still_ratios(cells: list[dict]) -> list[float]:
    """Coverage / lloyd_tuned's of every still-water cell (the cells' own policy)."""
    return [c["coverage"]["mean"] / c["baselines"]["lloyd_tuned"]["coverage"]["mean"] for c in cells
            if c["event"] == "none"]


def general_verdicts(cells: list[dict], t) -> list[tuple[str, str, str]]:
    """(bar, how many cells meet it, verdict) of the general policy's targets (``report.general``, ``t``): a cell
    meets a bar when every seed's policy does."""
    def rival(c, name):
        return c["baselines"][name]["coverage"]["mean"]

    def every_seed(c, bar) -> bool:
        return all(bar(v) for v in seed_coverages(c).values())

    still = [c for c in cells if c["event"] == "none"]
    key = {(c["region"], c["n_agents"], c["start"]): seed_coverages(c) for c in still}

    def keeps(c, share) -> bool:  # each seed against its own still-water coverage
        own = key[(c["region"], c["n_agents"], c["start"])]
        return all(v >= share * own[s] for s, v in seed_coverages(c).items())

    checks = [
        (f"still water: ≥ {t.of_lloyd:.0%} of lloyd_tuned", still,
         [every_seed(c, lambda v, c=c: v >= t.of_lloyd * rival(c, "lloyd_tuned")) for c in still]),
        ("still water: above naive_tuned", still,
         [every_seed(c, lambda v, c=c: v > rival(c, "naive_tuned")) for c in still]),
        (f"still water: ≥ {t.of_best:.0%} of the best layout", still,
         [every_seed(c, lambda v, c=c: v >= t.of_best * rival(c, "best_layout")) for c in still]),
        (f"lakes where lloyd_tuned is ≥ {t.narrow_gap} below the best layout: above lloyd_tuned",
         narrow := [c for c in still if rival(c, "best_layout") - rival(c, "lloyd_tuned") >= t.narrow_gap],
         [every_seed(c, lambda v, c=c: v > rival(c, "lloyd_tuned")) for c in narrow]),
        (f"buoys lost at T/2: ≥ {t.lose_of_lloyd:.0%} of what lloyd_tuned re-covers",
         lose := [c for c in cells if c["event"] == "lose"],
         [every_seed(c, lambda v, c=c: v >= t.lose_of_lloyd * rival(c, "lloyd_tuned")) for c in lose]),
        (f"drift: ≥ {t.current_of_still:.0%} of its own still-water coverage",
         drift := [c for c in cells if c["event"] == "current"], [keeps(c, t.current_of_still) for c in drift]),
        ("no buoy ever outside the water", cells,
         [all(r["max_outside_m"] == 0 for r in (c.get("seeds") or {"kept": c}).values()) for c in cells]),
    ]
    return [(bar, f"{sum(ok)} of {len(which)}", "met" if all(ok) else "not met") for bar, which, ok in checks
            if which]


def per_region_cr(params, summary: dict, c: dict) -> str:
    """The per-region `tuned` CR-MARL of a suite cell's region, fleet, start and event, from the robustness
    scenario (``evaluate.robustness``) with the same start, the same buoys lost and the region's T (its own
    physics, not the wall), as mean [CI] over seeds, its T written out where the suite's differs; "—" where there
    is none."""
    if c["region"] not in params.regions or c["n_agents"] != params.world.n_agents or c["event"] == "current":
        return "—"
    runs = summary.get("runs", {}).get(Cell("tuned", "cr", c["region"]).key, {}).get("robustness", {})
    lose = c.get("lose", 0) if c["event"] == "lose" else 0
    same = [name for name, s in params.evaluate.robustness.items()
            if (s.start, s.lose, s.horizon) == (c["start"], lose, 1.0) and name in runs]
    if not same:
        return "—"
    steps = run_config(params, "tuned", "cr", c["region"]).world.episode_length
    text = fmt(runs[same[0]]["coverage"])
    return text if steps == c.get("steps") else f"{text} (T = {steps})"


def general_rows(params, cells: list[dict], summary: dict) -> list[str]:
    """Markdown rows: every cell of the named regions, then the held-out lakes pooled per fleet, start and event
    (mean over lakes, and the worst lake's ratio to lloyd_tuned). The general policy's column is the kept seed's (its
    interval over episodes); the next gives the range over every seed (over seeds of the mean over lakes); then
    the per-region `tuned` CR-MARL where ``summary`` has it (``per_region_cr``)."""
    def row(label, n, start, event, general, seeds, cr, rivals, ratio):
        return (f"| {label} | {n} | {start} | {event} | {general} | {min(seeds):.3f}-{max(seeds):.3f} | {cr} | "
                + " | ".join(f"{v:.3f}" for v in rivals) + f" | {ratio} |")

    rows = []
    for c in cells:
        if c["region"] in params.regions:
            rivals = [c["baselines"][k]["coverage"]["mean"] for k in YARDSTICKS]
            rows.append(row(c["region"], c["n_agents"], c["start"], c["event"], fmt(c["coverage"]),
                            list(seed_coverages(c).values()), per_region_cr(params, summary, c),
                            rivals, f"{c['coverage']['mean'] / rivals[1]:.3f}"))
    lakes: dict[tuple, list[dict]] = {}
    for c in cells:
        if c["region"] not in params.regions:
            lakes.setdefault((c["n_agents"], c["start"], c["event"]), []).append(c)
    for (n, start, event), group in sorted(lakes.items(), key=lambda kv: (*kv[0][:2], EVENTS.index(kv[0][2]))):
        general = [c["coverage"]["mean"] for c in group]
        per_seed = [seed_coverages(c) for c in group]
        seeds = [sum(p[s] for p in per_seed) / len(group) for s in per_seed[0]]
        rivals = [sum(c["baselines"][k]["coverage"]["mean"] for c in group) / len(group) for k in YARDSTICKS]
        ratios = [c["coverage"]["mean"] / c["baselines"]["lloyd_tuned"]["coverage"]["mean"] for c in group]
        rows.append(row(f"{len(group)} held-out lakes (mean)", n, start, event,
                        f"{sum(general) / len(general):.3f} ({min(general):.3f}-{max(general):.3f})", seeds, "—",
                        rivals,
                        f"{sum(ratios) / len(ratios):.3f} (worst {min(ratios):.3f})"))
    return rows


def bar_table(cells: list[dict], t, seeds: list[str]) -> list[str]:
    """The bars of ``report.general`` (``t``): cells meeting each with every seed (the verdict), then with each
    seed alone; and each seed's mean and worst ratio to lloyd_tuned in still water."""
    per_seed = [general_verdicts(one_seed(cells, s), t) for s in seeds] if all("seeds" in c for c in cells) else []
    head = "| bar (`report.general`) | cells meeting it, every seed | verdict |" + "".join(
        f" {s} alone |" for s in seeds[:len(per_seed)])
    rows = [head, "|---|---|---|" + "---|" * len(per_seed)]
    for k, (bar, n, v) in enumerate(general_verdicts(cells, t)):
        rows.append(f"| {bar} | {n} | **{v}** |" + "".join(f" {seed[k][1]} |" for seed in per_seed))
    if per_seed:
        ratios = {s: still_ratios(one_seed(cells, s)) for s in seeds}
        rows += ["", "Still water, coverage / lloyd_tuned per seed: " + "; ".join(
            f"{s} mean {sum(r) / len(r):.3f}, worst {min(r):.3f}" for s, r in ratios.items()) + "."]
    return rows


def general_section(params, general: dict, summary: dict | None = None) -> list[str]:
    cells, t = general["cells"], params.report.general
    su = params.general.suite
    seeds = ", ".join(general.get("seeds", [])) or "one"
    said = {"none": "still water", "lose": f"{su.lose_fraction:.0%} of the fleet lost at T/2 (coverage of the rest "
            "at T)", "current": f"a uniform drift of {su.current} m/s"}
    turned = (", its actor averaged over the compass's quarter turns and mirrors, `general.learner.symmetry`"
              if params.general.learner.symmetry != "none" else "")
    lines = ["## One policy for every lake", "",
             f"The general policy (`{general['policy']}`, one network trained once on the training worlds of "
             f"`general`, local sensors only{turned}), zero-shot on lakes it never trained on, behind the shore "
             f"wall: the square, the rectangle and Bedok at N ∈ {list(su.named_fleets)} (each at the paper's density), "
             f"{su.held_out} held-out generated lakes at N ∈ {list(su.lake_fleets)} (each at its own density); "
             "starts in the corner patch or scattered; on every lake and fleet: "
             f"{', '.join(said[e] for e in su.events)}. {su.episodes} episodes per cell from the evaluation seed. "
             "The general policy's column is the deployed policy (the best-validated seed) with its interval over "
             "episodes; "
             f"\"every seed\" is the range over the trained seeds ({seeds}), and a cell meets a bar only when "
             "every seed does. naive_tuned and lloyd_tuned carry the gains tuned once on the "
             "training worlds (`tuning.general_baselines`), geodesic Lloyd Lloyd's; the best layout is the "
             "offline limit for the buoys in service. \"tuned CR\" is the per-region `tuned` CR-MARL of the "
             "robustness table (its own training physics, not the wall; mean [CI] over its seeds), where a "
             "scenario matches.", "",
             *bar_table(cells, t, general.get("seeds", [])), "",
             "| lake | N | start | event | general policy | every seed | tuned CR | naive_tuned | lloyd_tuned | "
             "geodesic Lloyd | best layout | general / lloyd_tuned |", "|" + "---|" * 12,
             *general_rows(params, cells, summary or {}), ""]
    return lines
