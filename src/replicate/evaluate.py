"""Evaluation (SPEC §8): a trained run or a baseline, 100 episodes with fixed evaluation seeds, into JSON.

All evaluation episodes run at once as E = ``episodes`` parallel environments from the evaluation seed, so a
method and a baseline start from the same positions. Policies are deterministic (no exploration noise).
"""

from __future__ import annotations

import csv
import io
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

from . import artifacts, baselines, metrics, stats
from .config import (
    ConfigError,
    LloydConfig,
    NaiveConfig,
    Params,
    RunConfig,
    StartsConfig,
    load_params,
    run_config,
    selection_only,
)
from .env import CoverageEnv
from .regions import Region, make_region
from .train import CURVE, core_seconds, load_actors

# the paper's comparisons with hand-set gains and the same heuristics with gains tuned by ``tuning.py``, in the
# order the evaluate stage starts them: costliest first (the converged Lloyd layouts run 500 steps)
BASELINES = ("lloyd_converged", "lloyd_tuned", "lloyd", "naive_tuned", "naive", "random")
PAPER_START = StartsConfig("corner")


def rollout(env: CoverageEnv, policy, steps: int, seed: int, starts: StartsConfig = PAPER_START,
            bar=None) -> dict:
    """Run ``policy`` for ``steps`` from a reset with ``seed`` at ``starts.start``, losing ``starts.lose`` buoys
    after half the steps (drawn from a generator of ``seed``): positions at every step [steps + 1, E, N, 2],
    the live buoys' last positions [E, N_live, 2], and each agent's return under the environment's reward [E, N]
    (zeros when it has none). ``bar``, a tqdm bar, counts the steps."""
    env.reset(seed, start=starts.start)
    loss_rng = np.random.default_rng([seed, 1])
    trace = [env.pos.copy()]
    returns = np.zeros((env.n_envs, env.n_agents))
    for t in range(steps):
        if starts.lose and t == steps // 2:
            env.lose(starts.lose, loss_rng)
        returns += env.step(policy(env)).reward
        trace.append(env.pos.copy())
        if bar is not None:
            bar.update(1)
    return {"positions": np.stack(trace), "live": env.live_positions().copy(), "returns": returns}


def robustness(env: CoverageEnv, policy, params: Params, region: Region, rc: RunConfig, bar=None) -> dict:
    """Mean exact coverage of ``policy`` under every scenario of ``evaluate.robustness``, each from the
    evaluation seed: {scenario: {"coverage", "steps"}}."""
    out = {}
    for name, starts in params.evaluate.robustness.items():
        steps = round(starts.horizon * rc.world.episode_length)
        live = rollout(env, policy, steps, params.evaluate.seed, starts, bar)["live"]
        cov = metrics.coverage_fraction(region.polygon, live, rc.coverage.radius, rc.coverage.edges)
        out[name] = {"coverage": float(cov.mean()), "steps": steps}
    return out


def summarise(region: Region, trace: np.ndarray, radius: float, edges: int) -> dict:
    """SPEC §8 metrics of the last step of a rollout ``trace`` [T + 1, E, N, 2]: per-episode values, their mean
    with a 95 % CI, and the first episode's trajectory as an example for the figures."""
    xy = trace[-1]
    cov = metrics.coverage_fraction(region.polygon, xy, radius, edges)
    nn = metrics.mean_nearest_neighbour(xy)
    inside = metrics.fraction_inside(region.polygon, xy, radius, edges)
    return {
        "coverage": metrics.mean_ci(cov),
        "nearest_neighbour": metrics.mean_ci(nn),
        "fraction_inside": metrics.mean_ci(inside),
        "per_episode": {"coverage": cov.round(6).tolist()},
        "example": {"final_positions": xy[0].round(5).tolist(), "trajectory": trace[:, 0].round(4).tolist()},
    }


def actor_policy(net, observation: str) -> baselines.Policy:
    """The trained decentralised actors as a deterministic policy: a_i = tanh(μ_i(o_i))."""

    def policy(env: CoverageEnv) -> np.ndarray:
        obs = env.observe()
        with torch.no_grad():
            x = torch.from_numpy(np.ascontiguousarray(obs.transpose(1, 0, 2)))
            return torch.tanh(net(x)).transpose(0, 1).numpy().astype(float)

    return policy


def read_curve(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a curve file (``curve.csv.gz`` of a run, ``validation.csv``, a reference curve)."""
    rows = list(csv.DictReader(io.StringIO(artifacts.read_text(path))))
    if not rows:
        raise ValueError(f"{path}: empty curve")
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def evaluate_run(run_dir: str | Path, params: Params, region: Region, actors: str = "actors.pt",
                 as_config: str | None = None, progress: bool = False) -> dict:
    """Metrics of a finished run: deterministic evaluation plus convergence from its training curve.
    ``actors``/``as_config`` evaluate another actors file of the run and file it under another config name
    (the last actors of a selecting run are its "without selection" ablation)."""
    run_dir = Path(run_dir)
    net, meta = load_actors(run_dir / actors)
    ident = meta["identity"]
    rc = run_config(params, ident["config"], ident["method"], ident["region"])
    ev = params.evaluate
    env = eval_env(region, rc, ev.episodes, rc.algo.observation)
    if meta["observation"] != rc.algo.observation:
        raise ConfigError(f"{run_dir}: actors observe {meta['observation']!r}, params say {rc.algo.observation!r}")
    policy = actor_policy(net, meta["observation"])
    with steps_bar(params, rc, progress, f"evaluating {Path(run_dir).name}") as bar:
        pos = rollout(env, policy, rc.world.episode_length, ev.seed, bar=bar)["positions"]
        out = summarise(region, pos, rc.coverage.radius, rc.coverage.edges)
        out["robustness"] = robustness(env, policy, params, region, rc, bar)
    curve = read_curve(run_dir / CURVE)
    conv = {str(f): metrics.convergence_episode(curve["team_reward"], ev.converge_window, f * ev.converge_tolerance,
                                                ev.converge_final) for f in (1.0, *params.report.sensitivity)}
    run = json.loads((run_dir / "run.json").read_text())
    out.update(
        kind="run",
        config=as_config or ident["config"],
        method=ident["method"],
        region=ident["region"],
        seed=ident["seed"],
        episodes=ident["episodes"],
        convergence_episode=conv["1.0"],
        convergence_by_tolerance=conv,  # tolerance factor → convergence episode, for the report's sensitivity
        training_coverage_last100=float(curve["coverage"][-100:].mean()),
        core_seconds=core_seconds(run),  # one core's time for the run
    )
    return out


def eval_env(region: Region, rc: RunConfig, episodes: int, observation: str = "position") -> CoverageEnv:
    return CoverageEnv(
        region,
        rc.world,
        rc.coverage,
        n_envs=episodes,
        observation=observation,
        geofence=rc.algo.geofence,
    )


def baseline_policy(name: str, params: Params, tuned: dict | None = None) -> baselines.Policy:
    """A baseline by name; ``naive_tuned``/``lloyd_tuned`` take their gains from ``tuned`` (the entry of
    ``metrics/tuning/baselines.json`` for their kind and region)."""
    ev = params.evaluate
    if name == "random":
        return baselines.random_policy(np.random.default_rng(ev.seed + 1))
    if name == "naive":
        return baselines.naive_swarming(ev.naive)
    if name in ("lloyd", "lloyd_converged"):
        return baselines.lloyd(ev.lloyd)
    if tuned is None:
        raise ConfigError(f"baseline {name!r} needs its tuned gains (the tune_baselines stage)")
    if name == "naive_tuned":
        return baselines.naive_swarming(NaiveConfig(**tuned["gains"]))
    return baselines.lloyd(LloydConfig(**tuned["gains"], converged_steps=ev.lloyd.converged_steps))


def steps_bar(params: Params, rc: RunConfig, progress: bool, what: str, steps: int | None = None):
    """A progress bar over the environment steps of an evaluation and its robustness scenarios."""
    from tqdm.auto import tqdm

    scenarios = sum(round(s.horizon * rc.world.episode_length) for s in params.evaluate.robustness.values())
    total = (rc.world.episode_length if steps is None else steps) + scenarios
    return tqdm(total=total, desc=what, unit="step", disable=not progress, leave=False)


def evaluate_baseline(name: str, params: Params, region: Region, config: str = "paper",
                      tuned: dict | None = None, progress: bool = False) -> dict:
    """Metrics of a baseline with the same physics, T and start as the runs of ``config``, and under the
    robustness scenarios (but the converged Lloyd layout, which is a limit, not a policy under a horizon)."""
    if name not in BASELINES:
        raise ConfigError(f"unknown baseline {name!r}; known: {list(BASELINES)}")
    rc = run_config(params, config, "cr", region.name)
    ev = params.evaluate
    env = eval_env(region, rc, ev.episodes)
    steps = ev.lloyd.converged_steps if name == "lloyd_converged" else rc.world.episode_length
    policy = baseline_policy(name, params, tuned)
    with steps_bar(params, rc, progress, f"evaluating {name}", steps) as bar:
        if name == "lloyd_converged":
            bar.total = steps
        pos = rollout(env, policy, steps, ev.seed, bar=bar)["positions"]
        out = summarise(region, pos, rc.coverage.radius, rc.coverage.edges)
        if name != "lloyd_converged":
            out["robustness"] = robustness(env, policy, params, region, rc, bar)
    if tuned is not None:
        out["gains"] = tuned["gains"]
    out.update(kind="baseline", baseline=name, region=region.name, steps=steps, config=config)
    out["ceiling"] = metrics.coverage_ceiling(region.area, rc.world.n_agents, rc.coverage.radius, rc.coverage.edges)
    return out


# ---- the pipeline's evaluate stage ---------------------------------------------------------------------
def _evaluate_one(job: dict) -> tuple[str, dict]:
    import torch

    torch.set_num_threads(1)
    params = load_params(job["params"])
    region = make_region(job["region"], params.regions[job["region"]], params.world.region_area)
    if "run" in job:
        result = evaluate_run(job["run"], params, region, job.get("actors", "actors.pt"), job.get("as_config"))
    else:
        result = evaluate_baseline(job["baseline"], params, region, tuned=job.get("tuned"))
    artifacts.write_json(job["out"], result)
    return job["out"], result


def selection_ablation_jobs(params_path: str, params: Params, run: Path, ident: dict, metrics_dir: Path) -> list:
    """Evaluation jobs for the selection-only ablation changes: the base run's last actors, filed under the
    ablation config's name (its training is the base run's, step for step)."""
    ab = params.ablation
    if not (ident["config"] == ab.base and ident["method"] == ab.method and ident["region"] in ab.regions
            and ident["seed"] in ab.seeds and (run / "actors_last.pt").exists()):
        return []
    jobs = []
    for change in (c for c in ab.changes if selection_only(params, c)):
        name = f"{ab.base}-without-{change}"
        out = metrics_dir / "runs" / f"{run.name.replace(ab.base, name, 1)}.json"
        jobs.append({"params": params_path, "run": str(run), "region": ident["region"], "actors": "actors_last.pt",
                     "as_config": name, "out": str(out)})
    return jobs


def evaluate_matrix(params_path: str, runs_dir: str, metrics_dir: str, regions, workers: int,
                    tuned_baselines: str | Path) -> dict:
    """SPEC §8 metrics of every run in ``runs_dir`` and of every baseline on every region (the tuned ones with the
    gains in ``tuned_baselines``); a summary table."""
    metrics_dir = Path(metrics_dir)
    params = load_params(params_path)
    tuned = json.loads(Path(tuned_baselines).read_text())
    jobs = []
    for run in sorted(p for p in Path(runs_dir).iterdir() if (p / "actors.pt").exists()):
        ident = json.loads((run / "run.json").read_text())
        why = not_in_matrix(params, ident, run)
        if why:  # a run of older code or settings, of a seed that chose values, of an ablation since removed
            print(f"evaluate: skipped {run.name}: {why}")
            continue
        curve = read_curve(run / CURVE)
        artifacts.write_csv(metrics_dir / "curves" / f"{run.name}.csv", ["episode", "team_reward", "coverage"],
                            zip(curve["episode"].astype(int), curve["team_reward"], curve["coverage"]))
        jobs.append({"params": params_path, "run": str(run), "region": ident["region"],
                     "out": str(metrics_dir / "runs" / f"{run.name}.json")})
        jobs += selection_ablation_jobs(params_path, params, run, ident, metrics_dir)
    # the baselines first: the converged Lloyd layouts (500 steps of 100 episodes) are the longest jobs, and
    # started last they kept one process busy while the other idled
    jobs = [{"params": params_path, "baseline": name, "region": region,
             "tuned": tuned.get(f"{name.removesuffix('_tuned')}/{region}") if name.endswith("_tuned") else None,
             "out": str(metrics_dir / "baselines" / f"{name}-{region}.json")}
            for name in BASELINES for region in regions] + jobs
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = dict(pool.map(_evaluate_one, jobs))
    summary = summarise_metrics(results.values(), stats.Bootstrap(params.report.level, params.report.resamples,
                                                                   params.report.seed))
    summary = split_ablation(summary, params)
    artifacts.write_json(metrics_dir / "summary.json", summary)
    return summary


def not_in_matrix(params: Params, ident: dict, run: Path) -> str | None:
    """Why the finished run ``run`` (its ``run.json`` is ``ident``) is not one the pipeline reports, or None: its
    config and seed must be in the matrix (``train.seeds``, ``ablation.seeds``), and its identity (code version,
    settings, region, episodes) the one params.yaml gives now."""
    from .pipeline import cell_seeds
    from .train import finished_run, run_identity

    config = ident.get("config")
    if config not in params.all_configs():
        return f"its config {config!r} is not in params.yaml"
    if config in params.configs and config not in params.train.seeds:
        return f"params.yaml train.seeds has no seeds for {config!r}"
    if ident.get("seed") not in cell_seeds(params, config):
        return f"seed {ident.get('seed')} is not among {config}'s reported seeds"
    region = make_region(ident["region"], params.regions[ident["region"]], params.world.region_area) \
        if ident.get("region") in params.regions else None
    if region is None:
        return f"its region {ident.get('region')!r} is not in params.yaml"
    rc = run_config(params, config, ident["method"], ident["region"])
    if finished_run(run, run_identity(rc, region, params.train.episodes, ident["seed"])) is None:
        return "it was trained with other code or settings than params.yaml gives now"
    return None


def split_ablation(summary: dict, params: Params) -> dict:
    """Move the ablation groups out of ``runs`` into ``ablation``: one row per change with the base config's
    coverage (with the change) and the derived config's (without it), each over the ablation's seeds, and the
    bootstrap interval of Δ = with − without."""
    ab, r = params.ablation, params.report
    boot = stats.Bootstrap(r.level, r.resamples, r.seed)
    runs = dict(summary["runs"])
    rows = {}
    for change, keys in ab.changes.items():
        for region in ab.regions:
            derived = runs.pop(f"{ab.base}-without-{change}/{ab.method}/{region}", None)
            base = summary["runs"].get(f"{ab.base}/{ab.method}/{region}")
            if derived is None or base is None:
                continue
            with_ = [c for s, c in zip(base["seeds"], base["coverage_per_seed"]) if s in ab.seeds]
            without = derived["coverage_per_seed"]
            rows[f"{change}/{region}"] = {
                "keys": list(keys),
                "with": stats.mean_interval(with_, boot),
                "without": stats.mean_interval(without, boot),
                "with_per_seed": with_,
                "without_per_seed": without,
                "delta": stats.difference([with_], [without], boot),
            }
    return {**summary, "runs": runs, "ablation": rows}


def summarise_metrics(results, boot: stats.Bootstrap = stats.DEFAULT) -> dict:
    """Coverage table: per config × method × region the mean over seeds with its bootstrap interval, each
    robustness scenario likewise, and the baselines (deterministic: one value per region)."""
    groups: dict[str, list] = {}
    baselines = {}
    for r in results:
        if r["kind"] == "run":
            groups.setdefault(f"{r['config']}/{r['method']}/{r['region']}", []).append(r)
        else:
            baselines[f"{r['baseline']}/{r['region']}"] = {
                "coverage": r["coverage"]["mean"],
                "nearest_neighbour": r["nearest_neighbour"]["mean"],
                "fraction_inside": r["fraction_inside"]["mean"],
                "ceiling": r["ceiling"],
                "steps": r["steps"],
                **({"gains": r["gains"]} if "gains" in r else {}),
                **({"robustness": {k: v["coverage"] for k, v in r["robustness"].items()}}
                   if "robustness" in r else {}),
            }
    runs = {}
    for key, rs in sorted(groups.items()):
        rs = sorted(rs, key=lambda r: r["seed"])
        scenarios = rs[0].get("robustness", {})
        runs[key] = {
            "seeds": [r["seed"] for r in rs],
            "coverage": stats.mean_interval([r["coverage"]["mean"] for r in rs], boot),
            "coverage_per_seed": [round(r["coverage"]["mean"], 4) for r in rs],
            "nearest_neighbour": stats.mean_interval([r["nearest_neighbour"]["mean"] for r in rs], boot),
            "nearest_neighbour_per_seed": [round(r["nearest_neighbour"]["mean"], 4) for r in rs],
            "fraction_inside": stats.mean_interval([r["fraction_inside"]["mean"] for r in rs], boot),
            "convergence_episode": [r["convergence_episode"] for r in rs],
            "convergence_by_tolerance": {f: [r["convergence_by_tolerance"][f] for r in rs]
                                         for f in rs[0].get("convergence_by_tolerance", {})},
            "core_seconds": stats.mean_interval([r["core_seconds"] for r in rs], boot),
            "robustness": {name: {"coverage": stats.mean_interval([r["robustness"][name]["coverage"] for r in rs],
                                                                  boot),
                                  "per_seed": [round(r["robustness"][name]["coverage"], 4) for r in rs]}
                           for name in scenarios},
        }
    return {"runs": runs, "baselines": baselines}
