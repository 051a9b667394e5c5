"""``replicate act``: Commands for every buoy from an exported policy and their observations."""

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
    a.add_argument("--real", action="store_true", help="observations are UTM metres (m/s), not simulation units")
    a.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from replicate.toolkit.export import act

    if args.obs_file not in (None, "-") and not Path(args.obs_file).is_file():
        raise ConfigError(f"--obs-file {args.obs_file}: no such file; give a JSON file with an [N, obs_dim] list, "
                          "or - for standard input")
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
    actions = act(args.policy, obs, real=args.real)
    print(json.dumps({f"buoy_{i}": [round(float(v), 6) for v in a] for i, a in enumerate(actions)}))
    return 0
