"""``replicate tune``: Optuna studies: the baselines' gains, a method's training values, the general baselines'
gains."""

from __future__ import annotations

import argparse
from pathlib import Path

from replicate.core import artifacts
from replicate.core.params import load_params
from replicate.toolkit.cli.inputs import (
    claim_out_file,
    overrides,
    resolve_region,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``tune`` verb's options."""
    u = sub.add_parser("tune", help="Optuna studies: the baselines' gains, or a method's training values", **verb)
    u.add_argument("what", choices=("baselines", "method", "general-baselines"),
                   help="baselines: every gain of naive swarming and Lloyd per region (tuning.baselines); method: "
                        "tuning.method's training values (trials train on the tuning seeds); general-baselines: "
                        "one set of naive and Lloyd gains for every lake, on the general policy's training worlds "
                        "behind the wall (tuning.general_baselines)")
    u.add_argument("--out", default=None,
                   help="JSON of the best values (default: metrics/tuning/baselines.json, tuning.method.result or "
                        "tuning.general_baselines.result)")
    u.add_argument("--executor", choices=("local", "ray"), default=None,
                   help="where trials run: local (one after another) or ray (Ray tasks; RAY_ADDRESS joins a "
                        "cluster; several `replicate tune` may share one study through a storage URL) (default: "
                        "pipeline.executor)")
    u.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    from replicate.compare.tuning import tune_baselines, tune_general_baselines, tune_method
    from replicate.core.executor import configured_executor

    params = load_params(args.params, overrides(args.set))
    executor = configured_executor(params, args.executor)
    ms = params.tuning.method
    default = {"baselines": "metrics/tuning/baselines.json", "method": ms.result,
               "general-baselines": params.tuning.general_baselines.result}[args.what]
    # checked before the study runs; a study's result is written again from its storage, so it replaces the old
    out = claim_out_file(Path(args.out or default), force=True, held=args.held)
    shown = not args.no_progress
    if args.what == "baselines":
        names = params.stages.get("pipeline", {}).get("regions", list(params.regions))
        result = tune_baselines(params, {r: resolve_region(r, params) for r in names}, executor, shown)
        artifacts.write_json(out, result)
        for key, b in result.items():
            print(f"{key}: tuning coverage {b['tuning_coverage']:.3f} with {b['gains']} ({b['trials']} trials)")
    elif args.what == "general-baselines":
        result = tune_general_baselines(params, executor, params.stages.get("pipeline", {}).get("workers", 1), shown)
        artifacts.write_json(out, result)
        for key, b in result.items():
            print(f"{key}: coverage {b['tuning_coverage']:.3f} on the training worlds with {b['gains']} "
                  f"({b['trials']} trials, {b['cpu_seconds']:.0f} CPU s)")
    else:
        result = tune_method(params, {r: resolve_region(r, params) for r in ms.regions}, executor, shown)
        artifacts.write_json(out, result)
        print(f"{ms.config} {ms.method.upper()}-MARL: tuning coverage {result['tuning_coverage']:.3f} with "
              f"{result['values']} ({result['trials']} trials, {result['cpu_seconds']:.0f} CPU s); set them as "
              f"configs.{ms.config}.per_method.{ms.method} in params.yaml to adopt them")
    print(f"wrote {out}")
    return 0
