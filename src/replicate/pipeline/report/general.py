"""The general policy's section: its suite's cells against the bars of ``report.general``, every seed and the
baselines, as Markdown rows, the lakes of each kind (``compare.suite.LakeKind``) apart."""

from __future__ import annotations

import numpy as np

from replicate.compare.stats import DEFAULT, Bootstrap, mean_interval
from replicate.compare.suite import KINDS, lake_kinds
from replicate.core.params import Cell, run_config
from replicate.core.sections import DRIFTS, EVENTS
from replicate.pipeline.report.rules import fmt

# the comparisons of every cell, by what each one knows (``INFORMATION``)
YARDSTICKS = ("naive_tuned", "decentralised_lloyd", "lloyd_tuned", "geodesic_lloyd", "planner", "best_layout",
              "upper_bound")
CONTROLLERS = YARDSTICKS[:4]  # the baselines that steer from what they see, beside the policy
READ_AGAINST = ("lloyd_tuned", "planner", "best_layout")  # every policy column is also read as a share of these
INFORMATION = {
    "general policy": "its own sensors: the buoys it hears within the communication range, rays to the shore",
    "naive_tuned": "the buoys near it (it keeps away from them) and the map (it is drawn into the water)",
    "decentralised_lloyd": "what the policy knows: the buoys it hears, the water within its shore sensor's reach "
                           "of where it has been",
    "lloyd_tuned": "the map and every buoy (clairvoyant)",
    "geodesic_lloyd": "the map and every buoy, cells and paths through the water (clairvoyant)",
    "planner": "the map and every buoy: the best layout, each buoy assigned a place (Hungarian method on the "
               "distances through the water) and sailed there under the same physics (not a limit at T: a buoy "
               "covers nothing new on its way)",
    "best_layout": "the map, no physics and no time: a layout searched offline from greedy placements, Lloyd's "
                   "layout and the policies' best final layout, every buoy in the water (a heuristic, not a bound)",
    "upper_bound": "min(1, N·A(Cov)/A(Reg)): no layout covers more",
}
KIND_TITLE = {"trained": "trained on (the training worlds)",
              "design": "design lakes (the yardstick's: never trained on, read by every choice)",
              "test": "test lakes (generated, a stream no choice read)",
              "real": "real lakes (Bedok and OpenStreetMap reservoirs, never trained on)"}
POOLED = ("design", "test")  # generated lakes: one row per fleet, start and event, the mean over the lakes


def kind_of(params, c: dict) -> str:
    """A cell's lake kind (``compare.suite.lake_kinds`` for a cell written without one)."""
    return c.get("kind") or lake_kinds(params).get(c["region"], "test")


def seed_coverages(cell: dict) -> dict[str, float]:
    """{seed: mean coverage} of a suite cell: every trained seed's policy (the kept policy alone in a file
    without seeds)."""
    seeds = cell.get("seeds") or {"kept": {"coverage": cell["coverage"], "max_outside_m": cell["max_outside_m"]}}
    return {label: r["coverage"]["mean"] for label, r in seeds.items()}


def over_seeds(values: list[float], boot: Bootstrap = DEFAULT) -> str:
    """mean [interval] over training seeds, the seed as the unit (``stats.mean_interval`` with ``boot``, the
    ``report`` section's): Student's t below ``t_below`` seeds (the percentile bootstrap keeps a null difference
    too often at few seeds), else the percentile bootstrap; the mean alone for one seed."""
    ci = mean_interval(values, boot)
    if ci["n"] < 2:
        return f"{ci['mean']:.3f}"
    lo, hi = (ci["t_lo"], ci["t_hi"]) if "t_lo" in ci else (ci["lo"], ci["hi"])
    return f"{ci['mean']:.3f} [{lo:.3f}, {hi:.3f}]"


def one_limit(cells: list[dict]) -> list[dict]:
    """``cells`` with one best layout per lake, fleet and buoys in service: the best of their cells' searches. Each
    cell's search also starts from its own policies' best final layout (``best_layout.best_coverage_from``), so
    the cells of one lake may have found different layouts; the limit of a lake and fleet is the best of them,
    whatever start or event a cell had (a layout has no physics)."""
    def lake_and_fleet(c: dict) -> tuple:
        return c["region"], c["n_agents"], c["baselines"]["best_layout"].get("buoys")

    best: dict[tuple, dict] = {}
    for c in cells:
        if "best_layout" in c["baselines"]:
            layout = c["baselines"]["best_layout"]
            best[lake_and_fleet(c)] = max(best.get(lake_and_fleet(c), layout), layout,
                                          key=lambda b: b["coverage"]["mean"])  # the first of equals
    return [c | {"baselines": c["baselines"] | {"best_layout": best[lake_and_fleet(c)]}}
            if "best_layout" in c["baselines"] else c for c in cells]


def still_ratios(cells: list[dict], seed: str) -> list[float]:
    """Seed ``seed``'s coverage / lloyd_tuned's of every still-water cell."""
    return [c["seeds"][seed]["coverage"]["mean"] / c["baselines"]["lloyd_tuned"]["coverage"]["mean"] for c in cells
            if c["event"] == "none"]


def rival(c: dict, name: str) -> float:
    """The mean coverage of comparison ``name`` in cell ``c``."""
    return c["baselines"][name]["coverage"]["mean"]


def narrow_cells(cells: list[dict], t) -> list[dict]:
    """The still-water cells of lakes where lloyd_tuned stops ``t.narrow_gap`` or more below the best layout
    (arms, islands): ``report.general``'s bar there asks more than Lloyd's coverage of the policy."""
    return [c for c in cells if c["event"] == "none" and rival(c, "best_layout") - rival(c, "lloyd_tuned")
            >= t.narrow_gap]


def general_checks(cells: list[dict], t) -> list[tuple[str, list[dict], list[bool]]]:
    """(bar, the cells it applies to, whether each meets it with every seed) of ``report.general`` (``t``)."""

    def every_seed(c, bar) -> bool:
        return all(bar(v) for v in seed_coverages(c).values())

    still = [c for c in cells if c["event"] == "none"]
    key = {(c["region"], c["n_agents"], c["start"]): seed_coverages(c) for c in still}

    def keeps(c, share) -> bool:  # each seed against its own still-water coverage
        own = key.get((c["region"], c["n_agents"], c["start"]), {})
        return all(s in own and v >= share * own[s] for s, v in seed_coverages(c).items())

    lose, drift = [c for c in cells if c["event"] == "lose"], [c for c in cells if c["event"] in DRIFTS]
    narrow = narrow_cells(still, t)
    return [
        (f"still water: ≥ {t.of_lloyd:.0%} of lloyd_tuned", still,
         [every_seed(c, lambda v, c=c: v >= t.of_lloyd * rival(c, "lloyd_tuned")) for c in still]),
        ("still water: above naive_tuned", still, [every_seed(c, lambda v, c=c: v > rival(c, "naive_tuned"))
                                                   for c in still]),
        (f"still water: ≥ {t.of_best:.0%} of the best layout", still,
         [every_seed(c, lambda v, c=c: v >= t.of_best * rival(c, "best_layout")) for c in still]),
        (f"lakes where lloyd_tuned is ≥ {t.narrow_gap} below the best layout: above lloyd_tuned", narrow,
         [every_seed(c, lambda v, c=c: v > rival(c, "lloyd_tuned")) for c in narrow]),
        (f"buoys lost at T/2: ≥ {t.lose_of_lloyd:.0%} of what lloyd_tuned re-covers", lose,
         [every_seed(c, lambda v, c=c: v >= t.lose_of_lloyd * rival(c, "lloyd_tuned")) for c in lose]),
        (f"drift or vortex: ≥ {t.current_of_lloyd:.0%} of lloyd_tuned in the same water", drift,
         [every_seed(c, lambda v, c=c: v >= t.current_of_lloyd * rival(c, "lloyd_tuned")) for c in drift]),
        (f"drift or vortex: ≥ {t.current_of_still:.0%} of its own still-water coverage", drift,
         [keeps(c, t.current_of_still) for c in drift]),
    ]


def general_verdicts(cells: list[dict], t) -> list[tuple[str, str, str]]:
    """(bar, how many cells meet it, verdict) of the general policy's targets: a cell meets a bar when every
    seed's policy does."""
    return [(bar, f"{sum(ok)} of {len(which)}", "met" if all(ok) else "not met")
            for bar, which, ok in general_checks(cells, t) if which]


VERDICT_KINDS = ("test", "real")  # the lakes that neither the training nor a choice read: each its own verdict


def bar_table(params, cells: list[dict]) -> list[str]:
    """The bars of ``report.general``: cells meeting each with every seed, per lake kind, and a verdict for each
    kind of ``VERDICT_KINDS`` (never one verdict over two kinds)."""
    t = params.report.general
    kinds = {k: [c for c in cells if kind_of(params, c) == k] for k in KINDS}
    per_kind = {k: {bar: (ok, which) for bar, which, ok in general_checks(group, t)} for k, group in kinds.items()}
    verdicts = {k: {bar: verdict for bar, _, verdict in general_verdicts(kinds[k], t)} for k in VERDICT_KINDS}
    bars = [bar for bar, _, _ in general_checks(cells, t)]
    rows = ["| bar (`report.general`) | " + " | ".join(KIND_TITLE[k].split(" (")[0] for k in KINDS) + " | "
            + " | ".join(f"verdict: {k} lakes" for k in VERDICT_KINDS) + " |",
            "|---|" + "---|" * (len(KINDS) + len(VERDICT_KINDS))]
    for bar in bars:
        counts = [f"{sum(per_kind[k][bar][0])} of {len(per_kind[k][bar][1])}" if per_kind[k].get(bar, ((), ()))[1]
                  else "—" for k in KINDS]
        said = [f"**{verdicts[k][bar]}**" if bar in verdicts[k] else "—" for k in VERDICT_KINDS]
        rows.append(f"| {bar} | " + " | ".join(counts) + " | " + " | ".join(said) + " |")
    for k in VERDICT_KINDS:
        seeds = sorted({s for c in kinds[k] for s in c.get("seeds", {})})
        if seeds and all(set(c.get("seeds", {})) == set(seeds) for c in kinds[k]):
            ratios = {s: still_ratios(kinds[k], s) for s in seeds}
            rows += ["", f"Still water on the {k} lakes, coverage / lloyd_tuned per seed: " + "; ".join(
                f"{s} mean {np.mean(r):.3f}, worst {min(r):.3f}" for s, r in ratios.items()) + "."]
    return rows


def per_region_cr(params, summary: dict, c: dict) -> str:
    """The per-region `tuned` CR-MARL of a suite cell's region, fleet, start and event, from the robustness
    scenario (``evaluate.robustness``) with the same start, the same buoys lost and the region's T (its own
    physics, not the wall), as mean [CI] over seeds, its T written out where the suite's differs; "—" where there
    is none."""
    if c["region"] not in params.regions or c["n_agents"] != params.world.n_agents or c["event"] in DRIFTS:
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


def rivals_of(c: dict) -> list[float]:
    return [c["baselines"][k]["coverage"]["mean"] if k in c["baselines"] else float("nan") for k in YARDSTICKS]


def row(label, n, start, event, general: str, seeds: list[float], cr: str, rivals: list[float],
        ratios: list[str], boot: Bootstrap = DEFAULT) -> str:
    return (f"| {label} | {n} | {start} | {event} | {general} | {over_seeds(seeds, boot)} | {cr} | "
            + " | ".join("—" if v != v else f"{v:.3f}" for v in rivals) + " | " + " | ".join(ratios) + " |")


def nanmean(values) -> float:
    """The mean of the values that are not NaN; NaN when none is (a comparison no cell has)."""
    v = np.asarray(values, float)
    return float(v[~np.isnan(v)].mean()) if (~np.isnan(v)).any() else float("nan")


def share(value: float, of: float) -> float:
    """value / of, NaN where ``of`` is missing (NaN) or 0."""
    return value / of if of == of and of > 0 else float("nan")


def cell_rows(params, cells: list[dict], summary: dict) -> list[str]:
    """One row per cell: the deployed policy (its interval over episodes), the seeds (mean and interval over
    seeds), the per-region `tuned` CR-MARL where ``summary`` has it, the comparisons, seeds / lloyd_tuned."""
    out = []
    for c in cells:
        seeds, rivals = list(seed_coverages(c).values()), rivals_of(c)
        ratios = [share(float(np.mean(seeds)), rivals[YARDSTICKS.index(k)]) for k in READ_AGAINST]
        out.append(row(c["region"], c["n_agents"], c["start"], c["event"], fmt(c["coverage"]), seeds,
                       per_region_cr(params, summary, c), rivals, ["—" if r != r else f"{r:.3f}" for r in ratios],
                       Bootstrap.of(params.report)))
    return out


def pooled_rows(cells: list[dict], kind: str = "test", boot: Bootstrap = DEFAULT) -> list[str]:
    """Generated lakes of ``kind`` pooled per fleet, start and event: means over lakes (the deployed policy's range
    over lakes), the seeds' interval over seeds of their mean over lakes, the worst lake's ratio to each yardstick."""
    groups: dict[tuple, list[dict]] = {}
    for c in cells:
        groups.setdefault((c["n_agents"], c["start"], c["event"]), []).append(c)
    out = []
    for (n, start, event), group in sorted(groups.items(), key=lambda kv: (*kv[0][:2], EVENTS.index(kv[0][2]))):
        general = [c["coverage"]["mean"] for c in group]
        per_seed = [seed_coverages(c) for c in group]
        seeds = [float(np.mean([p[s] for p in per_seed])) for s in per_seed[0]]
        ratios = np.array([[share(float(np.mean(list(p.values()))), rivals_of(c)[YARDSTICKS.index(k)])
                            for k in READ_AGAINST] for p, c in zip(per_seed, group)])  # [lakes, READ_AGAINST]
        out.append(row(f"{len(group)} {kind} lakes (mean)", n, start, event,
                       f"{np.mean(general):.3f} ({min(general):.3f}-{max(general):.3f})", seeds, "—",
                       [nanmean(col) for col in np.array([rivals_of(c) for c in group]).T],
                       ["—" if np.isnan(r).all() else f"{np.nanmean(r):.3f} (worst {np.nanmin(r):.3f})"
                        for r in ratios.T], boot))
    return out


def general_tables(params, cells: list[dict], summary: dict) -> list[str]:
    """One table per lake kind: every cell of the trained-on and the real lakes, the generated ones pooled."""
    boot = Bootstrap.of(params.report)
    how = f"Student's t below {boot.t_below} seeds" if len(seed_coverages(cells[0])) < boot.t_below else "percentile"
    head = (f"| lake | N | start | event | general policy (deployed) | seeds: mean [{boot.level:.0%} CI over seeds, "
            f"{how}] | tuned CR | "
            "naive_tuned | decentralised Lloyd | lloyd_tuned | geodesic Lloyd | planner | best layout | upper bound | "
            "seeds / lloyd_tuned | seeds / planner | seeds / best layout |")
    lines = []
    for kind in KINDS:
        group = [c for c in cells if kind_of(params, c) == kind]
        if group:
            lines += [f"**{KIND_TITLE[kind][0].upper()}{KIND_TITLE[kind][1:]}**", "", head, "|" + "---|" * 17,
                      *(pooled_rows(group, kind, boot) if kind in POOLED else cell_rows(params, group, summary)), ""]
    return lines


def share_table(params, cells: list[dict]) -> list[str]:
    """Every controller as a share of the planner (the best layout, sailed to) and of the best layout (no physics, no
    time), the mean over the cells of each lake kind (every start and event): the seeds' mean coverage for the
    policy. Empty where no cell has the planner."""
    kinds = {k: [c for c in cells if kind_of(params, c) == k and "planner" in c["baselines"]] for k in KINDS}
    kinds = {k: group for k, group in kinds.items() if group}
    if not kinds:
        return []

    def coverage(c, who) -> float:
        return float(np.mean(list(seed_coverages(c).values()))) if who == "policy" else (
            c["baselines"][who]["coverage"]["mean"] if who in c["baselines"] else float("nan"))

    rows = ["| controller | " + " | ".join(f"{KIND_TITLE[k].split(' (')[0]}: of planner | of best layout"
                                          for k in kinds) + " |", "|---|" + "---|" * (2 * len(kinds))]
    for who in ("policy", *CONTROLLERS):
        shares = [nanmean([share(coverage(c, who), coverage(c, of)) for c in group])
                  for group in kinds.values() for of in ("planner", "best_layout")]
        label = "general policy (mean of its seeds)" if who == "policy" else who
        rows.append(f"| {label} | " + " | ".join("—" if v != v else f"{v:.3f}" for v in shares) + " |")
    every = [c for group in kinds.values() for c in group]
    def from_policy(c: dict) -> bool:
        return c["baselines"]["best_layout"].get("from_policy", False)

    found = [c for c in every if from_policy(c)]
    narrow = narrow_cells(every, params.report.general)
    return ["Every controller as a share of the planner and of the best layout (mean over the cells of a kind, "
            "every start and event):", "", *rows, "",
            f"The search from the policies' best final layout gave the best layout of the lake and fleet in "
            f"{len(found)} of {len(every)} cells; {sum(map(from_policy, narrow))} of the {len(narrow)} cells of the "
            "bar on lakes where lloyd_tuned stops short of the best layout are among them (a layout the policy "
            "found can bring a cell into that bar)."]


def tried_section(records: dict[str, dict]) -> list[str]:
    """The changes of the general training or its deployed policy measured on the yardstick (``replicate compare``
    records, by name), each with its gain over the standing baseline, the rule's bar (0, or a loss a change made for
    speed may cost) and its verdict."""
    if not records:
        return []
    lines = ["Changes of the general training or of its deployed policy measured on the yardstick lakes "
             "(`replicate compare`: tuning seeds, the seed as the unit, the rule written before the seeds were "
             "trained or run; the records in "
             "`docs/comparisons/`, the reading in `docs/GENERAL.md`, which says whether `params.yaml` adopted it; "
             "a candidate whose first seeds collapsed is there, with no record):", "",
             "| change (record) | seeds a side | Δ coverage / lloyd_tuned [95 % interval over seeds] | "
             "P(a candidate seed beats a baseline seed) | passes iff the interval lies above | passes |",
             "|---|---|---|---|---|---|"]
    for name, r in sorted(records.items()):
        d, v = r["verdict"]["difference"], r["verdict"]
        seeds = sum(k.startswith("candidate/") for k in r["scores"])
        lines.append(f"| {name} | {seeds} | {d['delta']:+.4f} [{d['lo']:+.4f}, {d['hi']:+.4f}] | "
                     f"{v['probability_of_improvement']['p']:.2f} | {v['min_gain']:+.3f} | "
                     f"{'yes' if v['keep'] == 'candidate' else 'no'} |")
    return [*lines, ""]


def general_section(params, general: dict, summary: dict | None = None) -> list[str]:
    cells = one_limit(general["cells"])
    su = params.general.suite
    seeds = general.get("seeds", [])
    trained = [r for r in params.regions if r in params.general.regions]
    named_real = [r for r in params.regions if r not in params.general.regions]
    said = {"none": "still water", "lose": f"{su.lose_fraction:.0%} of the fleet lost at T/2 (coverage of the rest "
            "at T)", "current": f"a uniform drift of {su.current} m/s, its heading drawn per cell",
            "vortex": f"a vortex over the lake (peak {su.current} m/s at a third of the lake's size from its middle; "
                      "its turn drawn per cell)"}
    lines = ["## One policy for every lake", "",
             f"The general policy (`{general['policy']}`, one network trained on the training worlds of `general`, "
             f"local sensors only, the compass symmetry `{params.general.learner.symmetry}`) on four kinds of "
             f"lakes, never pooled: the regions it trains on ({', '.join(trained)}, N ∈ {list(su.named_fleets)} "
             f"at the paper's density), the yardstick's {params.yardstick.lakes} design lakes, on which the "
             f"training's values were chosen, {su.test_lakes} generated test lakes of a seed stream that no choice "
             f"read (both N ∈ {list(su.lake_fleets)}, each lake at its own density), and real lakes, zero-shot: "
             f"{', '.join(named_real) or 'no named region'} (N ∈ {list(su.named_fleets)}) and "
             f"{len(su.real_lakes)} lake files (N ∈ {list(su.lake_fleets)}). Starts in the corner patch or scattered; "
             f"{', '.join(said[e] for e in su.events)}; {su.episodes} episodes per cell from the evaluation seed, "
             "behind the shore wall (no buoy can leave the water: a property of the wall, not a result).", "",
             f"The seed is the unit: {len(seeds) or 1} trained seeds ({', '.join(seeds) or 'one'}), each exported; a "
             "cell meets a bar only when every seed does. The deployed policy (the best-validated seed) is shown "
             "with its interval over episodes. What each controller knows:", "",
             *[f"- {name}: {what}" for name, what in INFORMATION.items()], "",
             "naive_tuned, lloyd_tuned, decentralised and geodesic Lloyd carry gains tuned once on the training "
             "worlds with the training's losses and drifts (`tuning.general_baselines`); the planner steers with "
             "lloyd_tuned's. \"tuned CR\" "
             "is the per-region `tuned` CR-MARL of the robustness table (trained on that region, its own physics, "
             "mean [CI] over its seeds), where a scenario matches.", "",
             *bar_table(params, cells), "", *share_table(params, cells), "",
             *general_tables(params, cells, summary or {})]
    return lines
