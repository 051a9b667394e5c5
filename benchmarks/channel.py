"""The 50-buoy channel from the corner: the rectangle at 1 m² per buoy (as `replicate evaluate --policy --region
rectangle --n-agents 50 --starts corner`), still water, the general policy's hardest cell of the suite.

    python benchmarks/channel.py --candidate DIR --out docs/comparisons/channel-NAME.json
        every seed of the standing baseline (yardstick/runs/general-s1..8/policy.pt) and of a candidate
        (DIR/general-s1..8/policy.pt, each `replicate export`ed) on the same episodes, with tuned Lloyd and the
        clairvoyant planner: the records docs/GENERAL.md reads beside each candidate's `replicate compare`.
    python benchmarks/channel.py --trace [--policy policies/general.pt]
        where the fleet is over time: the front buoy's and the median buoy's distance along the channel for the
        policy and for tuned Lloyd, and the policy again with its sensors' ranges set longer at deployment.

Run from the repository root with the project's environment (`make setup`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from replicate.compare.evaluate import SameEpisodes, evaluate_policy, fleet_policy, read_general_policy
from replicate.compare.rivals import general_baselines
from replicate.core import artifacts
from replicate.core.artifacts import CheckpointError
from replicate.core.params import load_params
from replicate.core.schema import ConfigError
from replicate.core.sections import SensorsConfig
from replicate.world.regions import at_density, make_region
from replicate.world.scenario import horizon

ROOT = Path(__file__).resolve().parents[1]
BASELINE = "yardstick/runs/general-s{}/policy.pt"  # the standing baseline's seeds (yardstick.seeds, train_yardstick)
N = 50
SETTING = ("the rectangle at 1 m² per buoy (as `evaluate --policy --region rectangle --n-agents 50`), 50 buoys, "
           "corner start, still water, {} episodes from evaluate.seed; every seed on the same episodes")


def channel(params, episodes: int):
    """(params with ``episodes`` evaluation episodes, the channel's region, its T)."""
    params = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, episodes=episodes))
    region = make_region("rectangle", params.regions["rectangle"], params.world.region_area)
    region = at_density(region, params.world.n_agents, N)
    return params, region, horizon(params.general, region, params.world.region_area)


def record(params, candidate: Path, episodes: int) -> dict:
    """Every seed of both versions, tuned Lloyd and the planner on the same episodes → the record."""
    params, region, _ = channel(params, episodes)
    seeds = {f"baseline/{s}": ROOT / BASELINE.format(s) for s in params.yardstick.seeds}
    seeds |= {f"candidate/{s}": candidate / f"general-s{s}" / "policy.pt" for s in params.yardstick.seeds}
    first = seeds.pop("baseline/1")
    out = evaluate_policy(first, region, params, N, "corner", seeds=seeds, naive=False, geodesic=False,
                          planner=True)
    covered = {"baseline/1": out["coverage"]["mean"]} | {k: v["coverage"]["mean"] for k, v in out["seeds"].items()}
    return {"setting": SETTING.format(episodes), "seeds": {k: round(v, 4) for k, v in sorted(covered.items())},
            "baselines": {k: b["coverage"] for k, b in out["baselines"].items()}}


def trace(params, policy: Path, episodes: int) -> None:
    """Print where the policy's and Lloyd's fleets are along the channel over time, and the policy's coverage with
    longer sensor ranges at deployment."""
    params, region, steps = channel(params, episodes)
    same = SameEpisodes(region, params, N, "corner", 0, None, steps)
    module, meta = read_general_policy(policy)
    rivals, _ = general_baselines(params, meta.get("baseline_gains"), geodesic=False, naive=False)
    west = region.polygon.bounds[0]
    runs = {"policy": same.run(fleet_policy(module), SensorsConfig(**meta["sensor_config"]))}
    runs |= {name: same.run(rival, None) for name, rival in rivals.items()}
    length = region.polygon.bounds[2] - west
    print(f"the channel: {length:.1f} x {region.polygon.bounds[3] - region.polygon.bounds[1]:.2f} m, T = {steps}; "
          "metres from the west end (front buoy / median buoy, mean over episodes) and coverage")
    for name, (positions, _) in runs.items():
        x = positions[..., 0] - west  # [T + 1, E, N]
        rows = []
        for t in range(0, steps + 1, steps // 6):
            cover = same.per_episode(positions[t]).mean()
            rows.append(f"t={t}: {x[t].max(-1).mean():.1f} / {np.median(x[t], -1).mean():.1f}, {cover:.3f}")
        print(f"  {name:12s} " + "; ".join(rows))
    for comm, ray in ((2.0, 2.0), (4.0, 2.0), (2.0, 4.0)):
        sensors = SensorsConfig(**(meta["sensor_config"] | {"comm_range": comm, "ray_range": ray}))
        positions, live = same.run(fleet_policy(module), sensors)
        front = (positions[-1, ..., 0].max(-1) - west).mean()
        print(f"  the policy hearing {comm:g} m and seeing the shore to {ray:g} m: coverage "
              f"{same.per_episode(live).mean():.3f}, front at the end {front:.1f} m")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--candidate", type=Path, help="a folder of general-s1..8/policy.pt")
    ap.add_argument("--out", type=Path, help="the record to write (JSON)")
    ap.add_argument("--force", action="store_true", help="replace --out")
    ap.add_argument("--episodes", type=int, default=None, help="episodes (default: 10 for a record, 4 for --trace)")
    ap.add_argument("--trace", action="store_true", help="print the fleets' positions over time instead")
    ap.add_argument("--policy", type=Path, default=ROOT / "policies" / "general.pt", help="the policy --trace reads")
    args = ap.parse_args(argv)
    if args.episodes is not None and args.episodes < 1:
        ap.error(f"--episodes must be at least 1, got {args.episodes}")
    if args.trace == (args.candidate is not None or args.out is not None) or \
            (not args.trace and (args.candidate is None or args.out is None)):
        ap.error("give --candidate DIR and --out FILE, or --trace (with --policy), not both")
    try:
        return run(args)
    except (ConfigError, CheckpointError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def run(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    if args.trace:
        trace(params, args.policy, args.episodes or 4)
        return 0
    seeds = params.yardstick.seeds
    missing = [p for s in seeds for p in (args.candidate / f"general-s{s}" / "policy.pt", ROOT / BASELINE.format(s))
               if not p.is_file()]
    if missing:
        print(f"error: {missing[0]} is missing; export each seed (`replicate export RUN --out RUN/policy.pt`) and "
              "build the standing baseline (`dvc repro train_yardstick`)", file=sys.stderr)
        return 2
    if args.out.exists() and not args.force:
        print(f"error: {args.out} exists; choose another --out or pass --force", file=sys.stderr)
        return 2
    artifacts.write_json(args.out, record(params, args.candidate, args.episodes or 10))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
