"""``replicate compare``: Two versions of the general training, several seeds each, on the yardstick."""

from __future__ import annotations

import argparse
from pathlib import Path

from replicate.core import artifacts
from replicate.core.params import load_params, packaged
from replicate.core.schema import ConfigError
from replicate.toolkit.cli.inputs import (
    claim_out_file,
    overrides,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``compare`` verb's options."""
    v = sub.add_parser("compare", help="two versions of the general training, several seeds each, on the yardstick's "
                       "lakes (never trained on, never reported): keep the candidate only if it wins over seeds",
                       **verb)
    v.add_argument("--baseline", nargs="+", default=None, metavar="POLICY",
                   help="the baseline version's exported policies, one per training seed (at least "
                        "yardstick.min_seeds; default: the standing baseline in yardstick/ beside --params (or of the "
                        "working folder), the "
                        "current training values on yardstick.seeds, written by the train_yardstick stage)")
    v.add_argument("--candidate", nargs="+", required=True, metavar="POLICY",
                   help="the candidate version's exported policies, one per training seed (at least "
                        "yardstick.min_seeds)")
    v.add_argument("--out", required=True, help="output JSON: every cell, each seed's score and the verdict")
    v.add_argument("--force", action="store_true", help="replace --out if it exists")
    v.add_argument("--workers", type=int, default=None, help="processes, one lake each (default: pipeline.workers)")
    v.add_argument("--executor", choices=("local", "ray"), default=None,
                   help="local processes or Ray tasks (default: pipeline.executor)")
    v.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    """Two versions of the general training, several seeds each, on the yardstick (``compare.yardstick``)."""
    from replicate.compare.yardstick import STANDING, Versions, check_versions, compare_versions, standing_baseline
    from replicate.core.executor import configured_executor

    params = load_params(args.params, overrides(args.set))
    beside = Path(args.params).parent if args.params else Path(".")  # the working folder without --params
    baseline = tuple(args.baseline) if args.baseline else standing_baseline(params, beside / STANDING)
    versions = Versions(baseline, tuple(args.candidate))
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    check_versions(versions, params.yardstick.min_seeds)
    out = claim_out_file(Path(args.out), args.force, held=args.held)
    workers = args.workers or params.stages.get("pipeline", {}).get("workers", 1)
    executor = configured_executor(params, args.executor)
    d = params.yardstick
    standing = "" if args.baseline else f" (the baseline: {STANDING}/)"
    runs_on = f"{workers} worker(s)" if executor == "local" else "Ray tasks"
    cells = d.lakes * len(d.fleets) * len(d.starts) * len(d.events)
    print(f"{cells} cells (yardstick lakes x fleets x starts x events), {len(baseline) + len(args.candidate)} "
          f"policies{standing}, {runs_on}")
    result = compare_versions(args.params or str(packaged("params.yaml")), versions, workers, executor,
                              overrides(args.set), not args.no_progress)
    artifacts.write_json(out, result)
    for label, score in result["scores"].items():
        print(f"{label} {result['policies'][label]}: coverage / lloyd_tuned {score:.4f}")
    v = result["verdict"]
    d, p = v["difference"], v["probability_of_improvement"]
    print(f"candidate - baseline {d['delta']:+.4f} (interval over seeds {d['lo']:+.4f} to {d['hi']:+.4f}); "
          f"P(a candidate seed beats a baseline seed) {p['p']:.2f}")
    print(f"rule: {v['rule']}; keep the {v['keep']}; wrote {out}")
    return 0
