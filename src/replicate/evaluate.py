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

from . import artifacts, baselines, metrics
from .config import ConfigError, Params, RunConfig, load_params, run_config, selection_only
from .env import CoverageEnv
from .regions import Region, make_region
from .train import CURVE, core_seconds, load_actors

BASELINES = ("random", "naive", "lloyd", "lloyd_converged")


def rollout(env: CoverageEnv, policy, steps: int, seed: int) -> dict:
    """Run ``policy`` for ``steps`` from a reset with ``seed``: positions at every step [steps + 1, E, N, 2] and
    each agent's return under the environment's reward [E, N] (zeros when it has none)."""
    env.reset(seed)
    trace = [env.pos.copy()]
    returns = np.zeros((env.n_envs, env.n_agents))
    for _ in range(steps):
        returns += env.step(policy(env)).reward
        trace.append(env.pos.copy())
    return {"positions": np.stack(trace), "returns": returns}


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
                 as_config: str | None = None) -> dict:
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
    pos = rollout(env, actor_policy(net, meta["observation"]), rc.world.episode_length, ev.seed)["positions"]
    out = summarise(region, pos, rc.coverage.radius, rc.coverage.edges)
    curve = read_curve(run_dir / CURVE)
    conv = metrics.convergence_episode(
        curve["team_reward"], ev.converge_window, ev.converge_tolerance, ev.converge_final
    )
    run = json.loads((run_dir / "run.json").read_text())
    out.update(
        kind="run",
        config=as_config or ident["config"],
        method=ident["method"],
        region=ident["region"],
        seed=ident["seed"],
        episodes=ident["episodes"],
        convergence_episode=conv,
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


def evaluate_baseline(name: str, params: Params, region: Region, config: str = "paper") -> dict:
    """Metrics of a baseline with the same physics, T and start as the runs of ``config``."""
    if name not in BASELINES:
        raise ConfigError(f"unknown baseline {name!r}; known: {list(BASELINES)}")
    rc = run_config(params, config, "cr", region.name)
    ev = params.evaluate
    env = eval_env(region, rc, ev.episodes)
    steps = rc.world.episode_length
    if name == "random":
        policy = baselines.random_policy(np.random.default_rng(ev.seed + 1))
    elif name == "naive":
        policy = baselines.naive_swarming(ev.naive)
    else:
        policy = baselines.lloyd(ev.lloyd)
        if name == "lloyd_converged":
            steps = ev.lloyd.converged_steps
    pos = rollout(env, policy, steps, ev.seed)["positions"]
    out = summarise(region, pos, rc.coverage.radius, rc.coverage.edges)
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
        result = evaluate_baseline(job["baseline"], params, region)
    artifacts.write_json(job["out"], result)
    return job["out"], result


def selection_ablation_jobs(params_path: str, params: Params, run: Path, ident: dict, metrics_dir: Path) -> list:
    """Evaluation jobs for the selection-only ablation changes: the base run's last actors, filed under the
    ablation config's name (its training is the base run's, step for step)."""
    ab = params.ablation
    if not (ident["config"] == ab.base and ident["method"] == ab.method and ident["region"] in ab.regions
            and (run / "actors_last.pt").exists()):
        return []
    jobs = []
    for change in (c for c in ab.changes if selection_only(params, c)):
        name = f"{ab.base}-without-{change}"
        out = metrics_dir / "runs" / f"{run.name.replace(ab.base, name, 1)}.json"
        jobs.append({"params": params_path, "run": str(run), "region": ident["region"], "actors": "actors_last.pt",
                     "as_config": name, "out": str(out)})
    return jobs


def evaluate_matrix(params_path: str, runs_dir: str, metrics_dir: str, regions, workers: int) -> dict:
    """SPEC §8 metrics of every run in ``runs_dir`` and of every baseline on every region; a summary table."""
    metrics_dir = Path(metrics_dir)
    params = load_params(params_path)
    jobs = []
    known = params.all_configs()
    for run in sorted(p for p in Path(runs_dir).iterdir() if (p / "actors.pt").exists()):
        ident = json.loads((run / "run.json").read_text())
        if ident["config"] not in known:  # e.g. the runs of an ablation change since removed from params.yaml
            print(f"evaluate: skipped {run.name}: its config {ident['config']!r} is not in params.yaml")
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
             "out": str(metrics_dir / "baselines" / f"{name}-{region}.json")}
            for name in reversed(BASELINES) for region in regions] + jobs  # BASELINES ends with the costliest
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = dict(pool.map(_evaluate_one, jobs))
    summary = summarise_metrics(results.values())
    summary = split_ablation(summary, params)
    artifacts.write_json(metrics_dir / "summary.json", summary)
    return summary


def split_ablation(summary: dict, params: Params) -> dict:
    """Move the ablation groups out of ``runs`` into ``ablation``: one row per change with the base config's
    coverage (with the change) and the derived config's (without it), each over the same seeds."""
    ab = params.ablation
    runs = dict(summary["runs"])
    rows = {}
    for change, keys in ab.changes.items():
        for region in ab.regions:
            derived = runs.pop(f"{ab.base}-without-{change}/{ab.method}/{region}", None)
            base = summary["runs"].get(f"{ab.base}/{ab.method}/{region}")
            if derived is None or base is None:
                continue
            rows[f"{change}/{region}"] = {
                "keys": list(keys),
                "with": base["coverage"],
                "without": derived["coverage"],
                "with_per_seed": base["coverage_per_seed"],
                "without_per_seed": derived["coverage_per_seed"],
                "delta": base["coverage"]["mean"] - derived["coverage"]["mean"],
            }
    return {**summary, "runs": runs, "ablation": rows}


def summarise_metrics(results) -> dict:
    """Coverage table: per config × method × region the mean over seeds with a 95 % CI, and the baselines."""
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
            }
    runs = {}
    for key, rs in sorted(groups.items()):
        conv = [r["convergence_episode"] for r in rs]
        runs[key] = {
            "seeds": sorted(r["seed"] for r in rs),
            "coverage": metrics.mean_ci([r["coverage"]["mean"] for r in rs]),
            "coverage_per_seed": [round(r["coverage"]["mean"], 4) for r in rs],
            "nearest_neighbour": metrics.mean_ci([r["nearest_neighbour"]["mean"] for r in rs]),
            "fraction_inside": metrics.mean_ci([r["fraction_inside"]["mean"] for r in rs]),
            "convergence_episode": conv,
            "core_seconds": metrics.mean_ci([r["core_seconds"] for r in rs]),
        }
    return {"runs": runs, "baselines": baselines}
