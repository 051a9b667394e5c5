"""The paper's claims (SPEC §10), each judged by its rule, with the verdict under the rule's margins scaled (the
sensitivity column); the headline comparisons; the targets of ``tuned``."""

from __future__ import annotations

from dataclasses import dataclass

from replicate.compare import stats
from replicate.core.params import Cell, RegionKey
from replicate.core.studies import ReportConfig
from replicate.pipeline.report.rules import (
    NOT,
    PARTLY,
    REPRODUCED,
    beats,
    bootstrap,
    fmt,
    fmt_delta,
    fmt_p,
    over_cells,
    scaled,
    span,
)


@dataclass(frozen=True)
class Claim:
    claim: str
    rule: str
    verdict: str
    evidence: str


@dataclass(frozen=True)
class Judge:
    """What every claim of one configuration is judged with: its runs and baselines, the rules scaled by
    ``factor`` (the sensitivity column) and the bootstrap."""

    summary: dict
    config: str
    regions: list[str]
    r: ReportConfig
    boot: object
    factor: float

    def get(self, method: str, region: str) -> dict | None:
        return self.summary["runs"].get(Cell(self.config, method, region).key)

    def baseline(self, name: str, region: str) -> dict:
        return self.summary["baselines"].get(RegionKey(name, region).key, {})


BAND = {"range": "of the moving average's range", "final": "of the final return's size"}
OTHER = {"range": "final", "final": "range", "inside": "all", "all": "inside"}
FIRST_READING = "SPEC §8, the rule before these numbers were read"  # claim 1's band "final"


def convergence_verdict(j: Judge, cr: dict, sw: dict, band: str) -> tuple[str, list, list]:
    """Claim 1's verdict with the convergence band ``band`` (at the judge's tolerance factor) → (verdict, CR's
    and SW's convergence episode per seed)."""
    r, by = j.r, (lambda run: run["convergence_by_tolerance"][band])
    cr_ep, sw_ep = (by(run).get(str(j.factor), by(run)["1.0"]) for run in (cr, sw))
    cr_ok = sum(e is not None and abs(e - 5000) <= r.about_episodes for e in cr_ep) / len(cr_ep)
    sw_ok = sum(e is None or e > r.not_converged_after for e in sw_ep) / len(sw_ep)
    holds = [cr_ok > r.majority, sw_ok > r.majority]
    return REPRODUCED if all(holds) else PARTLY if any(holds) else NOT, cr_ep, sw_ep


def claim_convergence(j: Judge) -> list[Claim]:
    r, factor = j.r, j.factor
    cr, sw = j.get("cr", "rectangle"), j.get("sw", "rectangle")
    if not (cr and sw):
        return []
    verdict, cr_ep, sw_ep = convergence_verdict(j, cr, sw, r.convergence_band)
    other = OTHER[r.convergence_band]
    was, cr_was, sw_was = convergence_verdict(j, cr, sw, other)
    return [Claim(
        "1. CR-MARL converges on the rectangle in about 5,000 episodes; SW-MARL has not converged by 10,000",
        f"more than {r.majority:.0%} of CR's seeds converge within 5,000 ± {r.about_episodes:,} episodes and "
        f"more than {r.majority:.0%} of SW's not before {r.not_converged_after:,} (SPEC §8 convergence, a band of "
        f"{factor:g} × `evaluate.converge_tolerance` {BAND[r.convergence_band]}, `report.convergence_band`); both → "
        "reproduced, one → partly",
        verdict,
        f"convergence episode per seed (None = not converged): CR {cr_ep}, SW {sw_ep}. With the band "
        f"{BAND[other]} ({FIRST_READING if other == 'final' else 'the other reading'}): {was}, CR {cr_was}, "
        f"SW {sw_was}; "
        "a band of the final return's size is near 0 for SW, whose return ends near 0 after starting at −180,064, "
        "and wide for CR, whose constant inside bonus dominates its return")]


SPREAD = {"inside": ("nearest_neighbour_inside_per_seed", "among the agents inside the region"),
          "all": ("nearest_neighbour_per_seed", "over every agent")}


def spread_verdict(j: Judge, spread: str) -> tuple[str, list[str]]:
    """Claim 2's verdict with the spread ``spread`` (``SPREAD``) → (verdict, evidence per region)."""
    key, holds, ev = SPREAD[spread][0], [], []
    for region in ("rectangle", "square"):
        cr, sw = j.get("cr", region), j.get("sw", region)
        if cr and sw and key in cr and key in sw:
            measured = {m: [v for v in run[key] if v is not None] for m, run in (("CR", cr), ("SW", sw))}
            short = [m for m, v in measured.items() if len(v) < 2]
            if short:  # the agents inside: fewer than two in every episode of a seed measure no spread there
                ev.append(f"{region}: not measurable ({' and '.join(short)}: fewer than two agents inside in "
                          "every episode of all but at most one seed)")
                continue
            ok, d = beats(measured["CR"], measured["SW"], j.r.spread_margin, j.boot)
            holds.append(ok)
            inside = "" if "fraction_inside" not in cr else (
                f" (fully inside: CR {cr['fraction_inside']['mean']:.3f}, SW {sw['fraction_inside']['mean']:.3f})")
            if spread == "inside" and "nearest_neighbour_inside_episodes" in sw:
                inside += (f"; episodes measured (two or more agents inside), every seed's: CR "
                           f"{sum(cr['nearest_neighbour_inside_episodes'])}, SW "
                           f"{sum(sw['nearest_neighbour_inside_episodes'])}")
            ev.append(f"{region}: Δ CR − SW {fmt_delta(d)} m{inside}")
    return (over_cells(holds, j.r.partly) if holds else ""), ev


def claim_spread(j: Judge) -> list[Claim]:
    r = j.r
    verdict, ev = spread_verdict(j, r.spread)
    if not ev:
        return []
    other = OTHER[r.spread]
    was, ev_was = spread_verdict(j, other)
    return [Claim(
        "2. CR-MARL spreads the agents more than SW-MARL (rectangle and square)",
        f"per region, the {r.level:.0%} interval of Δ mean nearest-neighbour distance {SPREAD[r.spread][1]} (CR − "
        f"SW, over seeds; `report.spread`) lies above {r.spread_margin:.3f} m; {rule_over_cells(r)}",
        verdict, "; ".join(ev) + (f". {SPREAD[other][1].capitalize()}"
                                  + (" (the rule before these numbers were read)" if other == "all" else "")
                                  + f": {was}, " + "; ".join(ev_was) +
                                  "; agents that leave the region lengthen the distance over every agent without "
                                  "spreading over the region" if ev_was else ""))]


def claims_beat_naive(j: Judge) -> list[Claim]:
    r, out = j.r, []
    for baseline, tuned_note in (("naive_tuned", "tuned naive swarming"), ("naive", "hand-set naive swarming")):
        holds, ev = [], []
        for region in j.regions:
            b = j.baseline(baseline, region).get("coverage")
            for method in ("sw", "cr"):
                run = j.get(method, region)
                if run and b is not None:
                    ok, d = beats(run["coverage_per_seed"], b, r.margin, j.boot)
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
    return out


def claim_acceptable(j: Judge) -> list[Claim]:
    r, holds, ev, ceiling = j.r, [], [], None
    for region in j.regions:
        ceiling = j.baseline("lloyd", region).get("ceiling")
        for method in ("sw", "cr"):
            run = j.get(method, region)
            if run and ceiling:
                lower = run["coverage"]["lo"] if run["coverage"]["lo"] == run["coverage"]["lo"] else \
                    run["coverage"]["mean"]
                holds.append(lower >= r.acceptable * ceiling)
                ev.append(f"{method.upper()} {region} {fmt(run['coverage'])}")
    if not holds:
        return []
    return [Claim(
        "4. Both give 'acceptable' coverage of every region",
        f"per method and region, the lower end of the {r.level:.0%} interval of mean coverage is at least "
        f"{r.acceptable:.0%} of the ceiling ({r.acceptable * ceiling:.3f}); {rule_over_cells(r)}",
        over_cells(holds, r.partly), "; ".join(ev))]


def claims(summary: dict, config: str, regions: list[str], rules: ReportConfig, factor: float = 1.0) -> list[Claim]:
    """SPEC §10's claims for one configuration, each judged by its rule (margins and tolerances × ``factor``)."""
    j = Judge(summary, config, regions, scaled(rules, factor), bootstrap(rules), factor)
    return claim_convergence(j) + claim_spread(j) + claims_beat_naive(j) + claim_acceptable(j)


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
                vb = base.get(RegionKey(b, region).key, {}).get("coverage")
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
            ref = summary["baselines"][RegionKey(target.of, region).key]["coverage"]
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
