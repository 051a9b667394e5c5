"""The general policy's goals (``report.goals``): what the learned policy is built toward beside the bars of
``report.general`` — above clairvoyant Lloyd on average, well above the decentralised Lloyd that sees what it sees,
near the planner everywhere, near the best layout on real lakes with arms, the long channel closed — each as a
Markdown row with what the seeds measured, how far it falls short and its verdict: on the test and real lakes,
which no choice read, and on the long channel, a training world."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from replicate.pipeline.report.general import VERDICT_KINDS, kind_of, rival, seed_coverages


@dataclass(frozen=True)
class Goal:
    """One goal read on one group of cells: ``value`` against ``target`` (met when at least it, or at most it
    where ``at_most``; above it where ``strict``), ``said`` the measured value as printed; ``limit`` the best
    layout read the same way (what no controller is known to exceed: a goal above it asks more than any layout
    found gives)."""

    goal: str
    lakes: str
    value: float
    target: float
    said: str
    limit: float | None = None
    at_most: bool = False
    strict: bool = False

    @property
    def met(self) -> bool:
        if self.at_most:
            return self.value <= self.target
        return self.value > self.target if self.strict else self.value >= self.target

    def row(self) -> str:
        short = "—" if self.met else f"{abs(self.target - self.value):.3f}" if not self.at_most \
            else f"{self.value - self.target:.0f} s"
        limit = "—" if self.limit is None else f"{self.limit:.3f}" + (" (below the goal)" if self.limit < self.target
                                                                      else "")
        return (f"| {self.goal} | {self.lakes} | {self.said} | {short} | {limit} | "
                f"{'met' if self.met else '**not met**'} |")


def mean_share(cells: list[dict], of: str, who: str = "policy") -> float:
    """The mean coverage over ``cells`` of the seeds (``who`` "policy") or of comparison ``who`` / comparison
    ``of``'s mean coverage over the same cells."""
    mine = [np.mean(list(seed_coverages(c).values())) if who == "policy" else rival(c, who) for c in cells]
    return float(np.mean(mine) / np.mean([rival(c, of) for c in cells]))


def worst_share(cells: list[dict], of: str, bar: float, strict: bool = False) -> tuple[float, str]:
    """(the lowest share of ``of`` any seed reached in any cell, "worst W; K of M cells at ``bar`` or above with
    every seed", above it where ``strict``)."""
    worst = [min(seed_coverages(c).values()) / rival(c, of) for c in cells]
    meets = sum(w > bar if strict else w >= bar for w in worst)
    return min(worst), f"worst {min(worst):.3f}; {meets} of {len(cells)} cells"


def worst_limit(cells: list[dict], of: str) -> float:
    """The lowest share of ``of`` the best layout reaches in any of ``cells``."""
    return min(rival(c, "best_layout") / rival(c, of) for c in cells)


def kind_goals(params, cells: list[dict], kind: str) -> list[Goal]:
    """The goals read over every still-water cell of lake kind ``kind``."""
    g, bars = params.report.goals, params.report.general
    still = [c for c in cells if kind_of(params, c) == kind and c["event"] == "none"]
    if not still:
        return []
    lakes = f"{kind} ({len(still)} cells)"
    out = []
    for of, target in (("lloyd_tuned", g.mean_of_lloyd), ("decentralised_lloyd", g.mean_of_decentralised)):
        share = mean_share(still, of)
        out.append(Goal(f"still water: mean coverage ≥ {target:g} × {of}'s", lakes, share, target, f"{share:.3f} ×",
                        mean_share(still, of, "best_layout")))
    for of, bar, label, strict in (("lloyd_tuned", bars.of_lloyd, f"≥ {bars.of_lloyd:.0%} of lloyd_tuned", False),
                                   ("naive_tuned", 1.0, "above naive_tuned", True),
                                   ("planner", g.of_planner, f"≥ {g.of_planner:.0%} of the planner", False)):
        worst, said = worst_share(still, of, bar, strict)
        out.append(Goal(f"still water: every cell, every seed {label}", lakes, worst, bar, said,
                        worst_limit(still, of), strict=strict))
    return out


def lake_file_goals(params, cells: list[dict]) -> list[Goal]:
    """Each real lake file at ``report.goals.lake_fleet`` buoys in still water, each start: the seeds' mean
    coverage as a share of the lake's best layout."""
    g = params.report.goals
    names = [Path(f).stem for f in params.general.suite.real_lakes]
    out = []
    for c in cells:
        if c["region"] in names and c["n_agents"] == g.lake_fleet and c["event"] == "none":
            share = float(np.mean(list(seed_coverages(c).values()))) / rival(c, "best_layout")
            out.append(Goal(f"still water, a real lake file: ≥ {g.lake_files_of_best:.0%} of the best layout",
                            f"{c['region']}, N = {c['n_agents']}, {c['start']} start", share, g.lake_files_of_best,
                            f"{share:.3f}"))
    return out


def channel_goal(params, cells: list[dict]) -> list[Goal]:
    """The long channel (``report.goals.channel`` with ``channel_fleet`` buoys) from the corner in still water: the
    seeds' mean against lloyd_tuned."""
    g = params.report.goals
    found = [c for c in cells if (c["region"], c["n_agents"], c["start"], c["event"])
             == (g.channel, g.channel_fleet, "corner", "none")]
    if not found:
        return []
    policy = float(np.mean(list(seed_coverages(found[0]).values())))
    share = policy / rival(found[0], "lloyd_tuned")
    return [Goal(f"still water, the long channel: ≥ {g.channel_of_lloyd:.2f} × lloyd_tuned",
                 f"{g.channel}, N = {g.channel_fleet}, corner start", share, g.channel_of_lloyd,
                 f"{policy:.3f} against {rival(found[0], 'lloyd_tuned'):.3f} ({share:.3f} ×)",
                 worst_limit(found, "lloyd_tuned"))]


def goal_section(params, cells: list[dict], seed_cpu: dict[int, float] | None = None) -> list[str]:
    """The goals of ``report.goals`` on the test and real lakes, the long channel and a reported seed's training
    time (``seed_cpu``: one core's seconds by seed, from ``policies/summary.json``), as a Markdown table."""
    goals = [goal for kind in VERDICT_KINDS for goal in kind_goals(params, cells, kind)]
    goals += [*lake_file_goals(params, cells), *channel_goal(params, cells)]
    if seed_cpu:
        worst = max(seed_cpu.values())
        goals.append(Goal(f"a reported seed trains within {params.report.goals.seed_cpu_s:.0f} s of one core",
                          f"{len(seed_cpu)} seeds", worst, params.report.goals.seed_cpu_s,
                          f"{min(seed_cpu.values()):.0f}-{worst:.0f} s", at_most=True))
    return ["Goals of the learned policy (`report.goals`), beside the bars (two of them, 98 % of Lloyd and above "
            "naive swarming, asked again): what the seeds measured (their mean coverage against the comparison's "
            "mean, or the worst seed in the worst cell where every cell is asked), how far each falls short, and the "
            "best "
            "layout read the same way (a goal above it asks more than any layout found gives, whatever the "
            "controller); the changes tried toward them are listed below. Deployment's cost per buoy and step is a "
            "benchmark (`make bench` section 7), not a result of the pipeline.", "",
            "| goal (`report.goals`) | lakes | measured | short by | the best layout, read the same way | verdict |",
            "|---|---|---|---|---|---|",
            *(goal.row() for goal in goals), ""]
