"""``REPORT.md``, generated from ``metrics/summary.json``: the paper's claims (SPEC §10), each judged by a rule
fixed in ``params.yaml`` ``report`` before the numbers and printed beside its verdict with the verdict under the
rule's margins and tolerances halved and doubled; the headline comparisons with intervals of their differences
and probabilities of improvement; the targets of ``tuned``; the search budgets; the robustness table; the
ablation; the coverage tables, the timings and the figures. Nothing in it is typed by hand.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from replicate.compare import stats
from replicate.core import artifacts
from replicate.core.params import EVENTS, Cell, ReportConfig, run_config

REPRODUCED, PARTLY, NOT = "reproduced", "partly", "not reproduced"


@dataclass(frozen=True)
class Claim:
    claim: str
    rule: str
    verdict: str
    evidence: str


def fmt(ci: dict) -> str:
    if ci.get("n", 0) == 0:
        return "—"
    if ci["n"] == 1 or ci["lo"] != ci["lo"]:
        return f"{ci['mean']:.3f} (n={ci['n']})"
    return f"{ci['mean']:.3f} [{ci['lo']:.3f}, {ci['hi']:.3f}]"


def fmt_delta(d: dict, key: str = "delta") -> str:
    if d["lo"] != d["lo"]:
        return f"{d[key]:+.3f}"
    return f"{d[key]:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}]"


def fmt_p(p: dict) -> str:
    return f"{p['p']:.2f}" if p["lo"] != p["lo"] else f"{p['p']:.2f} [{p['lo']:.2f}, {p['hi']:.2f}]"


def span(values: list[float]) -> str:
    """'lo-hi' of seconds, one number when they agree, a dash when there are none."""
    if not values:
        return "—"
    lo, hi = f"{min(values):.0f}", f"{max(values):.0f}"
    return lo if lo == hi else f"{lo}-{hi}"


def over_cells(holds: list[bool], partly: float) -> str:
    """A claim over several cells: every cell holds → reproduced; at least ``partly`` of them → partly."""
    if not holds:
        return NOT
    share = sum(holds) / len(holds)
    return REPRODUCED if share == 1 else PARTLY if share >= partly else NOT


def scaled(rules: ReportConfig, factor: float) -> ReportConfig:
    """The rules with every margin and tolerance multiplied by ``factor`` (the sensitivity column)."""
    return dataclasses.replace(
        rules, margin=rules.margin * factor, spread_margin=rules.spread_margin * factor,
        about_episodes=round(rules.about_episodes * factor), acceptable=rules.acceptable * factor)


def bootstrap(rules: ReportConfig) -> stats.Bootstrap:
    return stats.Bootstrap(rules.level, rules.resamples, rules.seed)


def beats(a: list[float], b: list[float] | float, margin: float, boot: stats.Bootstrap) -> tuple[bool, dict]:
    """Whether A beats B by more than ``margin``: the interval of mean(A) − mean(B) lies above it."""
    d = stats.difference([a], [b], boot)
    lower = d["lo"] if d["lo"] == d["lo"] else d["delta"]
    return lower > margin, d


def claims(summary: dict, config: str, regions: list[str], rules: ReportConfig, factor: float = 1.0) -> list[Claim]:
    """SPEC §10's claims for one configuration, each judged by its rule (margins and tolerances × ``factor``)."""
    runs, base = summary["runs"], summary["baselines"]
    r, boot = scaled(rules, factor), bootstrap(rules)

    def get(method, region):
        return runs.get(Cell(config, method, region).key)

    out = []
    cr, sw = get("cr", "rectangle"), get("sw", "rectangle")
    if cr and sw:
        tol = str(factor) if str(factor) in cr.get("convergence_by_tolerance", {}) else None
        cr_ep = cr["convergence_by_tolerance"][tol] if tol else cr["convergence_episode"]
        sw_ep = sw["convergence_by_tolerance"][tol] if tol else sw["convergence_episode"]
        cr_ok = sum(e is not None and abs(e - 5000) <= r.about_episodes for e in cr_ep) / len(cr_ep)
        sw_ok = sum(e is None or e > r.not_converged_after for e in sw_ep) / len(sw_ep)
        holds = [cr_ok > r.majority, sw_ok > r.majority]
        out.append(Claim(
            "1. CR-MARL converges on the rectangle in about 5,000 episodes; SW-MARL has not converged by 10,000",
            f"more than {r.majority:.0%} of CR's seeds converge within 5,000 ± {r.about_episodes:,} episodes and "
            f"more than {r.majority:.0%} of SW's not before {r.not_converged_after:,} (SPEC §8 convergence, band "
            f"{factor:g} × `evaluate.converge_tolerance`); both → reproduced, one → partly",
            REPRODUCED if all(holds) else PARTLY if any(holds) else NOT,
            f"convergence episode per seed (None = not converged): CR {cr_ep}, SW {sw_ep}"))
    holds, ev = [], []
    for region in ("rectangle", "square"):
        cr, sw = get("cr", region), get("sw", region)
        if cr and sw:
            ok, d = beats(cr["nearest_neighbour_per_seed"], sw["nearest_neighbour_per_seed"], r.spread_margin, boot)
            holds.append(ok)
            ev.append(f"{region}: Δ nearest neighbour CR − SW {fmt_delta(d)} m")
    if holds:
        out.append(Claim(
            "2. CR-MARL spreads the agents more than SW-MARL (rectangle and square)",
            f"per region, the {r.level:.0%} interval of Δ mean nearest-neighbour distance (CR − SW, over seeds) "
            f"lies above {r.spread_margin:.3f} m; {rule_over_cells(r)}",
            over_cells(holds, r.partly), "; ".join(ev)))
    for baseline, tuned_note in (("naive_tuned", "tuned naive swarming"), ("naive", "hand-set naive swarming")):
        holds, ev = [], []
        for region in regions:
            b = base.get(f"{baseline}/{region}", {}).get("coverage")
            for method in ("sw", "cr"):
                run = get(method, region)
                if run and b is not None:
                    ok, d = beats(run["coverage_per_seed"], b, r.margin, boot)
                    holds.append(ok)
                    ev.append(f"{method.upper()} {region} {fmt(run['coverage'])} vs {b:.3f}: Δ {fmt_delta(d)}")
        if holds:
            judged = baseline == "naive_tuned"
            out.append(Claim(
                "3. Both MARL methods beat naive swarming (coverage)" + ("" if judged else
                                                                          ", against the paper's hand-set gains"),
                f"per method and region, the {r.level:.0%} interval of Δ coverage (MARL − {tuned_note}) lies above "
                f"{r.margin:+.3f}; {rule_over_cells(r)}" + ("" if judged else " (for reference; the verdict is "
                                                              "the tuned baseline's)"),
                over_cells(holds, r.partly), "; ".join(ev)))
    holds, ev = [], []
    ceiling = None
    for region in regions:
        ceiling = base.get(f"lloyd/{region}", {}).get("ceiling")
        for method in ("sw", "cr"):
            run = get(method, region)
            if run and ceiling:
                lower = run["coverage"]["lo"] if run["coverage"]["lo"] == run["coverage"]["lo"] else \
                    run["coverage"]["mean"]
                holds.append(lower >= r.acceptable * ceiling)
                ev.append(f"{method.upper()} {region} {fmt(run['coverage'])}")
    if holds:
        out.append(Claim(
            "4. Both give 'acceptable' coverage of every region",
            f"per method and region, the lower end of the {r.level:.0%} interval of mean coverage is at least "
            f"{r.acceptable:.0%} of the ceiling ({r.acceptable * ceiling:.3f}); {rule_over_cells(r)}",
            over_cells(holds, r.partly), "; ".join(ev)))
    return out


def rule_over_cells(r: ReportConfig) -> str:
    return f"every cell → reproduced, at least {r.partly:.0%} of them → partly"


def sensitivity(summary: dict, config: str, regions: list[str], rules: ReportConfig) -> list[str]:
    """Per claim, its verdicts with the margins and tolerances × each factor of ``report.sensitivity``, and
    whether the verdict moves with them."""
    main = [c.verdict for c in claims(summary, config, regions, rules)]
    per_factor = {f: [c.verdict for c in claims(summary, config, regions, rules, f)] for f in rules.sensitivity}
    cells = []
    for i, v in enumerate(main):
        alt = [f"{f:g}×: {per_factor[f][i]}" for f in rules.sensitivity]
        moves = any(per_factor[f][i] != v for f in rules.sensitivity)
        cells.append("; ".join(alt) + (" — **moves**" if moves else " — stable"))
    return cells


COMPARISONS = (  # (A, B) cells compared on every region: what each headline claim rests on
    (("tuned", "cr"), ("paper", "cr")),
    (("tuned", "cr"), ("tuned", "sw")),
    (("paper", "cr"), ("paper", "sw")),
    (("tuned", "cr"), "naive_tuned"),
    (("tuned", "cr"), "lloyd_tuned"),
    (("tuned", "sw"), "naive_tuned"),
)


def comparisons(summary: dict, regions: list[str], rules: ReportConfig) -> list[str]:
    """Markdown rows: per comparison and region (and over all regions, a stratified bootstrap), Δ coverage with
    its interval, the probability of improvement with its interval, and the reading under ``report.margin``."""
    runs, base, boot = summary["runs"], summary["baselines"], bootstrap(rules)
    rows = []
    for a, b in COMPARISONS:
        name_b = b if isinstance(b, str) else f"{b[0]} {b[1].upper()}"
        a_vals, b_vals, used = [], [], []
        for region in regions:
            ra = runs.get(Cell(*a, region).key)
            if isinstance(b, str):
                vb = base.get(f"{b}/{region}", {}).get("coverage")
            else:
                rb = runs.get(Cell(*b, region).key)
                vb = rb["coverage_per_seed"] if rb else None
            if ra is None or vb is None:
                continue
            a_vals.append(ra["coverage_per_seed"])
            b_vals.append(vb)
            used.append(region)
        for label, av, bv in [*((reg, [x], [y]) for reg, x, y in zip(used, a_vals, b_vals)),
                              *((("all regions", a_vals, b_vals),) if len(used) > 1 else ())]:
            d = stats.difference(av, bv, boot)
            p = stats.probability_of_improvement(av, bv, boot)
            lower, upper = (d["lo"], d["hi"]) if d["lo"] == d["lo"] else (d["delta"], d["delta"])
            reading = ("A better" if lower > rules.margin else "B better" if upper < -rules.margin
                       else "no measurable difference")
            rows.append(f"| {a[0]} {a[1].upper()} | {name_b} | {label} | {fmt_delta(d)} | {fmt_p(p)} | {reading} |")
    return rows


def cpu_timed(runs: list[dict]) -> bool:
    """Whether every run's time is its CPU time (``train.timed_by``): a wall time shared with other work on the
    machine is not one core's, and no time bar is judged on it."""
    return bool(runs) and all(r.get("timed_by") == "cpu" for r in runs)


def targets(summary: dict, timing: dict, rules: ReportConfig, config: str = "tuned",
            method: str = "cr") -> list[tuple]:
    """(region, bar, per-seed coverage, naive_tuned, seconds, verdict) rows of the targets of ``config``/``method``:
    every seed at or above the bar and above tuned naive swarming, every run within ``target_seconds``."""
    rows = []
    for region, target in rules.targets.items():
        r = summary["runs"].get(Cell(config, method, region).key)
        naive = summary["baselines"].get(f"naive_tuned/{region}", {}).get("coverage")
        if r is None or naive is None:
            continue
        if target.of:
            ref = summary["baselines"][f"{target.of}/{region}"]["coverage"]
            bar, text = target.at_least * ref, f"≥ {target.at_least:.0%} of {target.of} = {target.at_least * ref:.3f}"
        else:
            bar, text = target.at_least, f"≥ {target.at_least:.2f}"
        seeds = r["coverage_per_seed"]
        cell_runs = [t for t in timing.get("runs", [])
                     if Cell(t["config"], t["method"], t["region"]) == Cell(config, method, region)]
        walls = [t["core_seconds"] for t in cell_runs]
        misses = []
        if min(seeds) < bar:
            misses.append(f"coverage: {sum(s < bar for s in seeds)} of {len(seeds)} seeds below, worst "
                          f"{min(seeds):.3f}, {bar - min(seeds):.3f} short")
        if min(seeds) <= naive:
            misses.append(f"naive_tuned: {sum(s <= naive for s in seeds)} of {len(seeds)} seeds ≤ {naive:.3f}")
        if walls and max(walls) > rules.target_seconds and cpu_timed(cell_runs):
            misses.append(f"time: {max(walls):.0f} s > {rules.target_seconds:.0f} s")
        rows.append((region, text, seeds, naive, span(walls), "met" if not misses else
                     "missed (" + "; ".join(misses) + ")"))
    return rows


def budgets(rules_params, tuning: dict) -> list[str]:
    """Markdown rows of every search: what it chose, trials or runs, one core's seconds."""
    hs = rules_params.tuning.hand_search
    rows = [f"| `{hs.config}` {hs.method.upper()}-MARL training values | by hand (`docs/TUNING.md`) | "
            f"{hs.configurations} configurations, {hs.runs} runs | {hs.cpu_seconds:,.0f} | {hs.note} |"]
    method = tuning.get("method")
    if method:
        ms = rules_params.tuning.method
        failed = f" (+ {method['failed_trials']} failed)" if method.get("failed_trials") else ""
        incumbent = (f"; the config's own values (a trial) {method['incumbent_coverage']:.3f}"
                     if method.get("incumbent_coverage") is not None else "")
        rows.append(f"| `{ms.config}` {ms.method.upper()}-MARL training values | Optuna TPE `{method['study']}` | "
                    f"{method['trials']} trials{failed} × {len(ms.seeds)} seeds × {ms.episodes:,} episodes on "
                    f"{', '.join(ms.regions)} | {method['cpu_seconds']:,.0f} | best tuning coverage "
                    f"{method['tuning_coverage']:.3f}{incumbent} |")
    for key, b in sorted(tuning.get("baselines", {}).items()):
        gains = ", ".join(f"{k} {v:.3g}" for k, v in b["gains"].items())
        rows.append(f"| {key} gains | Optuna TPE `{b['study']}` | {b['trials']} trials | {b['cpu_seconds']:,.0f} | "
                    f"{gains}; tuning coverage {b['tuning_coverage']:.3f} |")
    for key, b in sorted(tuning.get("general_baselines", {}).items()):
        gains = ", ".join(f"{k} {v:.3g}" for k, v in b["gains"].items())
        rows.append(f"| {key} gains for every lake | Optuna TPE `{b['study']}` on the general policy's training "
                    f"worlds | {b['trials']} trials | {b['cpu_seconds']:,.0f} | {gains}; tuning coverage "
                    f"{b['tuning_coverage']:.3f} |")
    return rows


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


def robustness_rows(summary: dict, regions: list[str], scenarios: list[str]) -> list[str]:
    """Markdown rows of the robustness table, one column per scenario: runs as mean [CI] over seeds, baselines
    as one value each (deterministic, same starts)."""
    rows = []
    for region in regions:
        for key, r in summary["runs"].items():
            cell = Cell.parse(key)
            if cell.region == region and r.get("robustness"):
                rows.append(f"| {region} | {cell.config} {cell.method.upper()}-MARL | "
                            + " | ".join(fmt(r["robustness"][s]["coverage"]) for s in scenarios) + " |")
        for name in ("naive", "naive_tuned", "lloyd", "lloyd_tuned"):
            b = summary["baselines"].get(f"{name}/{region}", {}).get("robustness")
            if b and set(scenarios) <= set(b):
                rows.append(f"| {region} | {name} | " + " | ".join(f"{b[s]:.3f}" for s in scenarios) + " |")
    return rows


def ablation_effect(delta: dict) -> str:
    """The reading of an ablation row's Δ (with − without): an interval that contains 0 (or none) has no
    measurable effect; above 0 the change helps, below it hurts."""
    lo, hi = delta["lo"], delta["hi"]
    return "no measurable effect" if lo != lo or lo <= 0 <= hi else "helps" if lo > 0 else "hurts"


def ablation_rows(summary: dict) -> list[str]:
    lines = []
    for key, r in summary.get("ablation", {}).items():
        change, region = key.split("/")
        keys = ", ".join(f"`{k}`" for k in r["keys"])
        d = r["delta"]
        effect = ablation_effect(d)
        lines.append(f"| `{change}` | {keys} | {region} | {fmt(r['with'])} | {fmt(r['without'])} | "
                     f"{fmt_delta(d)} | {effect} | {r['with_per_seed']} | {r['without_per_seed']} |")
    return lines


def seeds_section(params) -> list[str]:
    t, ev, tc = params.train, params.evaluate, params.tuning
    lines = ["## Seeds", "", "Reported numbers use seeds and starts that chose nothing; searches use others.", "",
             "| what | seeds |", "|---|---|"]
    for config, seeds in t.seeds.items():
        lines.append(f"| `{config}` reported runs, training seeds | {', '.join(map(str, seeds))} |")
    lines += [f"| every reported evaluation (SPEC §8 and robustness) | starts from seed {ev.seed} |",
              f"| `{tc.method.config}` {tc.method.method.upper()}-MARL search, training seeds | "
              f"{', '.join(map(str, tc.method.seeds))} |",
              f"| every search's evaluation starts | seed {tc.starts_seed} |",
              f"| the hand search of `{tc.hand_search.config}` | {tc.hand_search.note} |",
              f"| the ablation | {', '.join(map(str, params.ablation.seeds))} (the first `tuned` seeds) |", ""]
    return lines


def missing_runs(params, summary: dict) -> list[str]:
    """Cells of the matrix (``pipeline`` × ``train.seeds``) with fewer evaluated seeds than params.yaml asks for,
    as "CELL: n of N seeds"."""
    matrix = params.stages.get("pipeline", {})
    out = []
    for config in matrix.get("configs", []):
        for method in matrix.get("methods", []):
            for region in matrix.get("regions", []):
                cell = Cell(config, method, region)
                want = params.train.seeds_of(config)
                have = summary["runs"].get(cell.key, {}).get("seeds", [])
                if set(want) - set(have):
                    out.append(f"`{cell.key}`: {len(set(have) & set(want))} of {len(want)} seeds")
    return out


def arithmetic_line(runs: list[dict]) -> str:
    """Which arithmetic (``replicate.learn.fingerprint.fingerprint``) trained the runs: one fingerprint means every
    run is reproducible bit for bit by the same code, libraries and CPU."""
    counts = Counter(r.get("arithmetic") or "not recorded" for r in runs)
    kinds = ", ".join(f"`{k}` ({n} run{'s' * (n != 1)})" for k, n in counts.most_common())
    if len(counts) == 1 and "not recorded" not in counts:
        return (f"Arithmetic: all {len(runs)} runs were trained by the same arithmetic, fingerprint "
                f"`{next(iter(counts))}` (`replicate.learn.fingerprint`: the numbers a fixed workload gives with this "
                "code, libraries and CPU).")
    return (f"Arithmetic: the runs carry {len(counts)} fingerprints, {kinds}: runs of different fingerprints were "
            "trained by code, libraries or CPUs that round differently, and a rerun reproduces only its own kind "
            "bit for bit (`replicate.learn.fingerprint`).")


def write_report(params, summary_path: str, timing_path: str, tuning_paths: dict[str, str], figures: list[str],
                 out: str, stage_times: dict, general_path: str | None = None) -> str:
    summary = json.loads(Path(summary_path).read_text())
    general = json.loads(Path(general_path).read_text()) if general_path and Path(general_path).exists() else None
    timing = json.loads(Path(timing_path).read_text()) if Path(timing_path).exists() else {}
    tuning = {k: json.loads(Path(p).read_text()) for k, p in tuning_paths.items() if Path(p).exists()}
    rules = params.report
    cells = [Cell.parse(k) for k in summary["runs"]]
    regions = [r for r in params.regions if r in {c.region for c in cells} |
               {k.split("/")[1] for k in summary["baselines"]}]
    configs = sorted({c.config for c in cells})
    lines = ["# REPORT: buoy-swarm coverage, replication of Kouzehgar et al.", "",
             "Generated by the pipeline's `report` stage from `metrics/summary.json`; do not edit by hand.",
             "Coverage is the SPEC §8 fraction A((∪ Cov) ∩ Reg) / A(Reg) at the last step, deterministic policy, "
             f"{params.evaluate.episodes} evaluation episodes per run; intervals are {rules.level:.0%} percentile "
             "bootstraps over training seeds (`scipy.stats.bootstrap`, stratified by region where regions are "
             "pooled). Every rule below is `params.yaml` `report`, fixed before the numbers; the sensitivity "
             "column repeats the verdict with every margin and tolerance × "
             f"{' and × '.join(map(str, rules.sensitivity))}.",
             ""]
    missing = missing_runs(params, summary)
    if missing:
        lines += ["**Incomplete: the training matrix is not finished.** These cells have fewer evaluated runs than "
                  "`train.seeds` asks for, and every statement below about them rests on the runs there are: "
                  + "; ".join(missing) + ". `dvc repro` trains the missing runs (finished ones are kept).", ""]
    lines += seeds_section(params)
    for config in configs:
        lines += [f"## The paper's claims — `{config}` configuration", "",
                  "| claim | rule | verdict | sensitivity | evidence |", "|---|---|---|---|---|"]
        for c, sens in zip(claims(summary, config, regions, rules), sensitivity(summary, config, regions, rules)):
            lines.append(f"| {c.claim} | {c.rule} | **{c.verdict}** | {sens} | {c.evidence} |")
        lines.append("")
    rows = comparisons(summary, regions, rules)
    if rows:
        lines += ["## Headline comparisons", "",
                  f"Δ = mean coverage of A − of B with its {rules.level:.0%} interval; P(A > B) is the chance that a "
                  "seed of A beats a seed of B (a baseline is one number per region), with its interval. A reading "
                  f"needs the interval of Δ clear of ±{rules.margin:.3f} (`report.margin`).", "",
                  "| A | B | region | Δ coverage | P(A > B) | reading |", "|---|---|---|---|---|---|", *rows, ""]
    trows = targets(summary, timing, rules)
    if trows:
        lines += ["## Targets of `tuned` CR-MARL", "",
                  "Every seed must meet the coverage bar (`report.targets`) and beat tuned naive swarming, within "
                  f"{rules.target_seconds:.0f} s of one core per 10,000-episode run (a run's share of the process "
                  "that trained its cell's seeds together).", "",
                  "| region | coverage bar | coverage per seed | naive_tuned | one core's s per run | verdict |",
                  "|---|---|---|---|---|---|"]
        for region, text, seeds, naive, wall, v in trows:
            lines.append(f"| {region} | {text} | {seeds} | {naive:.3f} | {wall} | **{v}** |")
        if timing and not cpu_timed(timing.get("runs", [])):
            lines.append("\nRuns that recorded only their wall time (`timed_by: wall` in `runs/summary.json`) "
                         "may have shared a core with other work, so their times are not one core's; the time bar "
                         "is judged only on runs timed by their CPU time.")
        lines.append("")
    lines += ["## Search budgets", "",
              "Each search's trials (or runs) and one core's CPU seconds, on the seeds and starts of the Seeds table.",
              "", "| what was chosen | how | trials | CPU s | result |", "|---|---|---|---|---|",
              *budgets(params, tuning), ""]
    scenarios = list(params.evaluate.robustness)
    rrows = robustness_rows(summary, regions, scenarios)
    if rrows:
        spec = params.evaluate.robustness
        lines += ["## Robustness", "",
                  "The same policies and baselines from other starts and over longer horizons, and after losing "
                  "buoys (coverage of the remaining ones), all from the evaluation seed: "
                  + "; ".join(f"`{n}` = {s.start} start, {s.horizon:g} T" + (f", {s.lose} lost at half time"
                                                                              if s.lose else "")
                              for n, s in spec.items()) + ".", "",
                  "| region | policy | " + " | ".join(f"`{s}`" for s in scenarios) + " |",
                  "|---|---|" + "---|" * len(scenarios), *rrows, ""]
    if general is not None:
        lines += general_section(params, general, summary)
    ab = ablation_rows(summary)
    lines += ["## Ablation of `tuned` (leave one out)", ""]
    if ab:
        lines += ["Each row trains `tuned` with one change reverted to the `paper` value (`params.yaml` "
                  f"`ablation`), seeds {', '.join(map(str, params.ablation.seeds))}; Δ = with − without with its "
                  f"{rules.level:.0%} interval. A row whose interval contains 0 has no measurable effect. "
                  "`checkpoint_selection` needs no run of its own: it evaluates the last actors of the `tuned` "
                  "runs themselves.", "",
                  "| change | keys | region | with | without | Δ | effect | with, per seed | "
                  "without, per seed |", "|---|---|---|---|---|---|---|---|---|", *ab, ""]
    else:
        lines += ["No ablation runs in `runs/`: they are an experiment on top of the pipeline, "
                  "`dvc exp run -S pipeline.ablation=true` trains and reports them.", ""]
    lines += ["## Coverage", "", "| config | method | region | seeds | coverage | IQM | per seed | "
              "nearest neighbour (m) | fraction inside | convergence episode |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for key, r in summary["runs"].items():
        c = Cell.parse(key)
        iqm = r["coverage"].get("iqm", math.nan)
        lines.append(f"| {c.config} | {c.method.upper()}-MARL | {c.region} | {len(r['seeds'])} | {fmt(r['coverage'])} "
                     f"| {iqm:.3f} | {r['coverage_per_seed']} | {fmt(r['nearest_neighbour'])} | "
                     f"{fmt(r['fraction_inside'])} | {r['convergence_episode']} |")
    lines += ["", "Baselines run the same physics and start; `steps` is the region's episode length T (every run on "
              "that region has the same T), or the converged Lloyd layout's longer run. `naive` and `lloyd` have "
              "the paper's hand-set gains (`evaluate`), `naive_tuned` and `lloyd_tuned` the gains of their "
              "searches (Search budgets).", "",
              "| baseline | region | steps | coverage | nearest neighbour (m) | fraction inside | ceiling |",
              "|---|---|---|---|---|---|---|"]
    for key, b in sorted(summary["baselines"].items()):
        name, region = key.split("/")
        lines.append(f"| {name} | {region} | {b['steps']} | {b['coverage']:.3f} | "
                     f"{b['nearest_neighbour']:.3f} | {b['fraction_inside']:.2f} | {b['ceiling']:.3f} |")
    lines += ["", "## Time", ""]
    if timing:
        runs = timing["runs"]
        cores = [r["core_seconds"] for r in runs]
        kept = sum(r["skipped"] for r in runs)
        stage = (f"the last `train` stage took {timing['wall_seconds']:.0f} s wall and kept {kept} runs already "
                 "finished with identical settings" if timing.get("wall_seconds") is not None else
                 "the runs were trained by separate `train_matrix` calls, not one `train` stage")
        by_wall = sum(r.get("timed_by") != "cpu" for r in runs)
        if by_wall:
            stage += (f"; {by_wall} runs recorded only their wall time, which work beside them on the machine "
                      "inflates")
        lines.append(f"Training: {len(runs)} runs, {sum(cores):.0f} s of one core's time in all ({span(cores)} s "
                     "per run; a cell's seeds train together in one process, and a run counts its share of that "
                     f"process's CPU time, or of its wall time where it recorded only that); {stage}.")
    for stage, seconds in stage_times.items():
        lines.append(f"- `{stage}`: {seconds:.0f} s")
    if timing:
        lines += ["", arithmetic_line(timing["runs"])]
    lines += ["", "## Figures", ""]
    for path in figures:
        p = Path(path)
        lines.append(f"### {p.stem}\n\n![{p.stem}]({p.as_posix()})\n")
    text = "\n".join(lines) + "\n"
    artifacts.atomic_write_text(out, text)
    return text
