"""Searches on seeds and starts that no reported number uses: Optuna studies (seeded TPE) in one storage.

* ``tune_baselines``: every gain of naive swarming and of Lloyd, per region, at the region's T from the paper's
  corner start, scored by the exact coverage on the tuning starts (``tuning.starts_seed``, never
  ``evaluate.seed``). The pipeline's ``tune_baselines`` stage writes the best gains to
  ``metrics/tuning/baselines.json``; ``evaluate`` reports them as ``naive_tuned`` and ``lloyd_tuned``.
* ``tune_method``: a method's training values inside a config (``tuning.method``), each trial a shortened
  training on the tuning seeds, scored by its kept actors' coverage on the tuning starts. Its best values are
  written into ``configs.CONFIG.per_method.METHOD`` by hand: a training search is a decision, not a stage.

Studies live in ``tuning.baselines.storage`` and ``tuning.method.storage`` (SQLite files by default, any
SQLAlchemy URL such as PostgreSQL for several workers): a study interrupted is resumed where it stopped, and one
already complete is read back, not rerun.
Every trial records its CPU seconds, so the report states each search's budget.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import shutil
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from replicate.compare import baselines
from replicate.compare.decentralised import decentralised_lloyd
from replicate.compare.evaluate import actor_policy, rollout
from replicate.core.executor import map_jobs, parallel_slots
from replicate.core.params import Params, RegionKey, run_config, with_values
from replicate.core.schema import to_dict
from replicate.core.studies import Dimension, LloydConfig, NaiveConfig, StartsConfig
from replicate.learn.fingerprint import search_fingerprint
from replicate.learn.process import training_process
from replicate.learn.runs import TRAINING_VERSION
from replicate.learn.train import load_actors, train_runs
from replicate.learn.training_worlds import baseline_worlds
from replicate.world import coverage
from replicate.world.currents import random_current
from replicate.world.geometry import region_key
from replicate.world.regions import Region
from replicate.world.scenario import evaluation_env, general_env, horizon

log = logging.getLogger(__name__)

BASELINE_KINDS = ("naive", "lloyd")


def study_name(prefix: str, *searched) -> str:
    """``prefix`` and a digest of what the study searches (space, starts, world, ...): a changed search starts a
    study of its own instead of resuming trials drawn from another space. The trial count is not part of it, so
    raising ``trials`` continues the study."""
    digest = hashlib.sha256(json.dumps(to_dict(list(searched)), sort_keys=True, default=str).encode()).hexdigest()
    return f"{prefix}-{digest[:10]}"


class QuietInterrupt(logging.Filter):
    """Optuna logs a trial stopped by Ctrl-C as a failure, with its traceback; the command says it was interrupted
    in one line instead (``toolkit.cli.command``)."""

    def filter(self, record: logging.LogRecord) -> bool:
        cause = record.exc_info[1] if record.exc_info else None
        return not (isinstance(cause, KeyboardInterrupt) or "KeyboardInterrupt" in record.getMessage())


def open_storage(storage: str):
    """The Optuna storage at the SQLAlchemy URL ``storage``, its tables created if new: open it once before several
    processes share a new file, or they race to create the same tables."""
    import optuna

    if storage.startswith("sqlite:///"):
        Path(storage.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if not any(isinstance(f, QuietInterrupt) for f in optuna.logging.get_logger("optuna").filters):
        optuna.logging.get_logger("optuna").addFilter(QuietInterrupt())
    # a worker's heartbeat: the trial of a worker that died (killed, machine lost) is failed after the grace
    # period, so a resumed study does not wait for it, while the live trials of other workers go on
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.storages.RDBStorage(storage, heartbeat_interval=60, grace_period=180)


def open_study(storage: str, name: str, sampler_seed: int):
    """The study ``name`` in ``storage`` (created if new), maximising, with a seeded TPE sampler."""
    import optuna

    rdb = open_storage(storage)
    study = optuna.create_study(study_name=name, storage=rdb, direction="maximize", load_if_exists=True)
    # the sampler's generator continues from the trials already there (a resumed study would otherwise draw its
    # first trials again): an uninterrupted study is the same on every machine, a resumed one has no repeats
    study.sampler = optuna.samplers.TPESampler(seed=sampler_seed + len(study.trials))
    return study


def suggest(trial, space: dict[str, Dimension]) -> dict:
    """One value per searched key, drawn by the trial's sampler."""
    values = {}
    for key, dim in space.items():
        if dim.choices is not None:
            values[key] = trial.suggest_categorical(key, list(dim.choices))
        elif dim.integer:
            values[key] = trial.suggest_int(key, int(dim.low), int(dim.high), log=dim.log)
        else:
            values[key] = trial.suggest_float(key, dim.low, dim.high, log=dim.log)
    return values


def run_trials(study, score: Callable[[dict], tuple[float, float]], space: dict[str, Dimension], trials: int,
               executor: str = "local", progress: str | None = None) -> None:
    """Complete the study to ``trials`` finished trials (a resumed study runs only the missing ones); a trial
    draws values for ``space`` and ``score(values)`` gives (value, CPU seconds).

    ``local``: one trial after another in this process, TPE seeing every result before its next draw (the order
    the committed studies were run in). ``ray``: batches of as many trials as the cluster has CPUs, each trial a
    Ray task (TPE draws a batch before it sees its results). Any number of processes may work on one study at
    once through a shared storage URL. Each trial records its CPU seconds and the arithmetic fingerprint of the
    process running the sampler (``fingerprint.search_fingerprint``) as user attributes. ``progress`` names a bar
    of the trials (a command's; the pipeline's stages show none)."""
    import optuna

    def finished() -> int:
        return len(study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)))

    if executor == "local":
        def objective(trial) -> float:
            value, cpu = score(suggest(trial, space))
            trial.set_user_attr("cpu_seconds", cpu)
            trial.set_user_attr("arithmetic", search_fingerprint())
            return value

        if finished() < trials:
            if progress:
                log.info("%s: %d trials", progress, trials - finished())
            study.optimize(objective, n_trials=trials - finished(), show_progress_bar=progress is not None)
        return
    slots = parallel_slots(executor, 1)
    while (done := finished()) < trials:
        batch = [study.ask() for _ in range(min(slots, trials - done))]
        try:
            results = map_jobs(score, [suggest(t, space) for t in batch], executor, progress=progress)
        except BaseException:
            for t in batch:
                study.tell(t, state=optuna.trial.TrialState.FAIL)
            raise
        for t, (value, cpu) in zip(batch, results, strict=True):
            t.set_user_attr("cpu_seconds", cpu)
            t.set_user_attr("arithmetic", search_fingerprint())  # the sampler's process (workers score)
            study.tell(t, value)


def cpu_seconds(study) -> float:
    return float(sum(t.user_attrs.get("cpu_seconds", 0.0) for t in study.trials))


def budget(study) -> dict:
    """What a study cost: its finished trials, the trials that failed (a killed worker's), one core's seconds."""
    import optuna

    states = [t.state for t in study.trials]
    return {"trials": states.count(optuna.trial.TrialState.COMPLETE),
            "failed_trials": states.count(optuna.trial.TrialState.FAIL),
            "cpu_seconds": round(cpu_seconds(study), 1), "study": study.study_name}


# ---- baselines -------------------------------------------------------------------------------------------
def policy_with_gains(kind: str, gains: dict, params: Params) -> baselines.Policy:
    if kind == "naive":
        return baselines.naive_swarming(NaiveConfig(**gains))
    lloyd = LloydConfig(**gains, converged_steps=params.evaluate.lloyd.converged_steps)
    if kind == "decentralised":
        return decentralised_lloyd(lloyd, params.evaluate.geodesic.spacing)
    if kind == "geodesic":
        return baselines.geodesic_lloyd(lloyd, params.evaluate.geodesic.spacing, params.evaluate.geodesic.lookahead)
    return baselines.lloyd(lloyd)


def gain_space(params: Params, kind: str):
    """The search of a baseline kind's gains: decentralised and geodesic Lloyd search Lloyd's space."""
    return getattr(params.tuning.baselines, "lloyd" if kind in ("decentralised", "geodesic") else kind)


def baseline_coverage(kind: str, gains: dict, params: Params, region: Region, seed: int, episodes: int) -> float:
    """Mean exact coverage of a baseline with ``gains`` at the region's T from the corner start, ``episodes``
    starts drawn from ``seed``."""
    rc = run_config(params, "paper", "cr", region.name)
    env = evaluation_env(region, rc, episodes)
    env.reset(seed)
    policy = policy_with_gains(kind, gains, params)
    for _ in range(rc.world.episode_length):
        env.step(policy(env))
    return float(coverage.coverage_fraction(region.polygon, env.pos, rc.coverage.radius, rc.coverage.edges).mean())


def baseline_score(kind: str, params: Params, region: Region, seed: int, episodes: int, gains: dict):
    """One baseline trial: (coverage, CPU seconds)."""
    t0 = time.process_time()
    return baseline_coverage(kind, gains, params, region, seed, episodes), time.process_time() - t0


def tune_baseline(params: Params, region: Region, kind: str, executor: str = "local", progress: bool = False) -> dict:
    """The ``kind`` baseline's study on ``region``: best gains, their tuning coverage, the budget."""
    tc = params.tuning
    search = getattr(tc.baselines, kind)
    rc = run_config(params, "paper", "cr", region.name)
    name = study_name(f"{kind}-{region.name}", search.space, tc.starts_seed, tc.starts, tc.sampler_seed,
                      region_key(region.polygon), rc.world, rc.coverage)
    study = open_study(tc.baselines.storage, name, tc.sampler_seed)
    score = functools.partial(baseline_score, kind, params, region, tc.starts_seed, tc.starts)
    run_trials(study, score, search.space, search.trials, executor, f"{kind} on {region.name}" if progress else None)
    return {"gains": dict(study.best_params), "tuning_coverage": study.best_value, **budget(study),
            "storage": tc.baselines.storage}


def tune_baselines(params: Params, regions: dict[str, Region], executor: str = "local", progress: bool = False) -> dict:
    """Every baseline kind on every region → ``{"KIND/REGION": tune_baseline(...)}``."""
    return {RegionKey(kind, name).key: tune_baseline(params, region, kind, executor, progress)
            for kind in BASELINE_KINDS for name, region in regions.items()}


# ---- the general policy's baselines: one set of gains for every lake -------------------------------------
_GENERAL_WORLDS: dict[str, list] = {}


def general_worlds(params: Params) -> list:
    """(region, world env) of every world of ``training_worlds.baseline_worlds``, behind the wall, with half the
    study's starts as environments; built once per process and setting (a lake's geometry takes seconds)."""

    gc, starts = params.general, params.tuning.general_baselines.starts
    key = study_name("worlds", gc, params.world, params.coverage, params.regions, starts)
    if key not in _GENERAL_WORLDS:
        _GENERAL_WORLDS[key] = [(region, general_env(params, gc, region, n, max(1, starts // 2), 0, reward=False,
                                                   sensors=False)) for region, n in baseline_worlds(params, gc)]
    return _GENERAL_WORLDS[key]


def general_baseline_coverage(kind: str, params: Params, gains: dict) -> float:
    """Mean exact coverage (of the buoys in service) at each world's evaluation horizon over every training world:
    half of the episodes released in the corner patch in still water, half scattered with the events the policy
    trains on (world k even: ``general.lose_fraction`` of the fleet lost at T/2; odd: a random drift or vortex up
    to ``general.current_speed``); starts and events drawn from ``tuning.starts_seed``."""

    gc, seed = params.general, params.tuning.starts_seed
    policy, scores = policy_with_gains(kind, gains, params), []
    for k, (region, env) in enumerate(general_worlds(params)):
        steps = horizon(gc, region, params.world.region_area)
        for start in ("corner", "random"):
            lose = max(1, int(gc.lose_fraction * env.n_agents)) if start == "random" and k % 2 == 0 else 0
            drift = start == "random" and k % 2 == 1
            env.set_current(random_current(np.random.default_rng([seed, k]), env.n_envs, region.polygon,
                                           gc.current_speed) if drift else None)
            live = rollout(env, policy, steps, seed + k, StartsConfig(start, lose=lose))["live"]
            env.set_current(None)
            scores.append(coverage.coverage_fraction(region.polygon, live, params.coverage.radius,
                                                    params.coverage.edges).mean())
    return float(np.mean(scores))


def general_baseline_score(kind: str, params: Params, gains: dict) -> tuple[float, float]:
    """One trial of the general baselines' study: (coverage, CPU seconds)."""
    t0 = time.process_time()
    return general_baseline_coverage(kind, params, gains), time.process_time() - t0


GENERAL_KINDS = ("naive", "lloyd", "decentralised", "geodesic")  # the general baselines tuned, each a study
# what a kind's controller reads besides the world, part of its study's name: a changed sensor or raster is a new
# study (naive swarming and clairvoyant Lloyd read neither)
READS = {"decentralised": lambda p: (p.general.sensors, p.evaluate.geodesic.spacing),
         "geodesic": lambda p: (p.evaluate.geodesic,)}


def tune_general_baselines(params: Params, executor: str = "local", workers: int = 1, progress: bool = False) -> dict:
    """Naive swarming's, Lloyd's, decentralised Lloyd's and geodesic Lloyd's studies on the general policy's
    training worlds → ``{"naive_tuned": {gains, tuning_coverage, budget}, "lloyd_tuned": {...},
    "decentralised_tuned": {...}, "geodesic_tuned": {...}}``.

    Locally the studies run side by side in ``workers`` processes, each one's trials in order (the same trials as
    one process running them all); with Ray each study spreads its trials over the cluster in turn."""
    kinds = GENERAL_KINDS
    if executor == "local":
        open_storage(params.tuning.general_baselines.storage)  # its tables, before two processes open it
        results = map_jobs(functools.partial(general_study, params), kinds, "local", workers,
                           progress="general baselines' studies" if progress else None)
    else:
        results = [general_study(params, kind, executor, progress) for kind in kinds]
    return {f"{kind}_tuned": result for kind, result in zip(kinds, results)}


def general_study(params: Params, kind: str, executor: str = "local", progress: bool = False) -> dict:
    """One baseline's study of ``tune_general_baselines``, completed (or read back) → its result."""

    tc, gb = params.tuning, params.tuning.general_baselines
    worlds = [(region_key(region.polygon), n) for region, n in baseline_worlds(params, params.general)]
    search = gain_space(params, kind)
    events = (params.general.lose_fraction, params.general.current_speed)
    name = study_name(f"general-{kind}", search.space, tc.starts_seed, gb.starts, tc.sampler_seed, worlds,
                      params.world, params.coverage, params.general.episode_length, events,
                      *READS.get(kind, lambda p: ())(params))
    study = open_study(gb.storage, name, tc.sampler_seed)
    trials = getattr(gb, f"{kind}_trials")
    run_trials(study, functools.partial(general_baseline_score, kind, params), search.space, trials, executor,
               f"{kind}, every training world" if progress else None)
    return {"gains": dict(study.best_params), "tuning_coverage": study.best_value, **budget(study),
            "storage": gb.storage}


# ---- a method's training values ------------------------------------------------------------------------
def search_base(params: Params, region: str):
    """The run config the method search starts from: ``tuning.method``'s config and method with the config's
    own values, not the ``per_method`` values a finished search put there (so adopting them keeps the study)."""
    ms = params.tuning.method
    rc = run_config(params, ms.config, ms.method, region)
    return dataclasses.replace(rc, algo=with_values(params.configs[ms.config], {}, f"configs.{ms.config}"))


def incumbent_values(params: Params) -> dict:
    """The searched keys' values in the config as written (for SW-MARL in ``tuned``: the values chosen for CR)."""
    ms = params.tuning.method
    tree = to_dict(params.configs[ms.config])
    values = {}
    for dotted in ms.space:
        node = tree
        for part in dotted.split("."):
            node = node[part]
        values[dotted] = node
    return values


def method_trial(params: Params, region: Region, values: dict, workdir: Path) -> float:
    """Train ``tuning.method``'s config and method with ``values`` on the tuning seeds (one stack), and score
    the kept actors (selected on their own validation starts, as the reported runs are) on the tuning starts."""

    ms, tc = params.tuning.method, params.tuning
    rc = search_base(params, region.name)
    rc = dataclasses.replace(rc, algo=with_values(rc.algo, values, f"tuning.method trial {values}"))
    outs = [workdir / f"s{seed}" for seed in ms.seeds]
    train_runs(rc, region, ms.episodes, list(ms.seeds), outs, checkpoint_every=ms.episodes + 1, progress=False)
    scores = []
    for out in outs:
        net, meta = load_actors(out / "actors.pt")
        env = evaluation_env(region, rc, tc.starts, meta["observation"])
        pos = rollout(env, actor_policy(net, meta["observation"]), rc.world.episode_length, tc.starts_seed)
        scores.append(coverage.coverage_fraction(region.polygon, pos["positions"][-1], rc.coverage.radius,
                                                rc.coverage.edges).mean())
    return float(np.mean(scores))


def method_score(params: Params, regions: dict[str, Region], values: dict) -> tuple[float, float]:
    """One method trial: the mean score of ``method_trial`` over the regions, and its CPU seconds."""
    training_process()  # a trial trains: in a Ray worker as in the CLI's process
    t0 = time.process_time()
    workdir = Path(tempfile.mkdtemp(prefix="replicate-trial-"))
    try:
        score = float(np.mean([method_trial(params, region, values, workdir / name)
                               for name, region in regions.items()]))
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return score, time.process_time() - t0


def tune_method(params: Params, regions: dict[str, Region], executor: str = "local", progress: bool = False) -> dict:
    """The ``tuning.method`` study: trials train on every region of ``tuning.method.regions`` and score their
    mean coverage. → best values, best score, budget."""
    ms, tc = params.tuning.method, params.tuning
    rcs = [search_base(params, r) for r in ms.regions]
    searched = {k: v for k, v in to_dict(ms).items() if k not in ("storage", "result")} | {"trials": 0}
    name = study_name(f"{ms.config}-{ms.method}", searched, tc.starts_seed, tc.starts,
                      tc.sampler_seed, [region_key(regions[r].polygon) for r in ms.regions], rcs,
                      TRAINING_VERSION)
    study = open_study(ms.storage, name, tc.sampler_seed)
    score = functools.partial(method_score, params, {r: regions[r] for r in ms.regions})
    incumbent = incumbent_values(params)
    if not any(t.params == incumbent for t in study.trials):
        study.enqueue_trial(incumbent)  # the config's own values are a trial: the search can only improve on them
    run_trials(study, score, ms.space, ms.trials, executor, f"{ms.config} {ms.method}" if progress else None)
    return {"values": dict(study.best_params), "tuning_coverage": study.best_value, **budget(study),
            "storage": ms.storage, "incumbent": incumbent, "incumbent_coverage": next(
                (t.value for t in study.trials if t.params == incumbent and t.value is not None), None)}
