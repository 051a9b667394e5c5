"""The ``replicate`` command: ``train``, ``evaluate``, ``cover``, ``export``, ``act``, ``animate``
(``replicate COMMAND --help`` for the options)."""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

from . import artifacts
from .artifacts import CheckpointError
from .config import ConfigError, Params, load_params, run_config
from .regions import Region, RegionError, make_region, region_from_file


def resolve_region(name_or_path: str, params: Params) -> Region:
    """A region named in params.yaml (``square``, ``rectangle``, ``bedok``) or any vector file."""
    if name_or_path in params.regions:
        return make_region(name_or_path, params.regions[name_or_path], params.world.region_area)
    path = Path(name_or_path)
    if path.suffix or path.exists():
        return region_from_file(path, area=params.world.region_area)
    raise RegionError(f"unknown region {name_or_path!r}: not one of {sorted(params.regions)} and not a file")


def overrides(pairs: list[str] | None) -> dict:
    """``--set key.path=value`` pairs (values parsed as YAML) → a mapping for ``load_params``."""
    import yaml

    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {pair!r}")
        out[key.strip()] = yaml.safe_load(value)
    return out


def cmd_train(args: argparse.Namespace) -> int:
    from .train import train

    params = load_params(args.params, overrides(args.set))
    rc = run_config(params, args.config, args.method, args.region)
    region = resolve_region(args.region, params)
    episodes = args.episodes if args.episodes is not None else params.train.episodes
    out = Path(args.out or f"runs/{args.config}-{args.method}-{region.name}-s{args.seed}")
    for note in region.notes:
        print(f"region {region.name}: {note}", file=sys.stderr)
    t0 = time.perf_counter()
    summary = train(
        rc,
        region,
        episodes,
        args.seed,
        out,
        checkpoint_every=args.checkpoint_every or params.train.checkpoint_every,
        resume=args.resume,
        progress=not args.no_progress,
    )
    wall = time.perf_counter() - t0
    print(
        f"trained {summary['config']}/{summary['method']} on {summary['region']} for {episodes} episodes "
        f"(seed {args.seed}) in {wall:.1f} s wall ({summary['wall_seconds']:.1f} s in the training loop); "
        f"coverage over the last 100 training episodes {summary['final_coverage_last100']:.3f}; wrote {out}/"
    )
    if "selected_episode" in summary:
        print(f"kept the actors of episode {summary['selected_episode']} (validation coverage "
              f"{summary['selected_validation_coverage']:.3f}; the last ones are in actors_last.pt)")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluate import evaluate_baseline, evaluate_run

    params = load_params(args.params, overrides(args.set))
    if (args.run is None) == (args.baseline is None):
        raise ConfigError("give exactly one of --run RUN_DIR or --baseline NAME")
    if args.run is not None:
        result = evaluate_run(args.run, params, run_region(args.run, params, args.region))
        default = Path(args.run) / "metrics.json"
    else:
        if not args.region:
            raise ConfigError("--baseline needs --region")
        region = resolve_region(args.region, params)
        result = evaluate_baseline(args.baseline, params, region, args.config)
        default = Path(f"metrics/baseline-{args.baseline}-{region.name}.json")
    out = Path(args.out) if args.out else default
    artifacts.write_json(out, result)
    cov = result["coverage"]
    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f}, {cov['n']} episodes); wrote {out}")
    return 0


def run_region(run_dir: str, params: Params, region: str | None) -> Region:
    import json

    path = Path(run_dir) / "run.json"
    if region is None and not path.exists():
        raise FileNotFoundError(f"{path}: not a run folder (no run.json); pass --region")
    return resolve_region(region or json.loads(path.read_text())["region"], params)


def cmd_cover(args: argparse.Namespace) -> int:
    import tempfile

    from .waterbody import cover, outline_file

    params = load_params(args.params, overrides(args.set))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = outline_file(args.region, args.place, args.name, Path(tmp))
        if args.place:
            artifacts.atomic_write_bytes(out / "outline.geojson", path.read_bytes())
            path = out / "outline.geojson"
        s = cover(path, params, out, args.episodes, args.seed, args.n_agents, args.radius_m, args.config,
                  not args.no_progress)
    cov, lloyd = s["coverage"], s["lloyd_coverage"]
    print(f"{s['region']}: {s['n_agents']} buoys of radius {s['radius_m']:.3g} m on {s['area_m2']:.4g} m² "
          f"({s['utm_crs']}, 1 sim m = {s['scale_m_per_sim_m']:.4g} m), T = {s['episode_length']}")
    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f}) vs Lloyd {lloyd['mean']:.3f}: "
          f"{s['ratio_to_lloyd']:.0%} of the Lloyd layout; wrote {out}/")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from .export import export_policy

    params = load_params(args.params, overrides(args.set))
    region = run_region(args.run, params, args.region)
    out = Path(args.out or Path(args.run) / "policy.pt")
    meta = export_policy(Path(args.run) / "actors.pt", region, out, params.world.sensitivity)
    print(f"exported {meta['n_agents']} actors ({meta['observation']}) for {meta['region']} to {out}")
    return 0


def cmd_act(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from .export import act

    if args.obs is not None:
        obs = np.array([[float(v) for v in row.split(",")] for row in args.obs.split(";")])
    else:
        obs = np.array(json.loads(Path(args.obs_file).read_text()))
    actions = act(args.policy, obs, real=args.real)
    print(json.dumps({f"buoy_{i}": [round(float(v), 6) for v in a] for i, a in enumerate(actions)}))
    return 0


def cmd_animate(args: argparse.Namespace) -> int:
    from .animate import animate_run

    params = load_params(args.params, overrides(args.set))
    region = run_region(args.run, params, args.region)
    out = animate_run(args.run, params, region, args.out or Path(args.run) / "episode.gif", args.seed)
    print(f"wrote {out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="replicate", description=__doc__)
    parser.add_argument("--params", default="params.yaml", help="parameters file (default: params.yaml)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help="override a value of the parameters file, e.g. configs.tuned.n_envs=25 (repeatable)")
    sub = parser.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train MADDPG (SW-MARL or CR-MARL) on a region")
    t.add_argument("--config", default="paper", help="configuration in params.yaml: paper or tuned")
    t.add_argument("--method", default="cr", help="sw (swarming, shared reward) or cr (coverage range)")
    t.add_argument("--region", default="square", help="square, rectangle, bedok, or a vector file")
    t.add_argument("--episodes", type=int, default=None, help="default: train.episodes of params.yaml")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", default=None, help="run folder (default runs/CONFIG-METHOD-REGION-sSEED)")
    t.add_argument("--checkpoint-every", type=int, default=None, help="episodes between checkpoints")
    t.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_train)

    e = sub.add_parser("evaluate", help="SPEC §8 metrics of a run or a baseline, as JSON")
    e.add_argument("--run", default=None, help="a run folder written by `replicate train`")
    e.add_argument("--baseline", default=None, help="random, naive, lloyd or lloyd_converged")
    e.add_argument("--region", default=None, help="region (default: the run's own)")
    e.add_argument("--config", default="paper", help="physics/T of this config for a baseline")
    e.add_argument("--out", default=None, help="output JSON")
    e.set_defaults(func=cmd_evaluate)

    c = sub.add_parser("cover", help="train CR-MARL on any waterbody and compare with the Lloyd layout")
    c.add_argument("--region", default=None, help="vector file (any CRS) or OSM XML (.osm) of the outline")
    c.add_argument("--place", default=None, help="an OSM place name (needs the network)")
    c.add_argument("--name", default=None, help="the water feature's name (OSM place or .osm file)")
    c.add_argument("--episodes", type=int, default=2000)
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--config", default="tuned")
    c.add_argument("--n-agents", type=int, default=None, help="number of buoys (default: world.n_agents)")
    c.add_argument("--radius-m", type=float, default=None,
                   help="real scale: coverage radius in metres (default: the paper's 9 m² scale)")
    c.add_argument("--out", default="runs/cover")
    c.add_argument("--no-progress", action="store_true")
    c.set_defaults(func=cmd_cover)

    x = sub.add_parser("export", help="export a run's actors as one TorchScript file with metadata")
    x.add_argument("--run", required=True)
    x.add_argument("--region", default=None, help="region (default: the run's own)")
    x.add_argument("--out", default=None, help="default RUN/policy.pt")
    x.set_defaults(func=cmd_export)

    a = sub.add_parser("act", help="map observations to commands with an exported policy (prints JSON)")
    a.add_argument("--policy", required=True)
    group = a.add_mutually_exclusive_group(required=True)
    group.add_argument("--obs", help='observations "x,y;x,y;..." one buoy per ";"')
    group.add_argument("--obs-file", help="JSON file with an [N, obs_dim] list")
    a.add_argument("--real", action="store_true", help="observations are UTM metres (m/s), not simulation units")
    a.set_defaults(func=cmd_act)

    m = sub.add_parser("animate", help="GIF of an evaluation episode of a run")
    m.add_argument("run")
    m.add_argument("--region", default=None)
    m.add_argument("--seed", type=int, default=None)
    m.add_argument("--out", default=None, help="default RUN/episode.gif")
    m.set_defaults(func=cmd_animate)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    warnings.simplefilter("default")
    try:
        return args.func(args)
    except (ConfigError, RegionError, CheckpointError, FileNotFoundError, ValueError) as exc:
        print(f"replicate: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("replicate: interrupted; `replicate train --resume --out RUN` continues from the last checkpoint",
              file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
