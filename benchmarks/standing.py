"""What the benchmarks that read the standing baseline's seeds on the yardstick share (`settle.py`,
`deploy_prior.py`): where the seeds are (stage train_yardstick), the command line's common options and checks, and
the summary of their rows per event and start."""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from replicate.compare.evaluate import rollout
from replicate.compare.suite import suite_event
from replicate.compare.yardstick import YardstickCell, yardstick_cells, yardstick_lakes
from replicate.core.params import load_params
from replicate.core.studies import StartsConfig
from replicate.world import coverage
from replicate.world.regions import at_density
from replicate.world.scenario import general_evaluation_env, horizon

FOLDER = "yardstick/runs/general-s{}/"  # the standing baseline's seed S: actor.pt, policy.pt
GROUPS = ("all", "none", "lose", "current", "corner", "random")
TENTHS = np.linspace(0.1, 1.0, 10)


@dataclasses.dataclass(frozen=True)
class Episodes:
    """The evaluation's episodes of ``n_agents`` buoys on ``lake`` from ``start``, losing ``lose`` at T/2, in
    ``current``, for the lake's horizon."""

    params: object
    lake: object
    n_agents: int
    start: str
    lose: int = 0
    current: object = None

    def run(self, policy, sensors, every: bool = False):
        """Mean final coverage of ``policy``; with ``every``, also its mean coverage at each tenth of the horizon
        as a share of the final."""
        p, c = self.params, self.params.coverage
        steps = horizon(p.general, self.lake, p.world.region_area)
        env, _ = general_evaluation_env(p, self.lake, self.n_agents, p.evaluate.episodes, sensors, self.current)
        trace = rollout(env, policy, steps, p.evaluate.seed, StartsConfig(start=self.start, lose=self.lose))
        final = float(coverage.coverage_fraction(self.lake.polygon, trace["live"], c.radius, c.edges).mean())
        if not every:
            return final
        at = [coverage.coverage_fraction(self.lake.polygon, trace["positions"][round(f * steps)], c.radius,
                                         c.edges).mean() for f in TENTHS]
        return final, [float(a) / final for a in at]


def lake_cells(params_path: str, name: str) -> tuple[object, Iterator[tuple[YardstickCell, Episodes]]]:
    """The parameters as `replicate compare` reads them (its episodes and seed) and every yardstick cell of the lake
    ``name`` with its episodes."""
    params = load_params(params_path)
    d = params.yardstick
    params = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, episodes=d.episodes,
                                                                      seed=d.seed))
    region, drawn_for = yardstick_lakes(params)[name]

    def cells():
        for cell in (c for c in yardstick_cells(params) if c.lake == name):
            lake = at_density(region, drawn_for, cell.n_agents)
            lose, current = suite_event(params.general.suite, cell.event, cell.n_agents, water=lake.polygon)
            yield cell, Episodes(params, lake, cell.n_agents, cell.start, lose, current)

    return params, cells()


def add_options(ap: argparse.ArgumentParser) -> None:
    """--params, --seeds, --workers, --out and --force."""
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--seeds", default="1,2", help="the standing baseline's seeds, comma-separated")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, required=True, help="the JSON file of the rows")
    ap.add_argument("--force", action="store_true", help="replace --out")


def numbers(ap: argparse.ArgumentParser, option: str, text: str, kind=float) -> list:
    """``text``, the comma-separated value of ``option``, as numbers of ``kind``; refused by name otherwise."""
    try:
        return [kind(x) for x in text.split(",")]
    except ValueError:
        ap.error(f"{option} takes comma-separated numbers, got {text!r}")


def refused(ap: argparse.ArgumentParser, args: argparse.Namespace, params, seeds: list[int]) -> bool:
    """Whether the seeds' files or --out stop the run (said on stderr, exit 2); seeds that are not the standing
    baseline's are a usage error."""
    if not set(seeds) <= set(params.yardstick.seeds):
        ap.error(f"--seeds are the standing baseline's (yardstick.seeds {list(params.yardstick.seeds)}), got {seeds}")
    missing = [FOLDER.format(s) + f for s in seeds for f in ("actor.pt", "policy.pt")
               if not Path(FOLDER.format(s), f).is_file()]
    if missing:
        print(f"error: {missing[0]} is missing; run `make repro` (stage train_yardstick) first", file=sys.stderr)
    elif args.out.exists() and not args.force:
        print(f"error: {args.out} exists; choose another --out or pass --force", file=sys.stderr)
    return bool(missing) or (args.out.exists() and not args.force)


def by_group(rows: list[dict], keys: list[str]) -> list[str]:
    """Each of ``keys``' mean coverage / lloyd_tuned over the rows (cells), in all and per event and start."""
    lines = []
    for group in GROUPS:
        cells = [r for r in rows if group in ("all", r["event"], r["start"])]
        lines.append(f"{group} ({len(cells)} cells): " + ", ".join(
            f"{k} {statistics.mean(r[k] / r['lloyd'] for r in cells):.4f}" for k in keys))
    return lines
