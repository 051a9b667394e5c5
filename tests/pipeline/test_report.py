"""REPORT.md logic on a synthetic summary: each claim's rule and verdict, the sensitivity column, the targets
against the tuned baselines, the comparisons, the ablation's reading, and the README's numbers."""

from __future__ import annotations

import dataclasses
import json
import re

from replicate.compare import stats
from replicate.pipeline.evaluation import split_ablation
from replicate.pipeline.report.claims import claims, comparisons, sensitivity, targets
from replicate.pipeline.report.rules import span
from replicate.pipeline.report.tables import arithmetic_line
from replicate.pipeline.report.write import write_report

from ..conftest import ROOT


def group(per_seed, nn=0.8, conv=(5000, 5000, 5000), seeds=None):
    n = len(per_seed)
    return {
        "seeds": list(seeds if seeds is not None else range(n)),
        "coverage": stats.mean_interval(per_seed),
        "coverage_per_seed": list(per_seed),
        "nearest_neighbour": stats.mean_interval([nn] * n),
        "nearest_neighbour_per_seed": [nn + 0.001 * k for k in range(n)],
        "nearest_neighbour_inside_per_seed": [nn + 0.001 * k for k in range(n)],
        "fraction_inside": stats.mean_interval([1.0] * n),
        "convergence_episode": list(conv),
        "convergence_by_tolerance": {band: {"1.0": list(conv), "0.5": list(conv), "2.0": list(conv)}
                                     for band in ("range", "final")},
        "core_seconds": stats.mean_interval([100.0] * n),
        "robustness": {},
    }


def summary(params):
    base = {f"{b}/{r}": {"coverage": c, "nearest_neighbour": 0.7, "fraction_inside": 1.0, "ceiling": 0.78,
                        "steps": 50}
            for r in ("square", "rectangle", "bedok")
            for b, c in (("naive", 0.5), ("lloyd", 0.7), ("naive_tuned", 0.71), ("lloyd_tuned", 0.74))}
    runs = {
        "tuned/cr/square": group([0.72, 0.74, 0.75]),
        "tuned/cr/rectangle": group([0.72, 0.69, 0.75]),  # one seed below the 0.70 bar
        "tuned/cr/bedok": group([0.68, 0.69, 0.70]),  # >= 0.9 x lloyd_tuned (0.666)
        "tuned/sw/square": group([0.3, 0.31, 0.32], nn=0.5),
        "tuned/sw/rectangle": group([0.3, 0.31, 0.32], nn=0.5, conv=(None, None, None)),
    }
    for change in params.ablation.changes:
        runs[f"tuned-without-{change}/cr/square"] = group([0.5, 0.6, 0.55])
    return {"runs": runs, "baselines": base}


def ablated(params):
    """The synthetic summary's ablation split, with the base runs on the ablation's seeds."""
    s = summary(params)
    s["runs"]["tuned/cr/square"]["seeds"] = list(params.ablation.seeds[:3])
    return split_ablation(s, params)


def test_ablation_rows_leave_the_coverage_table(params):
    out = ablated(params)
    assert not [k for k in out["runs"] if "-without-" in k]
    assert set(out["ablation"]) == {f"{c}/square" for c in params.ablation.changes}
    row = out["ablation"]["geofence/square"]
    assert row["keys"] == ["geofence"] and abs(row["delta"]["delta"] - (0.7366667 - 0.55)) < 1e-6
    assert row["delta"]["lo"] <= row["delta"]["delta"] <= row["delta"]["hi"]


def test_targets_are_judged_against_the_tuned_baselines(params):
    timing = {"wall_seconds": 1000.0, "runs": [{"config": "tuned", "method": "cr", "region": r, "core_seconds": w,
                                                "timed_by": "cpu"}
                                               for r, w in (("square", 170.0), ("rectangle", 175.0), ("bedok", 200.0))]}
    rows = {r[0]: r for r in targets(ablated(params), timing, params.report)}
    assert rows["square"][-1] == "met"  # every seed above 0.70 and above naive_tuned's 0.71
    assert rows["rectangle"][-1].startswith("missed (coverage: 1 of 3 seeds below, worst 0.690, 0.010 short")
    assert "naive_tuned: 1 of 3 seeds ≤ 0.710" in rows["rectangle"][-1]  # 0.69 is not above it
    assert "time: 200 s > 180 s" in rows["bedok"][-1] and "0.666" in rows["bedok"][1]
    assert rows["square"][4] == "170"  # one run's time, or one stack's runs sharing it, is one number
    by_wall = {**timing, "runs": [{**r, "timed_by": "wall"} for r in timing["runs"]]}
    outside = {r[0]: r for r in targets(ablated(params), by_wall, params.report)}
    assert "time" not in outside["bedok"][-1], "a wall time shared with other work has no time verdict"


def test_span_of_seconds():
    assert span([]) == "—" and span([63.2, 62.9]) == "63" and span([118.0, 133.4]) == "118-133"


def test_claims_follow_their_rules(params):
    s = ablated(params)
    verdicts = {c.claim[:2]: c.verdict for c in claims(s, "tuned", ["square", "rectangle", "bedok"], params.report)}
    assert verdicts["1."] == "reproduced"  # CR converges at 5,000 on every seed, SW never
    assert verdicts["2."] == "reproduced"  # CR's nearest-neighbour distance 0.3 m above SW's on both regions
    three = [c for c in claims(s, "tuned", ["square", "rectangle", "bedok"], params.report) if c.claim[:2] == "3."]
    assert three[0].verdict == "not reproduced"  # against naive_tuned (0.71) neither method clears the margin
    assert three[1].verdict == "partly"  # against the hand-set 0.5, CR does on three of six cells
    assert "+0.010" in three[0].rule and "naive_tuned" not in three[0].rule  # the rule, in words, with its margin


def test_a_verdict_on_its_threshold_moves_in_the_sensitivity_column(params):
    s = ablated(params)
    s["runs"]["tuned/cr/rectangle"]["convergence_episode"] = [7400, 7400, 7400]  # inside 5,000 ± 2,500
    for f in ("1.0", "0.5", "2.0"):
        s["runs"]["tuned/cr/rectangle"]["convergence_by_tolerance"]["range"][f] = [7400, 7400, 7400]
    regions = ["square", "rectangle", "bedok"]
    assert claims(s, "tuned", regions, params.report)[0].verdict == "reproduced"
    first = sensitivity(s, "tuned", regions, params.report)[0]
    assert "0.5×: partly" in first and "**moves**" in first  # ± 1,250 no longer holds 7,400
    stable = dataclasses.replace(params.report, about_episodes=5000)  # halved, ± 2,500 still holds 7,400
    assert "stable" in sensitivity(s, "tuned", regions, stable)[0]


def test_comparisons_give_intervals_of_differences_and_probabilities(params):
    rows = comparisons(ablated(params), ["square", "rectangle", "bedok"], params.report)
    cr_sw = [r for r in rows if r.startswith("| tuned CR | tuned SW | square |")]
    assert cr_sw and "A better" in cr_sw[0] and "1.00" in cr_sw[0]
    pooled = [r for r in rows if "| tuned CR | naive_tuned | all regions |" in r]
    assert pooled, "a pooled row across regions"


def test_report_text_states_rules_budgets_and_seeds(params, tmp_path):
    s = ablated(params)
    (tmp_path / "summary.json").write_text(json.dumps(s))
    tuning = {"baselines": {"naive/square": {"gains": {"attraction": 2.0}, "tuning_coverage": 0.77, "trials": 150,
                                             "cpu_seconds": 40.0, "study": "naive-square-x"}}}
    (tmp_path / "baselines.json").write_text(json.dumps(tuning["baselines"]))
    (tmp_path / "method.json").write_text(json.dumps({"study": "m", "trials": 12, "cpu_seconds": 1034.0,
                                                      "tuning_coverage": 0.5}))
    text = write_report(params, str(tmp_path / "summary.json"), str(tmp_path / "none.json"),
                        {"baselines": str(tmp_path / "baselines.json"), "method": str(tmp_path / "method.json")}, [],
                        str(tmp_path / "R.md"), {})
    assert "## Ablation of `tuned`" in text and "| `update_schedule` |" in text
    assert "| naive_tuned | square | 50 | 0.710 |" in text  # the baseline table gives each baseline's T
    assert "| naive/square gains | Optuna TPE `naive-square-x` | 150 trials | 40 |" in text
    assert f"{params.tuning.hand_search.configurations} configurations" in text
    assert "compares two searches as well as two methods" in text and "study of 1,034 CPU-s" in text
    assert "| rule | verdict | sensitivity |" in text
    assert str(params.evaluate.seed) in text and "10, 11, 12" in text
    assert (tmp_path / "R.md").read_text() == text


def test_report_without_ablation_runs_says_how_to_run_them(params, tmp_path):
    s = summary(params)
    s["runs"] = {k: v for k, v in s["runs"].items() if "-without-" not in k}
    (tmp_path / "summary.json").write_text(json.dumps(split_ablation(s, params)))
    text = write_report(params, str(tmp_path / "summary.json"), str(tmp_path / "none.json"), {}, [],
                        str(tmp_path / "R.md"), {})
    section = text.split("## Ablation of `tuned`")[1].split("\n## ")[0]
    assert "dvc exp run -S pipeline.ablation=true" in section and "| `geofence` |" not in section


def test_readme_numbers_come_from_the_report():
    """The README carries no result of its own: every decimal number in it is in the generated REPORT.md."""
    readme = (ROOT / "README.md").read_text()
    report = (ROOT / "REPORT.md").read_text()
    numbers = set(re.findall(r"(?<![\w.])0\.\d{2,}(?![\w.])", readme))  # fractions: coverage, Δ, P
    missing = sorted(n for n in numbers if n not in report)
    assert not missing, f"README numbers not in REPORT.md: {missing}"


def test_an_unfinished_matrix_is_named_at_the_top(params, tmp_path):
    s = ablated(params)  # 3 seeds per cell where params.yaml asks for 10 (tuned) and 5 (paper), no paper runs
    (tmp_path / "summary.json").write_text(json.dumps(s))
    text = write_report(params, str(tmp_path / "summary.json"), str(tmp_path / "none.json"), {}, [],
                        str(tmp_path / "R.md"), {})
    head = text.split("## Seeds")[0]
    assert "Incomplete" in head and "`tuned/cr/square`: 3 of 10 seeds" in head and "`paper/sw/bedok`: 0 of 5" in head


def test_the_general_policys_bars_are_counted_per_cell(params):
    """``report.general``: each bar counts the cells that meet it with every seed; one cell short fails the bar;
    the lakes of each kind are counted apart, and the verdict reads the lakes never trained on."""
    from replicate.pipeline.report.general import bar_table, general_section, general_verdicts, over_seeds

    def cell(region, event, general, lloyd, best=0.78, naive=0.7, kind="test"):
        rivals = {"naive_tuned": naive, "lloyd_tuned": lloyd, "geodesic_lloyd": lloyd, "best_layout": best,
                  "decentralised_lloyd": lloyd - 0.05, "upper_bound": 0.9}
        return {"region": region, "n_agents": 9, "start": "corner", "event": event, "max_outside_m": 0.0,
                "steps": 50, "kind": kind,
                "coverage": {"mean": general, "lo": general - 0.01, "hi": general + 0.01, "n": 20},
                "baselines": {k: {"coverage": {"mean": v}} for k, v in rivals.items()}}

    cells = [cell("square", "none", 0.77, 0.775, kind="trained"), cell("square", "lose", 0.50, 0.52, kind="trained"),
             cell("square", "current", 0.70, 0.775, kind="trained"), cell("lake-a", "none", 0.66, 0.60, best=0.67),
             cell("lake-b", "none", 0.60, 0.70, best=0.72), cell("lake-b", "current", 0.67, 0.70, best=0.72),
             cell("bedok", "none", 0.70, 0.70, best=0.72, kind="real")]
    verdicts = {bar: (n, v) for bar, n, v in general_verdicts(cells, params.report.general)}
    assert verdicts["still water: ≥ 98% of lloyd_tuned"] == ("3 of 4", "not met")
    assert verdicts["lakes where lloyd_tuned is ≥ 0.05 below the best layout: above lloyd_tuned"] == ("1 of 1", "met")
    assert verdicts["buoys lost at T/2: ≥ 95% of what lloyd_tuned re-covers"] == ("1 of 1", "met")
    # 0.70 < 0.95 × 0.775
    assert verdicts["drift or vortex: ≥ 95% of lloyd_tuned in the same water"] == ("1 of 2", "not met")
    assert verdicts["drift or vortex: ≥ 90% of its own still-water coverage"] == ("2 of 2", "met")
    seeds = {"s1": {"coverage": {"mean": 0.77}, "max_outside_m": 0.0}, "s2": {"coverage": {"mean": 0.70},
                                                                             "max_outside_m": 0.0}}
    cells[0]["seeds"] = seeds  # one seed of the square below lloyd_tuned: the cell no longer meets the bar
    cells[2]["seeds"] = {"s1": {"coverage": {"mean": 0.70}, "max_outside_m": 0.0},
                         "s2": {"coverage": {"mean": 0.62}, "max_outside_m": 0.0}}  # each against its own still
    verdicts = {bar: (n, v) for bar, n, v in general_verdicts(cells, params.report.general)}
    assert verdicts["still water: ≥ 98% of lloyd_tuned"] == ("2 of 4", "not met")
    # 0.62 < 0.9 × 0.70
    assert verdicts["drift or vortex: ≥ 90% of its own still-water coverage"] == ("1 of 2", "not met")
    cells.append(cell("lake-d", "none", 0.60, 0.70, best=0.72, kind="design"))  # a design lake below the bar
    for c in cells[1:]:
        c.setdefault("seeds", {k: {"coverage": c["coverage"], "max_outside_m": c["max_outside_m"]} for k in seeds})
    table = "\n".join(bar_table(params, cells))
    # trained on: the square only (0 of 1); design: lake-d does not meet it, and is not in the verdict; test:
    # lake-a meets, lake-b does not; real: Bedok meets; a verdict for the test lakes and one for the real lakes
    assert "| still water: ≥ 98% of lloyd_tuned | 0 of 1 | 0 of 1 | 1 of 2 | 1 of 1 | **not met** | **met** |" in table
    assert "test lakes, coverage / lloyd_tuned per seed: s1 mean 0.979, worst 0.857;" in table  # (1.1 + 0.6/0.7) / 2
    assert "real lakes, coverage / lloyd_tuned per seed: s1 mean 1.000, worst 1.000;" in table
    summary = {"runs": {"tuned/cr/square": {"robustness": {"corner": {"coverage": {"mean": 0.74, "lo": 0.73,
                                                                                   "hi": 0.75, "n": 10}}}}}}
    text = "\n".join(general_section(params, {"policy": "policies/general.pt", "cells": cells}, summary))
    seeds_text = over_seeds([0.77, 0.70])
    square = f"| square | 9 | corner | none | 0.770 [0.760, 0.780] | {seeds_text} | 0.740 [0.730, 0.750] |"
    assert square in text and "| bedok | 9 | corner | none |" in text
    assert "| square | 9 | corner | current | 0.700 [0.690, 0.710] |" in text
    assert "| 2 test lakes (mean) | 9 | corner | none |" in text  # lake-a and lake-b pooled
    assert text.index("Trained on") < text.index("Test lakes") < text.index("Real lakes")
    assert over_seeds([0.7, 0.8]) == "0.750 [0.115, 1.385]"  # t with 1 degree of freedom: 12.71 × 0.05


def test_the_report_counts_the_arithmetic_of_its_runs():
    """One fingerprint: every run reproducible by the same code, libraries and CPU. Several, or runs that predate
    the record: the report names each kind and how many runs it trained."""
    same = arithmetic_line([{"arithmetic": "f518c001171e43a2"}] * 3)
    assert "all 3 runs were trained by the same arithmetic, fingerprint `f518c001171e43a2`" in same
    mixed = arithmetic_line([{"arithmetic": "aaaa"}, {"arithmetic": "aaaa"}, {"arithmetic": "bbbb"}, {}])
    assert "3 fingerprints" in mixed and "`aaaa` (2 runs), `bbbb` (1 run), `not recorded` (1 run)" in mixed


def test_claims_one_and_two_say_their_other_reading(params):
    """Claim 1 judged with the band of the curve's range and claim 2 with the agents inside, each with the verdict
    of the other reading beside it: here SW's agents leave the region (far apart over every agent, bunched inside)
    and SW's return converges only within a band of its final value's size."""
    s = ablated(params)
    sw = s["runs"]["tuned/sw/rectangle"]
    sw["nearest_neighbour_per_seed"] = [3.0, 3.0, 3.0]  # far apart over every agent ...
    sw["nearest_neighbour_inside_per_seed"] = [0.1, 0.1, 0.1]  # ... bunched among those inside
    sw["convergence_by_tolerance"]["final"] = {f: [2000, 2000, 2000] for f in ("1.0", "0.5", "2.0")}
    sw["convergence_by_tolerance"]["range"] = {f: [None, None, None] for f in ("1.0", "0.5", "2.0")}
    regions = ["square", "rectangle", "bedok"]
    one, two = claims(s, "tuned", regions, params.report)[:2]
    assert one.verdict == "reproduced"
    assert "of the final return's size (SPEC §8, the rule before these numbers were read): partly" in one.evidence
    assert "inside the region" in two.rule and "rectangle: Δ CR − SW +0.7" in two.evidence
    assert "Over every agent (the rule before these numbers were read): not reproduced" in two.evidence or \
        "Over every agent (the rule before these numbers were read): partly" in two.evidence
    final = dataclasses.replace(params.report, convergence_band="final", spread="all")
    one, two = claims(s, "tuned", regions, final)[:2]
    assert one.verdict == "partly" and "over every agent" in two.rule
    sw["nearest_neighbour_inside_per_seed"] = [None, None, 0.1]  # two of SW's seeds: never two agents inside
    two = claims(s, "tuned", regions, params.report)[1]
    assert "rectangle: not measurable (SW: fewer than two agents inside" in two.evidence
    assert "square: Δ CR − SW" in two.evidence  # judged on the square alone


def test_a_lake_and_fleet_has_one_best_layout_whatever_the_cell():
    """Each cell's search starts from its own policies' final layout too, so two cells of one lake and fleet may
    have found different layouts: the report reads both against the better one, and a cell with fewer buoys in
    service (a loss) against its own."""
    from replicate.pipeline.report.general import one_limit

    def cell(start, event, best, buoys, from_policy=False):
        return {"region": "lake-a", "n_agents": 9, "start": start, "event": event,
                "baselines": {"best_layout": {"coverage": {"mean": best}, "buoys": buoys, "from_policy": from_policy},
                              "lloyd_tuned": {"coverage": {"mean": 0.6}}}}

    cells = [cell("corner", "none", 0.70, 9), cell("random", "none", 0.72, 9, True), cell("corner", "lose", 0.55, 6)]
    limits = [c["baselines"]["best_layout"] for c in one_limit(cells)]
    assert [b["coverage"]["mean"] for b in limits] == [0.72, 0.72, 0.55]
    assert limits[0]["from_policy"] and not limits[2]["from_policy"]
    assert cells[0]["baselines"]["best_layout"]["coverage"]["mean"] == 0.70  # the suite's cells are not changed


def test_the_report_lists_each_compared_change_with_its_verdict():
    """``tried_section``: one row per ``replicate compare`` record, its gain with the interval over seeds, the
    probability of improvement, the rule's bar (a change for speed may lose a little) and whether the rule kept it;
    nothing without records."""
    from replicate.pipeline.report.general import tried_section

    def record(delta, keep, min_gain=0.0):
        return {"verdict": {"difference": {"delta": delta, "lo": delta - 0.01, "hi": delta + 0.01}, "keep": keep,
                            "probability_of_improvement": {"p": 0.5}, "min_gain": min_gain},
                "scores": {**{f"baseline/{s}": 1.0 for s in range(8)}, **{f"candidate/{s}": 1.0 for s in range(8)}}}

    lines = tried_section({"wider": record(0.02, "candidate"), "deeper": record(-0.003, "baseline"),
                           "faster": record(0.01, "candidate", -0.005)})
    rows = [line for line in lines if line.startswith(("| deeper", "| faster", "| wider"))]
    assert rows == ["| deeper | 8 | -0.0030 [-0.0130, +0.0070] | 0.50 | +0.000 | no |",
                    "| faster | 8 | +0.0100 [+0.0000, +0.0200] | 0.50 | -0.005 | yes |",
                    "| wider | 8 | +0.0200 [+0.0100, +0.0300] | 0.50 | +0.000 | yes |"]
    assert tried_section({}) == []
