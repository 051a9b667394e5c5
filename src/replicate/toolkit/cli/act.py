"""``replicate act``: Commands for every buoy from an exported policy and their observations: once, or a stream of
steps on standard input (one JSON line each), in simulation units or in SI (``--real``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from replicate.core.schema import ConfigError


def add(sub, verb: dict, regions: str) -> None:
    """The ``act`` verb's options."""
    a = sub.add_parser("act", help="map observations to commands with an exported policy (prints JSON)", **verb)
    a.add_argument("--policy", required=True, help="a file written by `replicate export`")
    group = a.add_mutually_exclusive_group(required=True)
    group.add_argument("--obs", help='observations "x,y;x,y;..." one buoy per ";" (negative numbers welcome)')
    group.add_argument("--obs-file", help="JSON file with an [N, obs_dim] list, or - for standard input")
    group.add_argument("--stream", action="store_true",
                       help="read one step per line on standard input (a JSON [N, obs_dim] list), answer each with "
                            "a JSON line of commands [N, 2], until the input ends")
    a.add_argument("--real", action="store_true",
                   help="observations in SI: metres and m/s (a general policy: give --radius-m and --speed-ms, "
                        "or a policy exported for them); a per-region policy: UTM metres")
    a.add_argument("--radius-m", type=float, default=None, help="--real, a general policy: the sensing radius, m")
    a.add_argument("--speed-ms", type=float, default=None, help="--real, a general policy: the top speed, m/s")
    a.set_defaults(func=run)


def deployment_units(args: argparse.Namespace):
    """The SI scale ``--radius-m`` and ``--speed-ms`` give (``world.units.Units``), or None."""
    if args.radius_m is None and args.speed_ms is None:
        return None
    if not args.real or args.radius_m is None or args.speed_ms is None:
        raise ConfigError("--radius-m and --speed-ms go together, with --real: the deployment's SI scale")
    from replicate.core.params import load_params
    from replicate.toolkit.cli.inputs import overrides
    from replicate.world.units import Units

    params = load_params(args.params, overrides(args.set))
    return Units.of(params.world, params.coverage, args.radius_m, args.speed_ms)


def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np
    import torch

    from replicate.toolkit.deploy import Actor, stream

    torch.set_num_threads(1)  # one step is a few small matmuls: a second thread's hand-off costs 4x their time
    if args.obs_file not in (None, "-") and not Path(args.obs_file).is_file():
        raise ConfigError(f"--obs-file {args.obs_file}: no such file; give a JSON file with an [N, obs_dim] list, "
                          "or - for standard input")
    if args.stream:
        stream(Actor(args.policy, args.real, deployment_units(args)))
        return 0
    try:
        if args.obs is not None:
            obs = np.array([[float(v) for v in row.split(",")] for row in args.obs.split(";")])
        else:
            text = sys.stdin.read() if args.obs_file == "-" else Path(args.obs_file).read_text()
            obs = np.array(json.loads(text), dtype=float)
    except (ValueError, TypeError) as exc:
        raise ConfigError("observations must be one row of numbers per buoy, every row as long (--obs "
                          f"\"x,y;x,y;...\" or --obs-file with an [N, obs_dim] list): {exc}") from None
    if obs.ndim != 2 or not np.isfinite(obs).all():
        raise ConfigError("observations must be a table of finite numbers, one row per buoy; got "
                          f"{'non-finite values' if obs.ndim == 2 else f'shape {obs.shape}'}")
    actions = Actor(args.policy, args.real, deployment_units(args))(obs)
    print(json.dumps({f"buoy_{i}": [round(float(v), 6) for v in a] for i, a in enumerate(actions)}))
    return 0
