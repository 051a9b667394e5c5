"""REPORT.md logic on a synthetic summary: the ablation split, the tuned targets and the claims' verdicts."""

from __future__ import annotations

import json

from replicate import metrics
from replicate.evaluate import split_ablation
from replicate.report import claims, span, targets, write_report


def group(per_seed, nn=0.8, conv=(5000, 5000, 5000)):
    return {
        "seeds": list(range(len(per_seed))),
        "coverage": metrics.mean_ci(per_seed),
        "coverage_per_seed": list(per_seed),
        "nearest_neighbour": metrics.mean_ci([nn] * len(per_seed)),
        "fraction_inside": metrics.mean_ci([1.0] * len(per_seed)),
        "convergence_episode": list(conv),
        "core_seconds": metrics.mean_ci([100.0] * len(per_seed)),
    }


def summary(params):
    base = {f"{b}/{r}": {"coverage": c, "nearest_neighbour": 0.7, "fraction_inside": 1.0, "ceiling": 0.78,
                        "steps": 50}
            for r in ("square", "rectangle", "bedok") for b, c in (("naive", 0.5), ("lloyd", 0.7))}
    runs = {
        "tuned/cr/square": group([0.72, 0.74, 0.75]),
        "tuned/cr/rectangle": group([0.72, 0.69, 0.75]),  # one seed below the 0.70 bar
        "tuned/cr/bedok": group([0.66, 0.67, 0.68]),  # >= 0.9 x Lloyd (0.63)
        "tuned/sw/square": group([0.3, 0.3, 0.3], nn=0.5),
        "tuned/sw/rectangle": group([0.3, 0.3, 0.3], nn=0.5, conv=(None, None, None)),
    }
    for change in params.ablation.changes:
        runs[f"tuned-without-{change}/cr/square"] = group([0.5, 0.6, 0.55])
    return {"runs": runs, "baselines": base}


def test_ablation_rows_leave_the_coverage_table(params):
    out = split_ablation(summary(params), params)
    assert not [k for k in out["runs"] if "-without-" in k]
    assert set(out["ablation"]) == {f"{c}/square" for c in params.ablation.changes}
    row = out["ablation"]["geofence/square"]
    assert row["keys"] == ["geofence"] and abs(row["delta"] - (0.7366667 - 0.55)) < 1e-6


def test_targets_name_the_missed_bar(params):
    timing = {"runs": [{"config": "tuned", "method": "cr", "region": r, "core_seconds": w}
                       for r, w in (("square", 170.0), ("rectangle", 175.0), ("bedok", 200.0))]}
    rows = {r[0]: r for r in targets(split_ablation(summary(params), params), timing)}
    assert rows["square"][-1] == "met"
    assert rows["rectangle"][-1].startswith("missed (coverage: worst seed 0.690, 0.010 short")
    assert "time: 200 s > 180 s" in rows["bedok"][-1] and "coverage" not in rows["bedok"][-1]
    assert rows["square"][4] == "170"  # one run's time, or one stack's runs sharing it, is one number


def test_span_of_seconds():
    assert span([]) == "—" and span([63.2, 62.9]) == "63" and span([118.0, 133.4]) == "118-133"


def test_claims_and_report_text(params, tmp_path):
    s = split_ablation(summary(params), params)
    verdicts = {c[0][:2]: c[1] for c in claims(s, "tuned", ["square", "rectangle", "bedok"])}
    assert verdicts["1."] == "reproduced"  # CR converges at 5,000 on every seed, SW never
    assert verdicts["2."] == "reproduced"  # CR's nearest-neighbour distance above SW's on both regions
    assert verdicts["3."] == "partly"  # CR beats naive, SW does not
    (tmp_path / "summary.json").write_text(json.dumps(s))
    text = write_report(str(tmp_path / "summary.json"), str(tmp_path / "none.json"), [], str(tmp_path / "R.md"), {})
    assert "## Ablation of `tuned`" in text and "| `update_schedule` |" in text
    assert "| naive | square | 50 | 0.500 |" in text  # the baseline table gives each baseline's T
    assert (tmp_path / "R.md").read_text() == text


def test_report_without_ablation_runs_says_how_to_run_them(params, tmp_path):
    s = summary(params)
    s["runs"] = {k: v for k, v in s["runs"].items() if "-without-" not in k}
    (tmp_path / "summary.json").write_text(json.dumps(split_ablation(s, params)))
    text = write_report(str(tmp_path / "summary.json"), str(tmp_path / "none.json"), [], str(tmp_path / "R.md"), {})
    section = text.split("## Ablation of `tuned`")[1].split("\n## ")[0]
    assert "dvc exp run -S pipeline.ablation=true" in section and "| `geofence` |" not in section
