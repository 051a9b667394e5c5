"""Evaluation (SPEC §8): a trained run, a baseline or a general policy, 100 episodes with fixed evaluation seeds,
into JSON.

All evaluation episodes run at once as E = ``episodes`` parallel environments from the evaluation seed, so a
method and a baseline start from the same positions. Policies are deterministic (no exploration noise).
"""

from __future__ import annotations

import json
from collections.abc import Hashable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from replicate.compare import baselines, metrics
from replicate.compare.best_layout import best_coverage_from
from replicate.compare.rivals import general_baselines, limits, lloyd_name, rivals_and_limit
from replicate.compare.stats import mean_interval
from replicate.core import artifacts
from replicate.core.executor import Beside
from replicate.core.params import Params, RunConfig, run_config
from replicate.core.progress import bar as progress_bar
from replicate.core.schema import ConfigError
from replicate.core.sections import SensorsConfig
from replicate.core.studies import LloydConfig, NaiveConfig, StartsConfig
from replicate.learn.policy import load_policy, takes_positions
from replicate.learn.runs import core_seconds
from replicate.learn.train import CURVE, load_actors
from replicate.world import coverage
from replicate.world.currents import Current
from replicate.world.env import CoverageEnv
from replicate.world.regions import Region
from replicate.world.scenario import evaluation_env, general_evaluation_env, horizon
from replicate.world.shore import distance_outside

# the paper's comparisons with hand-set gains and the same heuristics with gains tuned by ``tuning.py``, in the
# order the evaluate stage starts them: costliest first (the converged Lloyd layouts run 500 steps)
BASELINES = ("lloyd_converged", "lloyd_tuned", "lloyd", "naive_tuned", "naive", "random")
PAPER_START = StartsConfig("corner")


def rollout(env: CoverageEnv, policy, steps: int, seed: int, starts: StartsConfig = PAPER_START,
            bar=None) -> dict:
    """Run ``policy`` for ``steps`` from a reset with ``seed`` at ``starts.start``, losing ``starts.lose`` buoys
    after half the steps (drawn from a generator of ``seed``): positions at every step [steps + 1, E, N, 2], the
    buoys in service at every step [steps + 1, E, N] (a lost buoy is out from the frame it is lost at), the live
    buoys' last positions [E, N_live, 2], and each agent's return under the environment's reward [E, N] (zeros
    when it has none). ``bar``, a tqdm bar, counts the steps."""
    env.reset(seed, start=starts.start)
    loss_rng = np.random.default_rng([seed, 1])
    trace, alive = [env.pos.copy()], [np.ones((env.n_envs, env.n_agents), bool)]
    returns = np.zeros((env.n_envs, env.n_agents))
    for t in range(steps):
        if starts.lose and t == steps // 2:
            env.lose(starts.lose, loss_rng)
            alive[-1] = env.alive.copy()  # lost where they stand
        returns += env.step(policy(env)).reward
        trace.append(env.pos.copy())
        alive.append(alive[-1] if env.alive is None else env.alive.copy())
        if bar is not None:
            bar.update(1)
    return {"positions": np.stack(trace), "alive": np.stack(alive), "live": env.live_positions().copy(),
            "returns": returns}


def robustness(env: CoverageEnv, policy, params: Params, region: Region, rc: RunConfig, bar=None) -> dict:
    """Mean exact coverage of ``policy`` under every scenario of ``evaluate.robustness``, each from the
    evaluation seed: {scenario: {"coverage", "steps"}}."""
    out = {}
    for name, starts in params.evaluate.robustness.items():
        steps = round(starts.horizon * rc.world.episode_length)
        live = rollout(env, policy, steps, params.evaluate.seed, starts, bar)["live"]
        cov = coverage.coverage_fraction(region.polygon, live, rc.coverage.radius, rc.coverage.edges)
        out[name] = {"coverage": float(cov.mean()), "steps": steps}
    return out


def summarise(region: Region, trace: np.ndarray, radius: float, edges: int) -> dict:
    """SPEC §8 metrics of the last step of a rollout ``trace`` [T + 1, E, N, 2]: per-episode values, their mean
    with a 95 % CI, and the first episode's trajectory as an example for the figures."""
    xy = trace[-1]
    cov = coverage.coverage_fraction(region.polygon, xy, radius, edges)
    nn = metrics.mean_nearest_neighbour(xy)
    inside = coverage.fraction_inside(region.polygon, xy, radius, edges)
    return {
        "coverage": metrics.mean_ci(cov),
        "nearest_neighbour": metrics.mean_ci(nn),
        "nearest_neighbour_inside": metrics.mean_ci(metrics.nearest_neighbour_inside(region.polygon, xy)),
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


def run_actors(run_dir: Path, params: Params, actors: str = "actors.pt", same_observation: bool = True):
    """A run's actors, metadata and run config under ``params``, refused by name when the params give the world
    another number of buoys than the actors were trained for, or (``same_observation``) another observation."""
    net, meta = load_actors(Path(run_dir) / actors)
    ident = meta["identity"]
    rc = run_config(params, ident["config"], ident["method"], ident["region"])
    if same_observation and meta["observation"] != rc.algo.observation:
        raise ConfigError(f"{run_dir}: actors observe {meta['observation']!r}, params say {rc.algo.observation!r}")
    n_actors = net.weights[0].shape[0]
    if n_actors != rc.world.n_agents:
        raise ConfigError(f"{run_dir}: the run has {n_actors} actors (one per buoy), the world {rc.world.n_agents} "
                          f"buoys; use it with world.n_agents={n_actors}")
    return net, meta, rc


def evaluate_run(run_dir: str | Path, params: Params, region: Region, actors: str = "actors.pt",
                 as_config: str | None = None, progress: bool = False) -> dict:
    """Metrics of a finished run: deterministic evaluation plus convergence from its training curve.
    ``actors``/``as_config`` evaluate another actors file of the run and file it under another config name
    (the last actors of a selecting run are its "without selection" ablation)."""
    run_dir = Path(run_dir)
    net, meta, rc = run_actors(run_dir, params, actors)
    ident = meta["identity"]
    ev = params.evaluate
    env = evaluation_env(region, rc, ev.episodes, rc.algo.observation)
    policy = actor_policy(net, meta["observation"])
    with steps_bar(params, rc, progress, f"evaluating {Path(run_dir).name}") as bar:
        pos = rollout(env, policy, rc.world.episode_length, ev.seed, bar=bar)["positions"]
        out = summarise(region, pos, rc.coverage.radius, rc.coverage.edges)
        out["robustness"] = robustness(env, policy, params, region, rc, bar)
    curve = artifacts.read_curve(run_dir / CURVE)
    conv = {band: {str(f): metrics.convergence_episode(curve["team_reward"], ev.converge_window,
                                                       f * ev.converge_tolerance, ev.converge_final, band)
                   for f in (1.0, *params.report.sensitivity)} for band in metrics.BANDS}
    run = json.loads((run_dir / "run.json").read_text())
    out.update(
        kind="run",
        config=as_config or ident["config"],
        method=ident["method"],
        region=ident["region"],
        seed=ident["seed"],
        episodes=ident["episodes"],
        convergence_episode=conv[params.report.convergence_band]["1.0"],
        # band → tolerance factor → convergence episode: the report's sensitivity, and the other band's verdict
        convergence_by_tolerance=conv,
        training_coverage_last100=float(curve["coverage"][-100:].mean()),
        core_seconds=core_seconds(run),  # one core's time for the run
    )
    return out


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


def steps_bar(params: Params, rc: RunConfig, progress: bool, what: str, steps: int | None = None,
              scenarios: bool = True):
    """A progress bar over the environment steps of an evaluation (and of its robustness scenarios)."""
    scenarios = scenarios * sum(round(s.horizon * rc.world.episode_length) for s in params.evaluate.robustness.values())
    total = (rc.world.episode_length if steps is None else steps) + scenarios
    return progress_bar(progress, total=total, desc=what, unit="step", leave=False)


def evaluate_baseline(name: str, params: Params, region: Region, config: str = "paper",
                      tuned: dict | None = None, progress: bool = False) -> dict:
    """Metrics of a baseline with the same physics, T and start as the runs of ``config``, and under the
    robustness scenarios (but the converged Lloyd layout, which is a limit, not a policy under a horizon)."""
    if name not in BASELINES:
        raise ConfigError(f"unknown baseline {name!r}; known: {list(BASELINES)}")
    rc = run_config(params, config, "cr", region.name)
    ev = params.evaluate
    env = evaluation_env(region, rc, ev.episodes)
    steps = ev.lloyd.converged_steps if name == "lloyd_converged" else rc.world.episode_length
    policy = baseline_policy(name, params, tuned)
    limit = name == "lloyd_converged"  # a layout after many steps, not a policy under a horizon: no scenarios
    with steps_bar(params, rc, progress, f"evaluating {name}", steps, scenarios=not limit) as bar:
        pos = rollout(env, policy, steps, ev.seed, bar=bar)["positions"]
        out = summarise(region, pos, rc.coverage.radius, rc.coverage.edges)
        if not limit:
            out["robustness"] = robustness(env, policy, params, region, rc, bar)
    if tuned is not None:
        out["gains"] = tuned["gains"]
    out.update(kind="baseline", baseline=name, region=region.name, steps=steps, config=config)
    out["ceiling"] = coverage.coverage_ceiling(region.area, rc.world.n_agents, rc.coverage.radius, rc.coverage.edges)
    return out


class Phases:
    """A progress bar of an evaluation's phases (each rolls out every episode, or searches the best layout:
    seconds each): ``with Phases(lake, n, progress) as phase: phase("Lloyd")`` counts the phase before it."""

    def __init__(self, where: str, total: int, progress: bool):
        self.where, self.started = where, False
        self.bar = progress_bar(progress, total=total, unit="phase", leave=False)

    def __enter__(self):
        return self

    def __call__(self, label: str) -> None:
        if self.started:
            self.bar.update()
        self.started = True
        self.bar.set_description(f"{self.where}: {label}")

    def __exit__(self, *exc) -> None:
        if exc[0] is None and self.started:
            self.bar.update()
        self.bar.close()


@dataclass
class SameEpisodes:
    """Every controller of one evaluation on the same episodes: ``evaluate.episodes`` from the evaluation seed at
    ``start``, ``lose`` buoys lost half-way, in ``current``, for ``steps``; ``reached`` keeps each learned policy's
    best final layout, a start of the best layout's search (``limit``)."""

    region: Region
    params: Params
    n_agents: int
    start: str
    lose: int
    current: Current | tuple[float, float] | None
    steps: int
    reached: list[tuple[float, np.ndarray]] = field(default_factory=list)  # (coverage, layout [N_live, 2])

    def run(self, policy, sensors: SensorsConfig | None) -> tuple[np.ndarray, np.ndarray]:
        """Every buoy's position at every step [T + 1, E, N, 2] and the live buoys' last [E, N_live, 2]."""
        ev = self.params.evaluate
        env, _ = general_evaluation_env(self.params, self.region, self.n_agents, ev.episodes, sensors, self.current)
        trace = rollout(env, policy, self.steps, ev.seed, StartsConfig(start=self.start, lose=self.lose))
        return trace["positions"], trace["live"]

    def per_episode(self, live: np.ndarray) -> np.ndarray:  # SPEC §8's exact coverage of the buoys in service
        return coverage.coverage_fraction(self.region.polygon, live, self.params.coverage.radius,
                                          self.params.coverage.edges)

    def covered(self, policy) -> dict:
        """A baseline's coverage (mean and interval over episodes)."""
        return mean_interval(self.per_episode(self.run(policy, None)[1]))

    def learned(self, module, meta) -> dict:
        """A general policy's coverage and largest distance outside the water, on its own sensors."""
        positions, live = self.run(fleet_policy(module), SensorsConfig(**meta["sensor_config"]))
        per_episode = self.per_episode(live)
        self.reached.append((float(per_episode.max()), live[int(np.argmax(per_episode))]))
        return {"coverage": mean_interval(per_episode),
                "max_outside_m": float(distance_outside(self.region.polygon, positions).max()) * self.region.scale}

    def limit(self) -> tuple[float, bool]:
        """The best layout of the buoys in service, searched from the policies' best final layout too."""
        c = self.params.coverage
        return best_coverage_from(self.region.polygon, self.n_agents - self.lose, c.radius, c.edges,
                                  max(self.reached, key=lambda r: r[0])[1])


def evaluate_policy(policy_path: str | Path, region: Region, params: Params, n_agents: int, start: str = "corner",
                    lose: int = 0, current: Current | tuple[float, float] | None = None, progress: bool = False,
                    seeds: dict[Hashable, str | Path] | None = None, geodesic: bool = True, naive: bool = True,
                    best_layout: bool = True, beside: bool = False, decentralised: bool = False,
                    planner: bool = False) -> dict:
    """A general policy (``export.export_general``) on ``region`` with ``n_agents`` buoys, zero-shot: behind the
    wall, on its local sensors, ``evaluate.episodes`` episodes from the evaluation seed at ``start``, losing
    ``lose`` buoys half-way, in ``current`` (a ``Current``, or a uniform flow in m/s). Beside it, under the same
    physics, starts and events, the baselines of ``general_baselines`` (gains from the policy's metadata) and the
    best layout of the buoys left in service (``best_layout``: no physics, the limit; searched from the policies'
    best final layout too, ``best_coverage_from``). → coverage (mean, lo, hi, n
    over episodes), the
    baselines', ``ratio_to_lloyd``, ``ratio_to_best`` and ``max_outside_m``: the largest distance of any buoy
    outside the water at any step of any episode. ``seeds`` ({label: policy file}, e.g. every trained seed of
    the general policy) are run on the same episodes, each under ``"seeds"`` with its ``coverage`` and
    ``max_outside_m``; the baselines run once for all. ``geodesic``, ``naive`` and ``best_layout`` False leave
    that comparison out (its ratio is then None); Lloyd always runs; ``decentralised`` adds decentralised Lloyd,
    ``planner`` the clairvoyant planner. ``beside`` runs Lloyd's episodes in a second process while this one runs
    the rest (a command's wall time on two cores; the same numbers)."""

    module, meta = read_general_policy(policy_path)
    others = {label: read_general_policy(path) for label, path in (seeds or {}).items()}
    steps = horizon(params.general, region, params.world.region_area)
    same = SameEpisodes(region, params, n_agents, start, lose, current, steps)
    rivals, how = general_baselines(params, meta.get("baseline_gains"), geodesic, naive, decentralised, planner)
    lloyd_key = lloyd_name(rivals)
    aside = Beside(lambda: same.covered(rivals[lloyd_key])) if beside else None
    with Phases(region.name, 1 + len(others) + len(rivals) + best_layout, progress) as phase:
        phase("the policy")
        out = {"kind": "general policy", "policy": str(policy_path), "region": region.name, "n_agents": n_agents,
               "start": start, "lose": lose, "current": current_record(current), "steps": steps,
               "episodes": params.evaluate.episodes, **same.learned(module, meta), "baselines": {}}
        for label, policy in others.items():
            phase(f"seed {label}")
            out.setdefault("seeds", {})[label] = same.learned(*policy)
        out["baselines"], (best, from_policy) = rivals_and_limit(
            rivals, same.covered, same.limit if best_layout else None, {lloyd_key: aside} if aside else {}, phase)
        for name in rivals:
            out["baselines"][name]["gains"] = how
        out["baselines"] |= limits(region, params, n_agents - lose, best if best_layout else None, from_policy)
    mine, lloyd = out["coverage"]["mean"], out["baselines"][lloyd_key]["coverage"]["mean"]
    return out | {"ratio_to_lloyd": mine / lloyd if lloyd > 0 else None,
                  "ratio_to_best": mine / best if best > 0 else None}


def current_record(current: Current | tuple[float, float] | None) -> list[float] | dict | None:
    """A current as a result records it: a uniform flow as [x, y] m/s, a vortex as ``Current.describe``."""
    if isinstance(current, Current):
        return current.describe() if current.core[0] > 0 else [float(v) for v in current.flow[0]]
    return None if current is None else [float(v) for v in current]


def fleet_policy(module) -> baselines.Policy:
    """A general policy's TorchScript module as a deterministic policy of an environment's local sensors."""
    if takes_positions(module):  # messages between the buoys that hear each other
        def policy(env: CoverageEnv) -> np.ndarray:
            live = np.ones(env.pos.shape[:2], bool) if env.alive is None else env.alive
            with torch.no_grad():
                return module(torch.as_tensor(env.observe()), torch.as_tensor(env.pos, dtype=torch.float32),
                              torch.as_tensor(live)).numpy()

        return policy

    def policy(env: CoverageEnv) -> np.ndarray:
        with torch.no_grad():
            return module(torch.as_tensor(env.observe())).numpy()

    return policy


def general_episode(policy_path: str | Path, region: Region, params: Params, n_agents: int, start: str,
                    lose: int = 0, current: Current | tuple[float, float] | None = None,
                    seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One episode of a general policy as ``evaluate_policy`` runs it (the wall, its sensors, the event) for
    the figures: positions [T + 1, N, 2] and the buoys in service [T + 1, N]."""

    module, meta = read_general_policy(policy_path)
    env, steps = general_evaluation_env(params, region, n_agents, 1, SensorsConfig(**meta["sensor_config"]), current)
    seed = params.evaluate.seed if seed is None else seed
    trace = rollout(env, fleet_policy(module), steps, seed, StartsConfig(start=start, lose=lose))
    return trace["positions"][:, 0], trace["alive"][:, 0]


def read_general_policy(path: str | Path):
    """(module, metadata) of a general policy file, refused by name when it is another kind of policy."""

    if Path(path).name == "actor.pt":
        raise ConfigError(f"{path}: a general run's actor; export it first (`replicate export RUN`) and give "
                          "the exported policy file instead")
    module, meta = load_policy(path)
    if meta.get("n_agents") != "any" or "sensor_config" not in meta:
        raise ConfigError(f"{path}: a policy for {meta.get('n_agents')} buoys of one region; --policy takes a "
                          "general policy (`replicate export` of a general run)")
    return module, meta
