"""``replicate export``: A run's actors as one TorchScript file with its metadata; or an exported general policy
again, with its control contract for one deployment's SI scale (``--policy FILE --radius-m R --speed-ms V``)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from replicate.core.params import load_params
from replicate.core.schema import ConfigError
from replicate.toolkit.cli.inputs import (
    claim_out_file,
    overrides,
    run_region,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``export`` verb's options."""
    x = sub.add_parser("export", help="export a run's actors as one TorchScript file with metadata", **verb)
    x.add_argument("run", nargs="?", default=None, help="a run folder written by `replicate train`")
    x.add_argument("--run", dest="run_option", default=None, help=argparse.SUPPRESS)
    x.add_argument("--region", default=None, help=f"{regions} (default: the run's own)")
    x.add_argument("--out", default=None, help="TorchScript file (default: RUN/policy.pt)")
    x.add_argument("--force", action="store_true", help="replace --out if it exists")
    x.add_argument("--baseline-gains", default=None, metavar="FILE",
                   help="a general run: carry these baseline gains (`replicate tune general-baselines`) in the "
                        "policy, for `evaluate --policy` to compare with")
    x.add_argument("--lloyd-prior", type=float, default=0.0, metavar="G",
                   help="a general run trained without a Lloyd prior: add Lloyd's law toward the local centroid at "
                        "deployment: a = tanh(network + G x the offset), G per simulation metre (0: none)")
    d = x.add_argument_group("an exported general policy, for one deployment (instead of a run)")
    d.add_argument("--policy", default=None, metavar="FILE", help="a general policy file to re-export with its "
                   "control contract in SI (control period, units of every input, the action's velocity)")
    d.add_argument("--radius-m", type=float, default=None, help="the buoys' sensing radius, metres")
    d.add_argument("--speed-ms", type=float, default=None, help="the buoys' top speed, m/s")
    d.add_argument("--onnx", default=None, metavar="FILE", help="also write the policy as ONNX, for runtimes "
                   "without torch (needs `pip install '.[onnx]'`)")
    x.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    from replicate.toolkit.export import export_general, export_policy

    params = load_params(args.params, overrides(args.set))
    if args.policy is not None or args.radius_m is not None or args.speed_ms is not None:
        return export_deployment(args, params)
    if args.run is None:
        raise ConfigError("export needs a run folder (`replicate export RUN`) or a general policy with the "
                          "deployment's scale (`--policy FILE --radius-m R --speed-ms V --out FILE`)")
    if (Path(args.run) / "actor.pt").exists():  # a general run: one shared actor for any fleet and lake
        if args.region is not None:
            raise ConfigError(f"{args.run}: a general run has no region of its own; export it without --region")
        if not (math.isfinite(args.lloyd_prior) and args.lloyd_prior >= 0):
            raise ConfigError(f"--lloyd-prior is a gain per simulation metre, 0 or above: got {args.lloyd_prior}")
        if args.lloyd_prior and args.out is None:
            raise ConfigError("--lloyd-prior writes another policy than the run's own RUN/policy.pt: give --out FILE")
        gains = read_baseline_gains(args.baseline_gains)
        out = claim_out_file(Path(args.out or Path(args.run) / "policy.pt"), args.force, held=args.held)
        export_general(Path(args.run) / "actor.pt", out, params.world.sensitivity, gains, args.lloyd_prior)
        print(f"exported the general policy (any fleet, local sensors) to {out}"
              + (f", with the baselines' gains of {args.baseline_gains}" if gains else "")
              + (f", with Lloyd's law added at a gain of {args.lloyd_prior:g}" if args.lloyd_prior else ""))
        return 0
    if args.baseline_gains is not None or args.lloyd_prior:
        raise ConfigError("--baseline-gains and --lloyd-prior go with a general run; a per-region run has its own "
                          "baselines and no prior")
    region = run_region(args.run, params, args.region)
    out = claim_out_file(Path(args.out or Path(args.run) / "policy.pt"), args.force, held=args.held)
    meta = export_policy(Path(args.run) / "actors.pt", region, out, params.world.sensitivity)
    print(f"exported {meta['n_agents']} actors ({meta['observation']}) for {meta['region']} to {out}")
    return 0


def export_deployment(args: argparse.Namespace, params) -> int:
    """``export --policy FILE --radius-m R --speed-ms V --out FILE``: the general policy with its SI contract."""
    from replicate.toolkit.deploy import export_for
    from replicate.world.units import Units

    if args.run is not None or args.region is not None or args.baseline_gains is not None or args.lloyd_prior:
        raise ConfigError("--policy re-exports an exported general policy; give no run folder, --region, "
                          "--baseline-gains or --lloyd-prior with it")
    if args.onnx is not None:
        try:
            import onnx  # noqa: F401 - the extra this option needs
        except ImportError:
            raise ConfigError("--onnx needs the onnx extra: pip install '.[onnx]'") from None
    if args.policy is None or args.radius_m is None or args.speed_ms is None or args.out is None:
        raise ConfigError("a deployment's export needs --policy FILE, --radius-m, --speed-ms and --out FILE")
    if not Path(args.policy).is_file():
        raise ConfigError(f"--policy {args.policy}: no such file")
    units = Units.of(params.world, params.coverage, args.radius_m, args.speed_ms)
    out = claim_out_file(Path(args.out), args.force, held=args.held)
    onnx_out = None if args.onnx is None else claim_out_file(Path(args.onnx), args.force, "--onnx", held=args.held)
    si = export_for(args.policy, out, params, units, onnx_out)["contract"]["si"]
    print(f"exported {args.policy} for buoys of {si['radius_m']:g} m at {si['top_speed_ms']:g} m/s to {out}: a "
          f"control period of {si['control_period_s']:.4g} s, radio and shore ranges {si['comm_range_m']:g} m and "
          f"{si['shore_range_m']:g} m (metadata.json: contract)" + (f"; and as ONNX to {onnx_out}" if onnx_out else ""))
    return 0


def read_baseline_gains(path: str | None) -> dict | None:
    """The general baselines' study result (``replicate tune general-baselines``), checked, or None."""
    import json

    if path is None:
        return None
    from replicate.core.schema import build
    from replicate.core.studies import LloydConfig, NaiveConfig

    try:
        gains = json.loads(Path(path).read_text())
        build(NaiveConfig, gains["naive_tuned"]["gains"], "naive_tuned.gains")  # finite numbers, every gain
        for lloyd in ("lloyd_tuned", "decentralised_tuned", "geodesic_tuned"):  # the other two where the study has them
            if lloyd in gains or lloyd == "lloyd_tuned":
                build(LloydConfig, {**gains[lloyd]["gains"], "converged_steps": 0}, f"{lloyd}.gains")
    except FileNotFoundError:
        raise ConfigError(f"--baseline-gains {path}: no such file; `replicate tune general-baselines` writes it") \
            from None
    except ConfigError as exc:
        raise ConfigError(f"--baseline-gains {path}: not the general baselines' gains ({exc}); write it with "
                          "`replicate tune general-baselines`") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"--baseline-gains {path}: not the general baselines' gains ({type(exc).__name__}: "
                          f"{exc}); write it with `replicate tune general-baselines`") from None
    return gains
