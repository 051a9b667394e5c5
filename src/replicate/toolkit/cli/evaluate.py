"""``replicate evaluate``: SPEC §8 metrics of a run, a baseline, or a general policy zero-shot on any region, as
JSON."""

from __future__ import annotations

import argparse
import dataclasses
import math
import shutil
from pathlib import Path

import numpy as np
from shapely import affinity

from replicate.core import artifacts
from replicate.core.params import Params, load_params
from replicate.core.schema import MAX_AGENTS, ConfigError
from replicate.toolkit.cli.inputs import (
    claim_out_file,
    claim_run_folder,
    number_pair,
    overrides,
    resolve_region,
    run_region,
)
from replicate.world.units import top_speed


def add(sub, verb: dict, regions: str) -> None:
    """The ``evaluate`` verb's options."""
    e = sub.add_parser("evaluate", help="SPEC §8 metrics of a run, a baseline or a general policy, as JSON", **verb)
    e.add_argument("run", nargs="?", default=None, help="a run folder written by `replicate train`")
    e.add_argument("--run", dest="run_option", default=None, help=argparse.SUPPRESS)  # the older spelling
    e.add_argument("--baseline", default=None,
                   help="instead of a run: random, naive, lloyd, lloyd_converged (hand-set gains)")
    e.add_argument("--region", default=None, help=f"{regions} (default: the run's own)")
    e.add_argument("--config", default="paper", help="a baseline runs with this config's physics and T")
    e.add_argument("--out", default=None,
                   help="output JSON (default: RUN/metrics.json, my-runs/baseline-NAME-REGION.json or, with "
                        "--policy, my-runs/policy-REGION-nN.json)")
    e.add_argument("--force", action="store_true", help="replace --out if it exists")
    g = e.add_argument_group("a general policy, zero-shot on any region (instead of a run)")
    g.add_argument("--policy", default=None, help="a general policy file (`replicate export` of a general run)")
    g.add_argument("--n-agents", type=int, default=None, help="buoys (default: world.n_agents, 9); the region is "
                   "scaled to the paper's density, 1 m² per buoy")
    g.add_argument("--starts", choices=("corner", "random"), default="corner",
                   help="release in the corner patch (default) or scattered over the water")
    g.add_argument("--lose", type=int, default=0, help="buoys lost half-way (default 0)")
    g.add_argument("--current", default=None, help="a uniform drift U,V in simulation m/s (top speed 2)")
    g.add_argument("--decentralised", action="store_true", help="also decentralised Lloyd: each buoy's cell among "
                   "the buoys it hears, clipped to the water it has sensed (what the policy sees)")
    g.add_argument("--radius-m", type=float, default=None, help="a lake file kept at its size in metres, for buoys of "
                   "this sensing radius (default: scaled to the paper's density, 1 m² per buoy)")
    g.add_argument("--speed-ms", type=float, default=None, help="with --radius-m: the buoys' top speed, m/s "
                   "(default 1.0); the output states the control period and the mission in seconds")
    g.add_argument("--current-ms", default=None, metavar="EAST,NORTH",
                   help="with --radius-m: a uniform drift in m/s (instead of --current)")
    g.add_argument("--geodesic", action="store_true", help="also geodesic Lloyd (cells and paths through the "
                   "water; the slowest comparison, left out by default)")
    e.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    from replicate.compare.evaluate import BASELINES, evaluate_baseline, evaluate_run

    params = load_params(args.params, overrides(args.set))
    if args.policy is not None:
        return evaluate_policy_file(args, params)
    given = [flag for flag, value, default in (("--n-agents", args.n_agents, None), ("--starts", args.starts, "corner"),
                                               ("--lose", args.lose, 0), ("--current", args.current, None),
                                               ("--geodesic", args.geodesic, False),
                                               ("--decentralised", args.decentralised, False))
             if value != default]
    if given:
        raise ConfigError(f"{', '.join(given)}: options of a general policy; give --policy FILE with them")
    if (args.run is None) == (args.baseline is None):
        raise ConfigError("give exactly one of a run folder (`replicate evaluate RUN`) or --baseline NAME")
    if args.baseline is not None and not args.region:
        raise ConfigError("--baseline needs --region")
    if args.baseline is not None and args.baseline not in BASELINES:  # before any folder is made for its result
        raise ConfigError(f"unknown baseline {args.baseline!r}; known: {list(BASELINES)}")
    region = run_region(args.run, params, args.region) if args.run is not None else \
        resolve_region(args.region, params)
    default = (Path(args.run) / "metrics.json" if args.run is not None
               else Path(f"my-runs/baseline-{args.baseline}-{region.name}.json"))
    out = claim_out_file(Path(args.out) if args.out else default, args.force, held=args.held)
    if args.run is not None:
        result = evaluate_run(args.run, params, region, progress=not args.no_progress)
    else:
        result = evaluate_baseline(args.baseline, params, region, args.config, progress=not args.no_progress)
    artifacts.write_json(out, result)
    cov = result["coverage"]
    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over {cov['n']} evaluation episodes "
          f"of this trained policy; a training seed of its own can land outside it); wrote {out}")
    return 0


def evaluate_policy_file(args: argparse.Namespace, params: Params) -> int:
    """``evaluate --policy``: a general policy on ``--region`` with its fleet, starts and events."""
    from replicate.compare.evaluate import evaluate_policy
    from replicate.compare.rivals import lloyd_name

    if args.run is not None or args.baseline is not None or args.config != "paper":
        raise ConfigError("--policy evaluates a general policy; give no run folder, --baseline or --config with it")
    if not args.region:
        raise ConfigError("--policy needs --region (square, rectangle, bedok or a vector file)")
    if not Path(args.policy).is_file():
        raise ConfigError(f"--policy {args.policy}: no such file; export a general run with `replicate export`")
    from replicate.compare.evaluate import read_general_policy

    read_general_policy(args.policy)  # refused by name before any work if it is not a general policy
    n = params.world.n_agents if args.n_agents is None else args.n_agents
    if not 2 <= n <= MAX_AGENTS:
        raise ConfigError(f"--n-agents must be from 2 to {MAX_AGENTS}, got {n}")
    if not 0 <= args.lose < n:
        raise ConfigError(f"--lose must be from 0 to {n - 1} (a fleet of {n} keeps at least one), got {args.lose}")
    region, units, current = policy_world(args, params, n, simulation_drift(args, params))
    out = claim_out_file(Path(args.out or f"my-runs/policy-{region.name}-n{n}.json"), args.force, held=args.held)
    field = None if region.utm_crs is None else out.parent / f"{out.stem}-episode"  # a lake on the map: for a GIS
    created = field is not None and claim_run_folder(field, args.force, args.held)
    try:
        result = evaluate_policy(args.policy, region, params, n, args.starts, args.lose, current,
                                 not args.no_progress, geodesic=args.geodesic, beside=True,
                                 decentralised=args.decentralised)
        si = units.describe(params.world, params.coverage)
        result["si"] = {**si, "mission_s": units.steps_time_s(result["steps"])}
        if field is not None:
            result["field_files"] = [str(p) for p in episode_files(args, params, region, units, n, current, field)]
    except BaseException:
        if created:
            shutil.rmtree(field, ignore_errors=True)  # interrupted: no half-written folder beside no result
        raise
    artifacts.write_json(out, result)
    cov, rivals = result["coverage"], result["baselines"]
    lloyd = rivals[lloyd_name(rivals)]

    def ratio(key):
        return "n/a" if result[key] is None else f"{result[key]:.3f}"

    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over {cov['n']} evaluation episodes); "
          f"Lloyd {lloyd['coverage']['mean']:.3f} (gains {lloyd['gains']}), ratio {ratio('ratio_to_lloyd')}; "
          f"best layout {rivals['best_layout']['coverage']['mean']:.3f}, ratio {ratio('ratio_to_best')} (no layout "
          f"above {rivals['upper_bound']['coverage']['mean']:.3f}); "
          + (f"decentralised Lloyd {rivals['decentralised_lloyd']['coverage']['mean']:.3f}; "
             if "decentralised_lloyd" in rivals else "") +
          f"furthest outside the water {result['max_outside_m']:.3g} m; buoys of {si['radius_m']:.3g} m at "
          f"{si['top_speed_ms']:g} m/s: {result['steps']} control periods of {si['control_period_s']:.3g} s, "
          f"{result['si']['mission_s'] / 60:.1f} min; wrote {out}"
          + (f" and its first episode for a GIS in {field}/" if field is not None else ""))
    return 0


def episode_files(args: argparse.Namespace, params: Params, region, units, n: int, current, out: Path) -> list[Path]:
    """One episode of the evaluation's starts and events, flown by the policy and its rivals from the evaluation
    seed, written for a GIS into ``out`` (``toolkit.field``: GeoPackage, GeoJSON, waypoints, map)."""
    from replicate.core.studies import StartsConfig
    from replicate.toolkit.field import write_mission
    from replicate.toolkit.plan import Mission, plan_on

    drift = None if current is None else tuple(float(v) for v in units.speed_ms(np.asarray(current)))
    mission = Mission(n, float(units.length_m(params.coverage.radius)), float(units.speed_ms(top_speed(params.world))),
                      current_ms=drift, seed=params.evaluate.seed)
    p = plan_on(region, params, mission, Path(args.policy), StartsConfig(start=args.starts, lose=args.lose),
                decentralised=args.decentralised)
    return write_mission(p, out, "episode", animation=False)


def simulation_drift(args: argparse.Namespace, params: Params) -> tuple[float, float] | None:
    """``--current U,V`` (simulation m/s), refused by name unless two numbers slower than a buoy."""
    if args.current is None:
        return None
    try:
        current = tuple(float(v) for v in args.current.split(","))
    except ValueError:
        current = ()
    if len(current) != 2 or not all(math.isfinite(v) for v in current):
        raise ConfigError(f"--current expects two numbers U,V (simulation m/s), got {args.current!r}")
    top = top_speed(params.world)  # a buoy's top speed over the water
    if math.hypot(*current) >= top:
        raise ConfigError(f"--current {args.current}: a drift of {math.hypot(*current):.3g} simulation m/s is at "
                          f"least a buoy's top speed ({top:.3g}); the buoys would be swept off, give a slower one")
    return current


def policy_world(args: argparse.Namespace, params: Params, n: int, current):
    """The lake, its units and the drift (simulation m/s) of ``evaluate --policy``: the paper's density for any
    fleet (9 buoys on 9 m², the buoys of 1 m/s) or, with ``--radius-m``, the lake file in metres."""
    from replicate.world.scenario import scaled_setup
    from replicate.world.units import BOB_SPEED, Units

    if args.radius_m is None:
        if args.speed_ms is not None or args.current_ms is not None:
            raise ConfigError("--speed-ms and --current-ms go with --radius-m (a lake kept in metres)")
        region = resolve_region(args.region, params)
        s = math.sqrt(n / params.world.n_agents)  # the paper's density for any fleet: 9 buoys on 9 m²
        region = dataclasses.replace(region, polygon=affinity.scale(region.polygon, s, s, origin=(0, 0)),
                                     scale=region.scale / s)
        return region, Units.of(params.world, params.coverage, params.coverage.radius * region.scale), current
    if not Path(args.region).is_file():
        raise ConfigError(f"--radius-m keeps a lake file at its size in metres; --region {args.region} is not a file")
    if current is not None:
        raise ConfigError("with --radius-m give the drift in m/s: --current-ms EAST,NORTH")
    region, _ = scaled_setup(Path(args.region), params, n, args.radius_m)
    units = Units.of(params.world, params.coverage, args.radius_m, args.speed_ms or BOB_SPEED)
    if args.current_ms is not None:
        east_north = number_pair(args.current_ms, "--current-ms", "EAST,NORTH in m/s")
        if math.hypot(*east_north) >= units.speed_ms(top_speed(params.world)):
            raise ConfigError(f"--current-ms {args.current_ms}: at least the buoys' top speed; they would be swept off")
        current = tuple(float(v) for v in units.sim_speed(np.asarray(east_north)))
    return region, units, current
