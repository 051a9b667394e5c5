"""What the benchmarks that read the standing baseline's seeds on the yardstick share (`settle.py`,
`deploy_prior.py`): where the seeds are (stage train_yardstick), the command line's common options and checks, and
the summary of their rows per event and start."""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

FOLDER = "yardstick/runs/general-s{}/"  # the standing baseline's seed S: actor.pt, policy.pt
GROUPS = ("all", "none", "lose", "current", "corner", "random")


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
