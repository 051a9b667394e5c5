"""docs/DEVIATIONS.md quotes the ablation as REPORT.md measures it: every ablation change has its row, and the row
ends with the measured Δ and its reading from metrics/summary.json, so no row claims an effect the ablation does
not show."""

import json
import re
from pathlib import Path

from replicate.core.params import load_params
from replicate.pipeline.report.rules import fmt_delta
from replicate.pipeline.report.tables import ablation_effect

ROOT = Path(__file__).resolve().parents[2]


def test_every_ablation_row_quotes_the_measured_effect():
    params = load_params(ROOT / "params.yaml")
    rows = (ROOT / "docs" / "DEVIATIONS.md").read_text().splitlines()
    measured = json.loads((ROOT / "metrics" / "summary.json").read_text()).get("ablation", {})
    assert measured, "metrics/summary.json has no ablation (pipeline.ablation is false?)"
    for change in params.ablation.changes:
        (row,) = [r for r in rows if f"(`{change}`)" in r]
        for region in params.ablation.regions:
            d = measured[f"{change}/{region}"]["delta"]
            quote = f"Δ {fmt_delta(d)}, {ablation_effect(d, params.report.margin)}"
            assert quote in row, f"DEVIATIONS row of {change} should quote {quote!r}"
            quoted = re.findall(r"Ablation \(`REPORT.md`\): Δ ([+-][\d.]+ \[[^\]]+\]), ([a-z]+(?: [a-z]+)*)", row)
            assert quoted == [(fmt_delta(d), ablation_effect(d, params.report.margin))], \
                f"{change}: one quote, the measured one"


def test_the_reading_of_an_interval():
    """Against ``report.margin`` (0.01), as every comparison: an interval clear of 0 but not of the margin shows no
    effect beyond it (the ablation's `discount` row once read "helps" at a lower end of +0.000)."""
    assert ablation_effect({"lo": -0.01, "hi": 0.02}, 0.01) == "no effect beyond the margin"
    assert ablation_effect({"lo": 0.001, "hi": 0.02}, 0.01) == "no effect beyond the margin"
    assert ablation_effect({"lo": 0.011, "hi": 0.02}, 0.01) == "helps"
    assert ablation_effect({"lo": -0.03, "hi": -0.011}, 0.01) == "hurts"
    assert ablation_effect({"lo": float("nan"), "hi": float("nan")}, 0.01) == "no effect beyond the margin"
