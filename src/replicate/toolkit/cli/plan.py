"""``replicate plan``: a deployment plan for a lake file, N buoys of a sensing radius in metres and a top speed in
m/s: where each buoy ends up and when coverage reaches 90 % / 95 %, for the general policy, tuned Lloyd,
decentralised Lloyd and the clairvoyant planner side by side, with the best layout as the limit; GIS files of the
lake, tracks and layouts."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from replicate.core.params import load_params
from replicate.core.schema import MAX_AGENTS, ConfigError, check_seed
from replicate.toolkit.cli.inputs import claim_run_folder, number_pair, overrides


def add(sub, verb: dict, regions: str) -> None:
    """The ``plan`` verb's options."""
    p = sub.add_parser("plan", help="plan a deployment in metres and seconds: where each buoy goes and when, as GIS "
                                    "files", **verb)
    p.add_argument("--region", required=True, help="the lake: a vector file (GeoJSON, GeoPackage, shapefile; any CRS)")
    p.add_argument("--buoys", type=int, required=True, help=f"number of buoys, 2 to {MAX_AGENTS}")
    p.add_argument("--radius-m", type=float, required=True, help="each buoy's sensing (coverage) radius, metres")
    p.add_argument("--speed-ms", type=float, default=1.0, help="each buoy's top speed through the water, m/s "
                   "(the paper's BoB: 1.0)")
    p.add_argument("--launch", default=None, metavar="LON,LAT",
                   help="where the buoys are released, degrees WGS84 (default: the lake's lower-left corner patch)")
    p.add_argument("--duration-min", type=float, default=None,
                   help="mission length in minutes (default: long enough to cross the lake, as `evaluate --policy`)")
    p.add_argument("--current-ms", default=None, metavar="EAST,NORTH", help="a uniform drift, m/s (default: still)")
    p.add_argument("--comm-range-m", type=float, default=None,
                   help="radio range between buoys, metres (default: the policy's, 4 radii)")
    p.add_argument("--shore-range-m", type=float, default=None,
                   help="range of the shore sensor, metres (default: the policy's, 4 radii)")
    p.add_argument("--policy", default=None, metavar="FILE",
                   help="a general policy file (default: the one installed with the package)")
    p.add_argument("--seed", type=int, default=0, help="draw of the start positions around the launch point")
    p.add_argument("--out", default="my-runs/plan", help="output folder")
    p.add_argument("--force", action="store_true", help="replace what --out holds")
    p.set_defaults(func=run)


def mission_of(args: argparse.Namespace):
    """The mission the options ask for, refused by name before anything is written."""
    from replicate.toolkit.plan import Mission

    check_seed(args.seed)
    if not 2 <= args.buoys <= MAX_AGENTS:
        raise ConfigError(f"--buoys must be from 2 to {MAX_AGENTS}, got {args.buoys}")
    for option, value in (("--radius-m", args.radius_m), ("--speed-ms", args.speed_ms),
                          ("--duration-min", args.duration_min), ("--comm-range-m", args.comm_range_m),
                          ("--shore-range-m", args.shore_range_m)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{option} must be a positive number, got {value}")
    launch = number_pair(args.launch, "--launch", "LON,LAT in degrees")
    if launch is not None and not (-180 <= launch[0] <= 180 and -90 <= launch[1] <= 90):
        raise ConfigError(f"--launch {args.launch}: longitude must lie in [-180, 180] and latitude in [-90, 90] "
                          "degrees (LON,LAT, longitude first)")
    current = number_pair(args.current_ms, "--current-ms", "EAST,NORTH in m/s")
    if current is not None and math.hypot(*current) >= args.speed_ms:
        raise ConfigError(f"--current-ms {args.current_ms}: a drift of {math.hypot(*current):.3g} m/s is at least "
                          f"the buoys' top speed ({args.speed_ms:g} m/s); they would be swept away")
    return Mission(args.buoys, args.radius_m, args.speed_ms, launch,
                   None if args.duration_min is None else 60 * args.duration_min, current, args.comm_range_m,
                   args.shore_range_m, args.seed)


def run(args: argparse.Namespace) -> int:
    from replicate.toolkit.cli.cover import general_policy_file

    params = load_params(args.params, overrides(args.set))
    mission = mission_of(args)
    policy = general_policy_file(args.policy)
    if not Path(args.region).is_file():
        raise ConfigError(f"--region {args.region}: no such file; give the lake's outline as a vector file")
    from replicate.compare.evaluate import read_general_policy

    read_general_policy(policy)  # refused by name before anything is written
    out = Path(args.out)
    created = claim_run_folder(out, args.force, args.held)
    try:
        from replicate.toolkit.field import write_mission
        from replicate.toolkit.plan import plan, summary

        p = plan(Path(args.region), params, mission, policy)
        written = write_mission(p, out, progress=not args.no_progress)
    except BaseException:
        if created:
            import shutil

            shutil.rmtree(out, ignore_errors=True)  # refused or interrupted: leave nothing half-written
        raise
    print_plan(summary(p), written)
    return 0


def print_plan(s: dict, written: list[Path]) -> None:
    """The plan as a field team reads it."""
    km2 = s["area_m2"] / 1e6
    print(f"{s['lake']} (centred at {s['centre']}): {s['buoys']} buoys of {s['radius_m']:g} m radius at "
          f"{s['top_speed_ms']:g} m/s on {km2:.3g} km² ({s['utm_crs']}); a control period of "
          f"{s['control_period_s']:.3g} s, a mission of {s['mission_s'] / 60:.1f} min")
    best = s["best_layout"]["coverage"]
    for name, m in s["methods"].items():
        print(f"  {name}: covers {100 * m['coverage']:.3g} % of the lake at the end ({m['of_best_layout']:.0%} of "
              "the best layout); "
              f"90 % of that by {m['seconds_to_90pct'] / 60:.1f} min, 95 % by {m['seconds_to_95pct'] / 60:.1f} min; "
              f"top speed {m['max_speed_ms']:.2f} m/s")
    print(f"  best layout found offline (placed, no motion: the limit): {100 * best:.3g} %")
    print(f"wrote {', '.join(str(p) for p in written)}")
