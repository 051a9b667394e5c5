"""``replicate animate``: A GIF of an evaluation episode of a run, in metres and minutes."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from replicate.core.params import load_params
from replicate.core.schema import ConfigError, check_seed
from replicate.toolkit.cli.inputs import (
    claim_out_file,
    overrides,
    run_region,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``animate`` verb's options."""
    m = sub.add_parser("animate", help="GIF of an evaluation episode of a run", **verb)
    m.add_argument("run", help="a run folder written by `replicate train`")
    m.add_argument("--region", default=None, help=f"{regions} (default: the run's own)")
    m.add_argument("--seed", type=int, default=None, help="starts of the episode (default: evaluate.seed)")
    m.add_argument("--speed-ms", type=float, default=1.0, metavar="M_PER_S",
                   help="the buoys' top speed in m/s (default 1.0, the paper's BoB): the clock's seconds; the map is "
                        "in metres (the lake's UTM zone where it has one)")
    m.add_argument("--out", default=None, help="GIF file (default: RUN/episode.gif)")
    m.add_argument("--force", action="store_true", help="replace --out if it exists")
    m.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    params = load_params(args.params, overrides(args.set))
    region = run_region(args.run, params, args.region)
    if args.seed is not None:
        check_seed(args.seed)
    if not (math.isfinite(args.speed_ms) and args.speed_ms > 0):
        raise ConfigError(f"--speed-ms must be a positive number of m/s, got {args.speed_ms}")
    out = claim_out_file(Path(args.out or Path(args.run) / "episode.gif"), args.force, held=args.held)
    from replicate.toolkit.animate import (
        animate_run,  # matplotlib's import is seconds: only once the inputs are known good
    )

    out = animate_run(args.run, params, region, out, args.seed, progress=not args.no_progress,
                      speed_ms=args.speed_ms)
    print(f"wrote {out}")
    return 0
