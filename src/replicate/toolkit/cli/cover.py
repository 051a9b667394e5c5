"""``replicate cover``: Cover any waterbody file with the general policy (zero-shot or fine-tuned) or with CR-MARL
trained there."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from replicate.core import artifacts
from replicate.core.params import Params, load_params
from replicate.core.schema import MAX_AGENTS, ConfigError, check_seed, positive
from replicate.toolkit.cli.inputs import (
    check_episodes,
    claim_run_folder,
    overrides,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``cover`` verb's options."""
    c = sub.add_parser("cover", help="cover any waterbody with the general policy (or CR-MARL trained there) and "
                                     "compare with the baselines", **verb)
    c.add_argument("--region", default=None, help="vector file (any CRS) or OSM XML (.osm) of the outline")
    c.add_argument("--place", default=None, help="an OSM place name (needs the network)")
    c.add_argument("--name", default=None, help="the water feature's name (OSM place or .osm file)")
    c.add_argument("--method", choices=("general", "cr"), default="general",
                   help="general: the general policy, zero-shot or --finetune'd (seconds to minutes); cr: CR-MARL "
                        "trained from scratch on this lake (--config, --episodes)")
    c.add_argument("--policy", default=None, metavar="FILE",
                   help="--method general: a general policy file (default: the one installed with the package, "
                        "policies/general.pt)")
    c.add_argument("--finetune", type=int, default=0, metavar="EPISODES",
                   help="--method general: train the policy on this lake for EPISODES first (rounded down to "
                        "general.n_envs); it keeps the starting weights unless training beats them on validation "
                        "starts")
    c.add_argument("--episodes", type=int, default=None,
                   help="--method cr: training episodes (default 2000, rounded to the config's n_envs)")
    c.add_argument("--seed", type=int, default=0, help="training seed (--finetune, --method cr), 0 to 2**32 - 1")
    c.add_argument("--config", default=None, help="--method cr: configuration in params.yaml (default: tuned)")
    c.add_argument("--n-agents", type=int, default=None, help="number of buoys, 1 to 200 (default: world.n_agents)")
    c.add_argument("--radius-m", type=float, default=None,
                   help="real scale: coverage radius in metres (default: the paper's 9 m² scale)")
    c.add_argument("--speed-ms", type=float, default=1.0, metavar="M_PER_S",
                   help="the buoys' top speed in m/s (default 1.0, the paper's BoB): the control period, the mission's "
                        "minutes and the timestamps of the tracks")
    c.add_argument("--out", default="my-runs/cover", help="output folder")
    c.add_argument("--force", action="store_true", help="replace what --out holds (the folder is cleared first)")
    c.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    import tempfile

    params = load_params(args.params, overrides(args.set))
    check_cover_args(args, params)
    out = Path(args.out)
    replacing = args.force and out.is_dir() and any(out.iterdir())
    created = claim_run_folder(out, args.force, args.held)
    run = out / "run"
    try:
        s = cover_into(args, params, out, tempfile)
    except BaseException:
        # read now: once the command ends, a replaced result is put back in place of this run
        args.interrupted_hint = (f"what {out} held before is back in place" if replacing
                                 else interrupted_hint(run))
        if created and not args.interrupted_hint:
            import shutil

            shutil.rmtree(out, ignore_errors=True)  # refused or interrupted before training: leave nothing behind
        raise
    print_cover(args, s, out)
    return 0


def interrupted_hint(run: Path) -> str:
    """What continues a ``cover --method cr`` stopped in ``run``: resuming its training, or (trained to the end)
    evaluating it; "" when it had not trained enough to keep (nothing to keep)."""
    if (run / "checkpoint.pt").exists():
        return (f"`replicate train --resume {run}` continues the training, and `replicate evaluate {run}` then "
                "measures it")
    try:
        finished = json.loads((run / "run.json").read_text()).get("status") == "finished"
    except (OSError, ValueError, AttributeError):
        finished = False
    return f"the training had finished: `replicate evaluate {run}` measures it" if finished else ""


def check_cover_args(args: argparse.Namespace, params: Params) -> None:
    """Refuse a bad combination of `cover`'s options by name, before anything is written; fill the defaults of
    ``--method cr`` and the general policy's file."""
    check_seed(args.seed)
    check_episodes(args.episodes)
    check_episodes(args.finetune, "--finetune")
    if args.method == "general":
        if args.episodes is not None:
            raise ConfigError("--episodes goes with --method cr; the general policy is fine-tuned with --finetune "
                              "EPISODES")
        if args.config is not None:
            raise ConfigError("--config goes with --method cr; the general policy has its own training values")
        n_envs = params.general.n_envs
        if args.finetune < 0 or 0 < args.finetune < n_envs:
            raise ConfigError(f"--finetune must be 0 (zero-shot) or at least general.n_envs ({n_envs}) episodes, "
                              f"got {args.finetune}")
        args.policy = general_policy_file(args.policy)
        from replicate.compare.evaluate import read_general_policy

        read_general_policy(args.policy)  # refused by name before anything is written
    else:
        if args.policy is not None or args.finetune:
            raise ConfigError("--policy and --finetune go with --method general")
        args.episodes = 2000 if args.episodes is None else args.episodes
        args.config = "tuned" if args.config is None else args.config
        if args.episodes < 1:
            raise ConfigError(f"--episodes must be at least 1, got {args.episodes}")
    if args.radius_m is not None:
        positive(args.radius_m, "--radius-m")
    positive(args.speed_ms, "--speed-ms")
    if args.n_agents is not None and not 1 <= args.n_agents <= MAX_AGENTS:
        raise ConfigError(f"--n-agents must be between 1 and {MAX_AGENTS}, got {args.n_agents}")
    if args.region is not None:
        from replicate.toolkit.cover import outline_path

        outline_path(args.region)  # before the output folder is made


def share(fraction: float) -> str:
    """A share of the lake as a field team reads it: a percentage to three significant digits (nine 25 m buoys on
    a 5 km² lake cover 0.322 %, which three decimals of a fraction would print as 0.003)."""
    return f"{100 * fraction:.3g} %"


def print_cover(args: argparse.Namespace, s: dict, out: Path) -> None:
    """The summary of a `cover` run, as the user reads it."""
    cov, lloyd = s["coverage"], s["lloyd_coverage"]
    chosen = "" if args.radius_m else " (the paper's density; give --radius-m for your buoys)"
    print(f"{s['region']} (centred at {s['centre']}): {s['n_agents']} buoys of radius {s['radius_m']:.3g} m{chosen} "
          f"on {s['area_m2']:.4g} m² ({s['utm_crs']}, 1 sim m = {s['scale_m_per_sim_m']:.4g} m); at "
          f"{s['top_speed_ms']:g} m/s a control period of {s['control_period_s']:.3g} s, {s['episode_length']} "
          f"periods: a mission of {s['mission_s'] / 60:.1f} min (its episode for a GIS: episode.gpkg)")
    if args.method == "general":
        best = s["baselines"]["best_layout"]["coverage"]["mean"]
        lloyd_name = "tuned Lloyd" if s["lloyd_baseline"] == "lloyd_tuned" else "Lloyd"
        print(f"general policy{' fine-tuned' if args.finetune else ', zero-shot'}: coverage {share(cov['mean'])} of "
              f"the lake (95 % CI {share(cov['lo'])}-{share(cov['hi'])} over evaluation episodes) vs {lloyd_name} "
              f"{share(lloyd['mean'])} ({s['ratio_to_lloyd']:.0%}) and the best layout {share(best)} "
              f"({s['ratio_to_best']:.0%}); no buoy left the water by more than {s['max_outside_m']:.3g} m; "
              f"wrote {out}/")
        return
    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over evaluation episodes of this one "
          f"trained policy; another training seed can land outside it) vs Lloyd {lloyd['mean']:.3f}: "
          f"{s['ratio_to_lloyd']:.0%} of the Lloyd layout; wrote {out}/")


def general_policy_file(path: str | None) -> Path:
    """The general policy to cover with: ``path``, or the one installed with the package."""
    from replicate.core.params import packaged

    policy = Path(path) if path is not None else packaged("general.pt")
    if not policy.is_file():
        raise ConfigError(f"--policy {policy}: no such file; give a general policy (`replicate export` of a general "
                          "run, or policies/general.pt of the pipeline)" if path else
                          f"{policy}: the installed general policy is missing; reinstall the package, or give "
                          "--policy FILE")
    return policy


def cover_into(args: argparse.Namespace, params: Params, out: Path, tempfile) -> dict:
    from replicate.toolkit.cover import cover, cover_general, outline_file

    with tempfile.TemporaryDirectory() as tmp:
        path = outline_file(args.region, args.place, args.name, Path(tmp))
        if args.place:
            artifacts.atomic_write_bytes(out / "outline.geojson", path.read_bytes())
            path = out / "outline.geojson"
        if args.method == "general":
            return cover_general(path, params, out, args.policy, args.finetune, args.seed, args.n_agents,
                                 args.radius_m, not args.no_progress, args.speed_ms)
        return cover(path, params, out, args.episodes, args.seed, args.n_agents, args.radius_m, args.config,
                     not args.no_progress, args.speed_ms)
