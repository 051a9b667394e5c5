"""The ``replicate`` command: ``train``, ``evaluate``, ``cover``, ``export``, ``act``, ``animate``
(``replicate COMMAND --help`` for the options)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
import warnings
from pathlib import Path

import shapely
from shapely import affinity

from . import artifacts
from .artifacts import CheckpointError
from .config import MAX_AGENTS, ConfigError, Params, check_seed, load_params, positive, run_config
from .regions import Region, RegionError, make_region, read_run_region, region_from_file, write_run_region


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


def resume_command(run: Path) -> str:
    import shlex

    return f"replicate train --resume {shlex.quote(str(run))}"


def claim_out_file(out: Path, force: bool, option: str = "--out") -> Path:
    """Check an output file before any work: not a folder, in a folder that exists (or can be made) and can be
    written, and not a finished result unless ``force``."""
    out = Path(out)
    if out.is_dir():
        raise ConfigError(f"{option} {out}: is a folder; give the path of a file")
    if out.exists() and not force:
        raise ConfigError(f"{option} {out}: exists; pass --force to replace it, or choose another path")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{option} {out}: cannot create its folder ({exc.strerror}); choose a writable folder") \
            from None
    if not os.access(out.parent, os.W_OK):
        raise ConfigError(f"{option} {out}: its folder is not writable; choose a writable folder")
    return out


def claim_run_folder(out: Path, force: bool) -> bool:
    """Make ``out`` ready for a new run: refuse a folder that holds a run (finished or interrupted) or anything
    else, unless ``force``, which clears it first. → whether the folder was created here (so that a run that
    fails before writing anything can leave no empty folder behind)."""
    import json
    import shutil

    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file, not a folder; choose a folder")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            run = out / "run.json"
            if (out / "checkpoint.pt").exists():
                raise ConfigError(f"--out {out}: holds an interrupted run; continue it with `{resume_command(out)}`, "
                                  "or pass --force to start over")
            if run.exists() and json.loads(run.read_text()).get("status") == "finished":
                d = json.loads(run.read_text())
                raise ConfigError(f"--out {out}: holds a finished run ({d.get('config')}/{d.get('method')} on "
                                  f"{d.get('region')}, seed {d.get('seed')}, {d.get('episodes')} episodes); pass "
                                  "--force to replace it, or choose another --out")
            raise ConfigError(f"--out {out}: is not empty; pass --force to clear it, or choose another --out")
        shutil.rmtree(out)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create the folder ({exc.strerror}); choose a writable folder") from exc
    if not os.access(out, os.W_OK):
        raise ConfigError(f"--out {out}: the folder is not writable; choose a writable folder")
    return created


def resumed_run(run: Path, params: Params):
    """(run config, region, episodes, seed) of the interrupted run in ``run``, read from its own checkpoint: the
    settings it was started with, whatever params.yaml says now."""
    import json

    from .config import RunConfig, from_mapping
    from .geometry import region_key

    if not run.is_dir():
        raise ConfigError(f"--resume {run}: no such run folder")
    if not (run / "checkpoint.pt").exists():
        status = json.loads((run / "run.json").read_text()).get("status") if (run / "run.json").exists() else None
        if status == "finished":
            raise ConfigError(f"--resume {run}: the run has already finished (nothing to continue); evaluate it "
                              f"with `replicate evaluate {run}`")
        raise ConfigError(f"--resume {run}: no checkpoint here (a run checkpoints every train.checkpoint_every "
                          "episodes; one stopped before its first checkpoint starts again with --force)")
    ident = artifacts.torch_load(run / "checkpoint.pt").get("identity", {})
    try:
        rc = from_mapping(RunConfig, ident["params"], f"{run}/checkpoint.pt")
        episodes, seed, name = int(ident["episodes"]), int(ident["seed"]), ident["region"]
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{run}/checkpoint.pt: checkpoint is incomplete or mismatched ({exc})") from exc
    region = read_run_region(run) or resolve_region(name, params)
    if region_key(region.polygon) != ident.get("region_key"):
        raise CheckpointError(f"{run}: region {name!r} is not the one the run was started on")
    return rc, region, episodes, seed


def cmd_train(args: argparse.Namespace) -> int:
    from .train import check_schedule, train

    params = load_params(args.params, overrides(args.set))
    every = args.checkpoint_every if args.checkpoint_every is not None else params.train.checkpoint_every
    if args.resume:
        out = Path(args.resume)
        rc, region, episodes, seed = resumed_run(out, params)
    else:
        rc = run_config(params, args.config, args.method, args.region)
        region = resolve_region(args.region, params)
        episodes = args.episodes if args.episodes is not None else params.train.episodes
        seed = check_seed(args.seed)
        out = Path(args.out or f"runs/{args.config}-{args.method}-{region.name}-s{seed}")
    for note in region.notes:
        print(f"region {region.name}: {note}", file=sys.stderr)
    args.interrupted_hint = f"`{resume_command(out)}` continues from the last checkpoint"
    check_schedule(rc, episodes, every)
    created = False
    if not args.resume:
        created = claim_run_folder(out, args.force)
        write_run_region(out, region)  # so --resume, evaluate and export need only the folder
    t0 = time.perf_counter()
    try:
        summary = train(rc, region, episodes, seed, out,
                        checkpoint_every=every, resume=args.resume is not None, progress=not args.no_progress)
    except (ConfigError, ValueError):
        if created and not (out / "checkpoint.pt").exists():  # refused before training: leave nothing behind
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise
    wall = time.perf_counter() - t0
    print(
        f"trained {summary['config']}/{summary['method']} on {summary['region']} for {episodes} episodes "
        f"(seed {seed}) in {wall:.1f} s wall ({summary['wall_seconds']:.1f} s in the training loop); "
        f"coverage over the last 100 training episodes {summary['final_coverage_last100']:.3f}; wrote {out}/"
    )
    if "selected_episode" in summary:
        print(f"kept the actors of episode {summary['selected_episode']} (validation coverage "
              f"{summary['selected_validation_coverage']:.3f}; the last ones are in actors_last.pt)")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluate import evaluate_baseline, evaluate_run

    params = load_params(args.params, overrides(args.set))
    if args.policy is not None:
        return evaluate_general(args, params)
    given = [flag for flag, value, default in (("--n-agents", args.n_agents, None), ("--starts", args.starts, "corner"),
                                               ("--lose", args.lose, 0), ("--current", args.current, None),
                                               ("--geodesic", args.geodesic, False))
             if value != default]
    if given:
        raise ConfigError(f"{', '.join(given)}: options of a general policy; give --policy FILE with them")
    if (args.run is None) == (args.baseline is None):
        raise ConfigError("give exactly one of a run folder (`replicate evaluate RUN`) or --baseline NAME")
    if args.baseline is not None and not args.region:
        raise ConfigError("--baseline needs --region")
    region = run_region(args.run, params, args.region) if args.run is not None else \
        resolve_region(args.region, params)
    default = (Path(args.run) / "metrics.json" if args.run is not None
               else Path(f"metrics/baseline-{args.baseline}-{region.name}.json"))
    out = claim_out_file(Path(args.out) if args.out else default, args.force)
    if args.run is not None:
        result = evaluate_run(args.run, params, region, progress=True)
    else:
        result = evaluate_baseline(args.baseline, params, region, args.config, progress=True)
    artifacts.write_json(out, result)
    cov = result["coverage"]
    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over {cov['n']} evaluation episodes "
          f"of this trained policy; a training seed of its own can land outside it); wrote {out}")
    return 0


def evaluate_general(args: argparse.Namespace, params: Params) -> int:
    """``evaluate --policy``: a general policy on ``--region`` with its fleet, starts and events."""
    from .evaluate import evaluate_policy, lloyd_name

    if args.run is not None or args.baseline is not None or args.config != "paper":
        raise ConfigError("--policy evaluates a general policy; give no run folder, --baseline or --config with it")
    if not args.region:
        raise ConfigError("--policy needs --region (square, rectangle, bedok or a vector file)")
    if not Path(args.policy).is_file():
        raise ConfigError(f"--policy {args.policy}: no such file; export a general run with `replicate export`")
    from .evaluate import general_policy

    general_policy(args.policy)  # refused by name before any work if it is not a general policy
    n = params.world.n_agents if args.n_agents is None else args.n_agents
    if not 2 <= n <= MAX_AGENTS:
        raise ConfigError(f"--n-agents must be from 2 to {MAX_AGENTS}, got {n}")
    if not 0 <= args.lose < n:
        raise ConfigError(f"--lose must be from 0 to {n - 1} (a fleet of {n} keeps at least one), got {args.lose}")
    current = None
    if args.current is not None:
        try:
            current = tuple(float(v) for v in args.current.split(","))
        except ValueError:
            current = ()
        if len(current) != 2 or not all(math.isfinite(v) for v in current):
            raise ConfigError(f"--current expects two numbers U,V (simulation m/s), got {args.current!r}")
    region = resolve_region(args.region, params)
    s = math.sqrt(n / params.world.n_agents)  # the paper's density for any fleet: 9 buoys on 9 m²
    region = dataclasses.replace(region, polygon=affinity.scale(region.polygon, s, s, origin=(0, 0)),
                                 scale=region.scale / s)
    out = claim_out_file(Path(args.out or f"policy-{region.name}-n{n}.json"), args.force)
    result = evaluate_policy(args.policy, region, params, n, args.starts, args.lose, current,
                             geodesic=args.geodesic)
    artifacts.write_json(out, result)
    cov, rivals = result["coverage"], result["baselines"]
    lloyd = rivals[lloyd_name(rivals)]

    def ratio(key):
        return "n/a" if result[key] is None else f"{result[key]:.3f}"

    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over {cov['n']} evaluation episodes); "
          f"Lloyd {lloyd['coverage']['mean']:.3f} (gains {lloyd['gains']}), ratio {ratio('ratio_to_lloyd')}; "
          f"best layout {rivals['best_layout']['coverage']['mean']:.3f}, ratio {ratio('ratio_to_best')}; "
          f"furthest outside the water {result['max_outside_m']:.3g} m; wrote {out}")
    return 0


def run_record(run: Path) -> dict:
    """A run folder's ``run.json``, refused by name when it is missing, unreadable or not a run's record."""
    import json

    path = Path(run) / "run.json"
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{run}: not a run folder (no run.json); give a folder that `replicate train` "
                              "wrote") from None
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: not a readable run record ({exc}); the run folder is damaged") from None
    if isinstance(record, dict) and "general" in record:
        raise CheckpointError(f"{run}: a general run (one policy for any lake); `replicate export {run}`, then "
                              "`replicate evaluate --policy FILE --region R`")
    if not isinstance(record, dict) or "region" not in record:
        raise CheckpointError(f"{path}: not a run's record (no region); the run folder is damaged")
    return record


def run_region(run_dir: str, params: Params, region: str | None) -> Region:
    """The region to evaluate a run on: ``region`` if given, else the run's own (recorded in the run folder by
    ``write_run_region``, or named in its run.json)."""
    own_name = run_record(Path(run_dir))["region"]
    own = read_run_region(Path(run_dir))
    if region is None:
        return own if own is not None else resolve_region(own_name, params)
    chosen = resolve_region(region, params)
    if chosen.name != own_name:
        print(f"note: {run_dir} was trained on {own_name!r}; evaluating it on {chosen.name!r} (its actors observe "
              "absolute positions, so they know only the region they were trained on)", file=sys.stderr)
    return chosen


def cmd_train_general(args: argparse.Namespace) -> int:
    """``train-general``: one seed of the general policy into ``--out`` (no checkpoints: an interrupted run starts
    again; 3,000 episodes take about half an hour of one core)."""
    import shutil

    from .pipeline.general import train_recorded
    from .train import training_process

    params = load_params(args.params, overrides(args.set))
    check_seed(args.seed)
    config = params.general
    if args.episodes is not None:
        if args.episodes < config.n_envs:
            raise ConfigError(f"--episodes must be at least general.n_envs ({config.n_envs}), got {args.episodes}")
        config = dataclasses.replace(config, episodes=args.episodes)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: a file, not a folder; choose a folder for the run")
    if out.exists() and any(out.iterdir()):
        if not args.force:
            raise ConfigError(f"--out {out}: holds a run already; choose a new folder or pass --force to replace it")
        shutil.rmtree(out)
    training_process()
    # recorded as the stages record a seed: train_general or train_design keeps this run when its values match
    summary = train_recorded(dataclasses.replace(params, general=config), args.seed, out, not args.no_progress)
    print(f"best validation coverage {summary['selected_validation_coverage']:.3f} at episode "
          f"{summary['selected_episode']}; wrote {out} (`replicate export {out}` makes its policy file)")
    return 0


def cmd_cover(args: argparse.Namespace) -> int:
    import tempfile

    params = load_params(args.params, overrides(args.set))
    check_cover_args(args, params)
    out = Path(args.out)
    created = claim_run_folder(out, args.force)
    try:
        s = cover_into(args, params, out, tempfile)
    except BaseException:
        if created and not (out / "run" / "checkpoint.pt").exists():
            import shutil

            shutil.rmtree(out, ignore_errors=True)  # refused or interrupted before training: leave nothing behind
        raise
    print_cover(args, s, out)
    return 0


def check_cover_args(args: argparse.Namespace, params: Params) -> None:
    """Refuse a bad combination of `cover`'s options by name, before anything is written; fill the defaults of
    ``--method cr`` and the general policy's file."""
    check_seed(args.seed)
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
        from .evaluate import general_policy

        general_policy(args.policy)  # refused by name before anything is written
    else:
        if args.policy is not None or args.finetune:
            raise ConfigError("--policy and --finetune go with --method general")
        args.episodes = 2000 if args.episodes is None else args.episodes
        args.config = "tuned" if args.config is None else args.config
        if args.episodes < 1:
            raise ConfigError(f"--episodes must be at least 1, got {args.episodes}")
    if args.radius_m is not None:
        positive(args.radius_m, "--radius-m")
    if args.n_agents is not None and not 1 <= args.n_agents <= MAX_AGENTS:
        raise ConfigError(f"--n-agents must be between 1 and {MAX_AGENTS}, got {args.n_agents}")


def print_cover(args: argparse.Namespace, s: dict, out: Path) -> None:
    """The summary of a `cover` run, as the user reads it."""
    cov, lloyd = s["coverage"], s["lloyd_coverage"]
    print(f"{s['region']}: {s['n_agents']} buoys of radius {s['radius_m']:.3g} m on {s['area_m2']:.4g} m² "
          f"({s['utm_crs']}, 1 sim m = {s['scale_m_per_sim_m']:.4g} m), T = {s['episode_length']}")
    if args.method == "general":
        best = s["baselines"]["best_layout"]["coverage"]["mean"]
        lloyd_name = "tuned Lloyd" if s["lloyd_baseline"] == "lloyd_tuned" else "Lloyd"
        print(f"general policy{' fine-tuned' if args.finetune else ', zero-shot'}: coverage {cov['mean']:.3f} "
              f"(95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over evaluation episodes) vs {lloyd_name} {lloyd['mean']:.3f} "
              f"({s['ratio_to_lloyd']:.0%}) and the best layout {best:.3f} ({s['ratio_to_best']:.0%}); "
              f"no buoy left the water by more than {s['max_outside_m']:.3g} m; wrote {out}/")
        return
    print(f"coverage {cov['mean']:.3f} (95 % CI {cov['lo']:.3f}-{cov['hi']:.3f} over evaluation episodes of this one "
          f"trained policy; another training seed can land outside it) vs Lloyd {lloyd['mean']:.3f}: "
          f"{s['ratio_to_lloyd']:.0%} of the Lloyd layout; wrote {out}/")


def general_policy_file(path: str | None) -> Path:
    """The general policy to cover with: ``path``, or the one installed with the package."""
    from .config import packaged

    policy = Path(path) if path is not None else packaged("general.pt")
    if not policy.is_file():
        raise ConfigError(f"--policy {policy}: no such file; give a general policy (`replicate export` of a general "
                          "run, or policies/general.pt of the pipeline)" if path else
                          f"{policy}: the installed general policy is missing; reinstall the package, or give "
                          "--policy FILE")
    return policy


def cover_into(args: argparse.Namespace, params: Params, out: Path, tempfile) -> dict:
    from .waterbody import cover, cover_general, outline_file

    with tempfile.TemporaryDirectory() as tmp:
        path = outline_file(args.region, args.place, args.name, Path(tmp))
        if args.place:
            artifacts.atomic_write_bytes(out / "outline.geojson", path.read_bytes())
            path = out / "outline.geojson"
        if args.method == "general":
            return cover_general(path, params, out, args.policy, args.finetune, args.seed, args.n_agents,
                                 args.radius_m, not args.no_progress)
        return cover(path, params, out, args.episodes, args.seed, args.n_agents, args.radius_m, args.config,
                     not args.no_progress)


def read_baseline_gains(path: str | None) -> dict | None:
    """The general baselines' study result (``replicate tune general-baselines``), checked, or None."""
    import json

    if path is None:
        return None
    from .config import LloydConfig, NaiveConfig

    try:
        gains = json.loads(Path(path).read_text())
        naive = NaiveConfig(**gains["naive_tuned"]["gains"])
        lloyd = LloydConfig(**gains["lloyd_tuned"]["gains"], converged_steps=0)
        values = [*dataclasses.asdict(naive).values(), lloyd.gain, lloyd.damping]
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f"gains must be finite numbers, got {values}")
    except FileNotFoundError:
        raise ConfigError(f"--baseline-gains {path}: no such file; `replicate tune general-baselines` writes it") \
            from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"--baseline-gains {path}: not the general baselines' gains ({type(exc).__name__}: "
                          f"{exc}); write it with `replicate tune general-baselines`") from None
    return gains


def cmd_export(args: argparse.Namespace) -> int:
    from .export import export_general, export_policy

    params = load_params(args.params, overrides(args.set))
    if args.run is None:
        raise ConfigError("export needs a run folder: `replicate export RUN`")
    if (Path(args.run) / "actor.pt").exists():  # a general run: one shared actor for any fleet and lake
        if args.region is not None:
            raise ConfigError(f"{args.run}: a general run has no region of its own; export it without --region")
        gains = read_baseline_gains(args.baseline_gains)
        out = claim_out_file(Path(args.out or Path(args.run) / "policy.pt"), args.force)
        export_general(Path(args.run) / "actor.pt", out, params.world.sensitivity, gains)
        print(f"exported the general policy (any fleet, local sensors) to {out}"
              + (f", with the baselines' gains of {args.baseline_gains}" if gains else ""))
        return 0
    if args.baseline_gains is not None:
        raise ConfigError("--baseline-gains goes with a general run; a per-region run has its own baselines")
    region = run_region(args.run, params, args.region)
    out = claim_out_file(Path(args.out or Path(args.run) / "policy.pt"), args.force)
    meta = export_policy(Path(args.run) / "actors.pt", region, out, params.world.sensitivity)
    print(f"exported {meta['n_agents']} actors ({meta['observation']}) for {meta['region']} to {out}")
    return 0


def cmd_act(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from .export import act

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


def cmd_animate(args: argparse.Namespace) -> int:
    params = load_params(args.params, overrides(args.set))
    region = run_region(args.run, params, args.region)
    if args.seed is not None:
        check_seed(args.seed)
    out = claim_out_file(Path(args.out or Path(args.run) / "episode.gif"), args.force)
    from .animate import animate_run  # matplotlib's import is seconds: only once the inputs are known good

    out = animate_run(args.run, params, region, out, args.seed, progress=True)
    print(f"wrote {out}")
    return 0


def cmd_tune(args: argparse.Namespace) -> int:
    from .executor import configured_executor
    from .tuning import tune_baselines, tune_general_baselines, tune_method

    params = load_params(args.params, overrides(args.set))
    executor = configured_executor(params, args.executor)
    if args.what == "baselines":
        names = params.stages.get("pipeline", {}).get("regions", list(params.regions))
        result = {"baselines": tune_baselines(params, {r: resolve_region(r, params) for r in names}, executor)}
        out = Path(args.out or "metrics/tuning/baselines.json")
        artifacts.write_json(out, result["baselines"])
        for key, b in result["baselines"].items():
            print(f"{key}: tuning coverage {b['tuning_coverage']:.3f} with {b['gains']} ({b['trials']} trials)")
    elif args.what == "general-baselines":
        result = tune_general_baselines(params, executor, params.stages.get("pipeline", {}).get("workers", 1))
        out = Path(args.out or params.tuning.general_baselines.result)
        artifacts.write_json(out, result)
        for key, b in result.items():
            print(f"{key}: coverage {b['tuning_coverage']:.3f} on the training worlds with {b['gains']} "
                  f"({b['trials']} trials, {b['cpu_seconds']:.0f} CPU s)")
    else:
        ms = params.tuning.method
        result = tune_method(params, {r: resolve_region(r, params) for r in ms.regions}, executor)
        out = Path(args.out or ms.result)
        artifacts.write_json(out, result)
        print(f"{ms.config} {ms.method.upper()}-MARL: tuning coverage {result['tuning_coverage']:.3f} with "
              f"{result['values']} ({result['trials']} trials, {result['cpu_seconds']:.0f} CPU s); set them as "
              f"configs.{ms.config}.per_method.{ms.method} in params.yaml to adopt them")
    print(f"wrote {out}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """Two versions of the general training, several seeds each, on the design yardstick (``design.py``)."""
    from .design import STANDING, Versions, check_versions, compare_versions, standing_baseline
    from .executor import configured_executor

    params = load_params(args.params, overrides(args.set))
    baseline = tuple(args.baseline) if args.baseline else standing_baseline(params, Path(args.params).parent / STANDING)
    versions = Versions(baseline, tuple(args.candidate))
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    check_versions(versions, params.design.min_seeds)
    out = claim_out_file(Path(args.out), args.force)
    workers = args.workers or params.stages.get("pipeline", {}).get("workers", 1)
    executor = configured_executor(params, args.executor)
    d = params.design
    standing = "" if args.baseline else f" (the baseline: {STANDING}/)"
    runs_on = f"{workers} worker(s)" if executor == "local" else "Ray tasks"
    print(f"{d.lakes * len(d.fleets) * len(d.starts) * len(d.events)} cells (design lakes x fleets x starts x events), "
          f"{len(baseline) + len(args.candidate)} policies{standing}, {runs_on}")
    result = compare_versions(args.params, versions, workers, executor, overrides(args.set))
    artifacts.write_json(out, result)
    for label, score in result["scores"].items():
        print(f"{label} {result['policies'][label]}: coverage / lloyd_tuned {score:.4f}")
    v = result["verdict"]
    d, p = v["difference"], v["probability_of_improvement"]
    print(f"candidate - baseline {d['delta']:+.4f} (interval over seeds {d['lo']:+.4f} to {d['hi']:+.4f}); "
          f"P(a candidate seed beats a baseline seed) {p['p']:.2f}")
    print(f"rule: {v['rule']}; keep the {v['keep']}; wrote {out}")
    return 0


def cmd_init(args: argparse.Namespace) -> int:
    from .config import packaged

    if Path(args.dir).exists() and not Path(args.dir).is_dir():
        raise ConfigError(f"{args.dir}: is a file; choose a folder")
    target = claim_out_file(Path(args.dir) / "params.yaml", args.force, "init")
    artifacts.atomic_write_bytes(target, packaged("params.yaml").read_bytes())
    print(f"wrote {target}: every value of the toolkit, commented; edit it and pass --params {target} (or run "
          f"from {args.dir})")
    return 0


def common_options(suppress: bool) -> argparse.ArgumentParser:
    """``--params`` and ``--set``, accepted before the verb and after it (``suppress``: a verb's copy leaves the
    value given before the verb alone unless given again)."""
    p = argparse.ArgumentParser(add_help=False)
    after = "_after_verb" if suppress else ""
    p.add_argument("--params", dest=f"params{after}", metavar="FILE", default=None if suppress else "params.yaml",
                   help="parameters file (params.yaml of the working folder, else the defaults installed with the "
                        "package; `replicate init` writes an editable copy)")
    p.add_argument("--set", dest=f"set{after}", action="append", metavar="KEY=VALUE", default=None,
                   help="override a value of the parameters file, e.g. configs.tuned.n_envs=25 (repeatable)")
    return p


class Help(argparse.HelpFormatter):
    """Help that names a default where there is one worth naming (not None, not a switch that is off)."""

    def _get_help_string(self, action):
        text = action.help or ""
        named = action.default is not None and action.default is not False and action.default != argparse.SUPPRESS
        if named and "%(default)" not in text and action.option_strings and not text.endswith(")"):
            text += " (default: %(default)s)"
        return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="replicate", description=__doc__, parents=[common_options(False)])
    sub = parser.add_subparsers(dest="command", required=True)
    verb = dict(parents=[common_options(True)], formatter_class=Help)
    regions = "square, rectangle, bedok (params.yaml regions), or a vector file in any CRS"

    t = sub.add_parser("train", help="train MADDPG (SW-MARL or CR-MARL) on a region", **verb)
    t.add_argument("--config", default="paper", help="configuration in params.yaml: paper or tuned")
    t.add_argument("--method", default="cr", help="sw (swarming, shared reward) or cr (coverage range)")
    t.add_argument("--region", default="square", help=regions)
    t.add_argument("--episodes", type=int, default=None,
                   help="training episodes, a multiple of the config's n_envs (default: train.episodes, 10,000)")
    t.add_argument("--seed", type=int, default=0, help="training seed, 0 to 2**32 - 1")
    t.add_argument("--out", default=None, help="run folder (default: runs/CONFIG-METHOD-REGION-sSEED)")
    t.add_argument("--checkpoint-every", type=int, default=None,
                   help="episodes between resumable checkpoints (default: train.checkpoint_every)")
    t.add_argument("--resume", default=None, metavar="RUN",
                   help="continue the interrupted run in folder RUN from its checkpoint, with the settings it was "
                        "started with (nothing else needed)")
    t.add_argument("--force", action="store_true",
                   help="train into --out even if it holds a run or other files (the folder is cleared first)")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_train)

    e = sub.add_parser("evaluate", help="SPEC §8 metrics of a run, a baseline or a general policy, as JSON", **verb)
    e.add_argument("run", nargs="?", default=None, help="a run folder written by `replicate train`")
    e.add_argument("--run", dest="run_option", default=None, help=argparse.SUPPRESS)  # the older spelling
    e.add_argument("--baseline", default=None,
                   help="instead of a run: random, naive, lloyd, lloyd_converged (hand-set gains)")
    e.add_argument("--region", default=None, help=f"{regions} (default: the run's own)")
    e.add_argument("--config", default="paper", help="a baseline runs with this config's physics and T")
    e.add_argument("--out", default=None,
                   help="output JSON (default: RUN/metrics.json, or metrics/baseline-NAME-REGION.json)")
    e.add_argument("--force", action="store_true", help="replace --out if it exists")
    g = e.add_argument_group("a general policy, zero-shot on any region (instead of a run)")
    g.add_argument("--policy", default=None, help="a general policy file (`replicate export` of a general run)")
    g.add_argument("--n-agents", type=int, default=None, help="buoys (default: world.n_agents, 9); the region is "
                   "scaled to the paper's density, 1 m² per buoy")
    g.add_argument("--starts", choices=("corner", "random"), default="corner",
                   help="release in the corner patch (default) or scattered over the water")
    g.add_argument("--lose", type=int, default=0, help="buoys lost half-way (default 0)")
    g.add_argument("--current", default=None, help="a uniform drift U,V in simulation m/s (top speed 2)")
    g.add_argument("--geodesic", action="store_true", help="also geodesic Lloyd (cells and paths through the "
                   "water; the slowest comparison, left out by default)")
    e.set_defaults(func=cmd_evaluate)

    tg = sub.add_parser("train-general", help="train one policy for every lake and fleet (params.yaml general)",
                        **verb)
    tg.add_argument("--seed", type=int, default=0, help="training seed, 0 to 2**32 - 1 (default 0)")
    tg.add_argument("--episodes", type=int, default=None, help="episodes (default: general.episodes)")
    tg.add_argument("--out", required=True, help="the run folder to write (actor.pt, curve.csv.gz, run.json)")
    tg.add_argument("--force", action="store_true", help="replace a finished run in --out")
    tg.add_argument("--no-progress", action="store_true", help="no progress bar")
    tg.set_defaults(func=cmd_train_general)

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
    c.add_argument("--out", default="runs/cover", help="output folder")
    c.add_argument("--force", action="store_true", help="replace what --out holds (the folder is cleared first)")
    c.add_argument("--no-progress", action="store_true", help="no progress bars")
    c.set_defaults(func=cmd_cover)

    x = sub.add_parser("export", help="export a run's actors as one TorchScript file with metadata", **verb)
    x.add_argument("run", nargs="?", default=None, help="a run folder written by `replicate train`")
    x.add_argument("--run", dest="run_option", default=None, help=argparse.SUPPRESS)
    x.add_argument("--region", default=None, help=f"{regions} (default: the run's own)")
    x.add_argument("--out", default=None, help="TorchScript file (default: RUN/policy.pt)")
    x.add_argument("--force", action="store_true", help="replace --out if it exists")
    x.add_argument("--baseline-gains", default=None, metavar="FILE",
                   help="a general run: carry these baseline gains (`replicate tune general-baselines`) in the "
                        "policy, for `evaluate --policy` to compare with")
    x.set_defaults(func=cmd_export)

    a = sub.add_parser("act", help="map observations to commands with an exported policy (prints JSON)", **verb)
    a.add_argument("--policy", required=True, help="a file written by `replicate export`")
    group = a.add_mutually_exclusive_group(required=True)
    group.add_argument("--obs", help='observations "x,y;x,y;..." one buoy per ";" (negative numbers welcome)')
    group.add_argument("--obs-file", help="JSON file with an [N, obs_dim] list, or - for standard input")
    a.add_argument("--real", action="store_true", help="observations are UTM metres (m/s), not simulation units")
    a.set_defaults(func=cmd_act)

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
    u.set_defaults(func=cmd_tune)

    v = sub.add_parser("compare", help="two versions of the general training, several seeds each, on the design "
                       "lakes (never trained on, never reported): keep the candidate only if it wins over seeds",
                       **verb)
    v.add_argument("--baseline", nargs="+", default=None, metavar="POLICY",
                   help="the baseline version's exported policies, one per training seed (at least "
                        "design.min_seeds; default: the standing baseline in design/ beside --params, the current "
                        "training values on design.seeds, written by the train_design stage)")
    v.add_argument("--candidate", nargs="+", required=True, metavar="POLICY",
                   help="the candidate version's exported policies, one per training seed (at least "
                        "design.min_seeds)")
    v.add_argument("--out", required=True, help="output JSON: every cell, each seed's score and the verdict")
    v.add_argument("--force", action="store_true", help="replace --out if it exists")
    v.add_argument("--workers", type=int, default=None, help="processes, one lake each (default: pipeline.workers)")
    v.add_argument("--executor", choices=("local", "ray"), default=None,
                   help="local processes or Ray tasks (default: pipeline.executor)")
    v.set_defaults(func=cmd_compare)

    i = sub.add_parser("init", help="write an editable params.yaml with every default value into a folder", **verb)
    i.add_argument("dir", nargs="?", default=".", help="folder")
    i.add_argument("--force", action="store_true", help="replace a params.yaml already there")
    i.set_defaults(func=cmd_init)

    m = sub.add_parser("animate", help="GIF of an evaluation episode of a run", **verb)
    m.add_argument("run", help="a run folder written by `replicate train`")
    m.add_argument("--region", default=None, help=f"{regions} (default: the run's own)")
    m.add_argument("--seed", type=int, default=None, help="starts of the episode (default: evaluate.seed)")
    m.add_argument("--out", default=None, help="GIF file (default: RUN/episode.gif)")
    m.add_argument("--force", action="store_true", help="replace --out if it exists")
    m.set_defaults(func=cmd_animate)
    return parser


def glued_values(argv: list[str]) -> list[str]:
    """``--obs -1.2,-1.2;...`` → ``--obs=-1.2,-1.2;...``: argparse takes a value that starts with a minus sign for
    an option."""
    out, it = [], iter(argv)
    for arg in it:
        if arg == "--obs":
            value = next(it, None)
            out.append(arg if value is None else f"--obs={value}")
        else:
            out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(glued_values(sys.argv[1:] if argv is None else argv))
    if getattr(args, "run_option", None) is not None:
        args.run = args.run or args.run_option
    args.params = args.params_after_verb or args.params  # --params and --set work before or after the verb
    args.set = (args.set or []) + (args.set_after_verb or [])
    warnings.simplefilter("default")
    if args.command in ("train", "cover", "tune"):
        from .train import training_process

        training_process()
    try:
        return args.func(args)
    except (ConfigError, RegionError, CheckpointError, OSError, ValueError) as exc:
        print(f"replicate: error: {exc}", file=sys.stderr)
        return 2
    except shapely.errors.GEOSException as exc:
        print(f"replicate: error: the region's geometry cannot be used ({exc}); check the outline file, or repair "
              "it (e.g. shapely.make_valid)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return interrupted(args)
    except Exception as exc:
        if not caused_by_ctrl_c(exc):
            raise
        return interrupted(args)


def caused_by_ctrl_c(exc: BaseException) -> bool:
    """Whether ``exc`` wraps a KeyboardInterrupt: numba turns one that lands while it loads a compiled function
    from its cache into an error of its own, raised from the interrupt."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def interrupted(args) -> int:
    hint = getattr(args, "interrupted_hint", None)
    print("replicate: interrupted" + (f"; {hint}" if hint else ""), file=sys.stderr)
    return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
