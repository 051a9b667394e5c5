"""How a verdict is reached and written: the verdict words, the rules' helpers (a margin scaled for the
sensitivity column, the bootstrap, "A beats B"), and the number formats every table uses."""

from __future__ import annotations

import dataclasses

from replicate.compare import stats
from replicate.core.studies import ReportConfig

REPRODUCED, PARTLY, NOT = "reproduced", "partly", "not reproduced"


def fmt(ci: dict) -> str:
    if ci.get("n", 0) == 0:
        return "—"
    if ci["n"] == 1 or ci["lo"] != ci["lo"]:
        return f"{ci['mean']:.3f} (n={ci['n']})"
    return f"{ci['mean']:.3f} [{ci['lo']:.3f}, {ci['hi']:.3f}]"


def fmt_t(ci: dict) -> str:
    """The Student-t interval beside a percentile one (``stats.mean_interval``, fewer seeds than
    ``report.t_below``), or a dash."""
    return f"[{ci['t_lo']:.3f}, {ci['t_hi']:.3f}]" if "t_lo" in ci else "—"


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
    return stats.Bootstrap.of(rules)


def beats(a: list[float], b: list[float] | float, margin: float, boot: stats.Bootstrap) -> tuple[bool, dict]:
    """Whether A beats B by more than ``margin``: the interval of mean(A) − mean(B) lies above it."""
    d = stats.difference([a], [b], boot)
    lower = d["lo"] if d["lo"] == d["lo"] else d["delta"]
    return lower > margin, d
