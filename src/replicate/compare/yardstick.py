"""The yardstick: where two versions of the general training (a sensor, a value, a network) are compared
before one is kept.

Each version is given as the exported policies of several training seeds. They run, zero-shot and on the same
episodes, on lakes of a seed stream of their own (``lakes.yardstick``): never trained on, and never the test
lakes the report judges the kept version on. A cell is one lake × fleet × start × event (``YardstickCell``); a
policy's score is its mean over the cells of its coverage / ``lloyd_tuned``'s, Lloyd run on the same starts and
events with the gains the policies carry. The candidate is kept when the bootstrap interval of its gain lies above
``yardstick.min_gain`` with the training seed as the unit: one seed moves every cell at once, so an interval over
cells is too narrow (``docs/GENERAL.md``, "Choosing on lakes of their own", has the case that showed it).
The baseline version is by default the standing one (``STANDING``, stage ``train_yardstick``): the current values on
the tuning seeds of ``yardstick.seeds``, so that a candidate trains only its own seeds. Its drift flows along +x in
every cell (the suite's heading is drawn per cell), so that its decisions stay comparable with the ones recorded in
``docs/GENERAL.md``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from replicate.compare import stats
from replicate.compare.evaluate import evaluate_policy, read_general_policy
from replicate.compare.rivals import lloyd_name
from replicate.compare.suite import suite_event
from replicate.core.artifacts import CheckpointError
from replicate.core.executor import map_jobs
from replicate.core.params import Params, load_params
from replicate.core.schema import ConfigError
from replicate.learn.process import training_process
from replicate.learn.runs import SEED_POLICY, finished_general, general_identity, seed_folder
from replicate.world.lakes import yardstick
from replicate.world.regions import Region, at_density
from replicate.world.scenario import named_lakes


@dataclass(frozen=True)
class YardstickCell:
    """One cell of the yardstick: a lake of ``lakes.yardstick``, a fleet, a start and an event."""

    lake: str
    n_agents: int
    start: str
    event: str


SIDES = ("baseline", "candidate")
STANDING = "yardstick"  # the standing baseline's folder (stage train_yardstick), beside the parameters file


@dataclass(frozen=True)
class SeedPolicy:
    """One training seed's policy in a comparison: its version (of ``SIDES``) and its place among that
    version's files (1, 2, ...). Written to JSON as its label, ``baseline/1``."""

    side: str
    index: int

    def __str__(self) -> str:
        return f"{self.side}/{self.index}"


@dataclass(frozen=True)
class Versions:
    """The two versions compared, each the exported policy files of its training seeds."""

    baseline: tuple[str, ...]
    candidate: tuple[str, ...]

    def files(self) -> dict[SeedPolicy, str]:
        """{seed: policy file}: the baseline's seeds, then the candidate's, in the order given."""
        return {SeedPolicy(side, i): path for side in SIDES for i, path in enumerate(getattr(self, side), start=1)}


def yardstick_lakes(params: Params) -> dict[str, tuple[Region, int]]:
    """The yardstick's lakes → (region, the fleet it is drawn for)."""

    return named_lakes(params, yardstick(params.yardstick.lakes))


def yardstick_cells(params: Params) -> list[YardstickCell]:
    """Every cell of the yardstick, lake by lake."""
    d = params.yardstick
    return [YardstickCell(lake, n, start, event) for lake in yardstick_lakes(params) for n in d.fleets
            for start in d.starts for event in d.events]


def standing_baseline(params: Params, folder: Path) -> tuple[str, ...]:
    """The exported policies of the standing baseline in ``folder`` (``pipeline.general.train_yardstick``: the
    general training's current values on ``yardstick.seeds``), refused by name when it is missing, unreadable, of
    other seeds than ``yardstick.seeds`` or trained with other values than ``params`` (its runs' identities must
    match: a stale baseline would credit or blame the candidate for every change made since)."""

    retrain = "`dvc repro train_yardstick` trains it again, or give --baseline"
    summary = folder / "summary.json"
    if not summary.is_file():
        raise ConfigError(f"{summary}: no standing baseline here (it is read beside the parameters file); train it "
                          "with `dvc repro train_yardstick`, or give --baseline with the policies of each seed")
    try:
        seeds = [run["seed"] for run in json.loads(summary.read_text())["runs"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{summary}: not a standing baseline's summary ({type(exc).__name__}: {exc}); "
                          f"{retrain}") from None
    if seeds != list(params.yardstick.seeds):
        raise ConfigError(f"{summary}: the standing baseline's seeds are {seeds}, yardstick.seeds "
                          f"{list(params.yardstick.seeds)}; {retrain}")
    for seed in seeds:
        run = seed_folder(folder, seed)
        try:
            same = finished_general(run, general_identity(params, seed)) is not None
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{run / 'run.json'}: unreadable ({type(exc).__name__}: {exc}); {retrain}") from None
        if not same:
            raise ConfigError(f"{run}: the standing baseline was trained with other values than the params given "
                              f"(or did not finish); {retrain}")
    return tuple(str(seed_folder(folder, seed) / SEED_POLICY) for seed in seeds)


def check_versions(versions: Versions, min_seeds: int) -> None:
    """Refuse, by name, what cannot give a seed-level interval or a common yardstick: fewer than ``min_seeds``
    seeds a version, a missing or non-general policy file, one file on both sides, a policy without the tuned
    baselines' gains, policies carrying different gains (their Lloyd would differ)."""

    for side in SIDES:
        if len(getattr(versions, side)) < min_seeds:
            raise ConfigError(f"--{side}: give the policies of at least {min_seeds} training seeds "
                              "(yardstick.min_seeds: the interval resamples seeds, and fewer make it too narrow), got "
                              f"{len(getattr(versions, side))}")
    files = versions.files()
    if len({str(Path(p).resolve()) for p in files.values()}) < len(files):
        raise ConfigError("--baseline/--candidate: a policy file is given twice; each seed's policy once")
    gains = {}
    for seed, path in files.items():
        option = "--" + seed.side
        if not Path(path).is_file():
            raise ConfigError(f"{option} {path}: no such file; export each seed's run with `replicate export`")
        try:
            meta = read_general_policy(path)[1]
        except (ConfigError, CheckpointError) as exc:
            raise ConfigError(f"{option} {path}: not an exported general policy ({exc})") from None
        if not meta.get("baseline_gains"):
            raise ConfigError(f"{option} {path}: carries no tuned baseline gains; export it with `replicate export "
                              "RUN --baseline-gains metrics/tuning/general_baselines.json`")
        gains[path] = meta["baseline_gains"]
    first, *rest = gains
    differ = [path for path in rest if gains[path] != gains[first]]
    if differ:
        raise ConfigError(f"{differ[0]}: carries other baseline gains than {first}; export every policy with the "
                          "same `--baseline-gains` file, so that both versions are read against the same Lloyd (the "
                          "standing baseline in yardstick/ is exported again by `dvc repro train_yardstick`)")


def _yardstick_lake(job: dict) -> list[dict]:
    """Every cell of one lake (a job of ``compare_versions``): every policy and Lloyd on the same episodes."""

    training_process()
    params = load_params(job["params"], job["overrides"])
    d, su = params.yardstick, params.general.suite
    params = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, episodes=d.episodes,
                                                                      seed=d.seed))
    region, drawn_for = yardstick_lakes(params)[job["lake"]]
    (first, path), *others = job["policies"].items()
    rows = []
    for cell in map(lambda c: YardstickCell(**c), job["cells"]):
        lake = at_density(region, drawn_for, cell.n_agents)
        lose, current = suite_event(su, cell.event, cell.n_agents, water=lake.polygon)
        r = evaluate_policy(path, lake, params, cell.n_agents, cell.start, lose, current, seeds=dict(others),
                            geodesic=False, naive=False, best_layout=False)
        coverage = {first: r["coverage"]["mean"], **{k: v["coverage"]["mean"] for k, v in r["seeds"].items()}}
        lloyd = lloyd_name(r["baselines"])  # lloyd_tuned, or the hand-set lloyd for policies without gains
        rows.append({**dataclasses.asdict(cell), "lloyd": r["baselines"][lloyd]["coverage"]["mean"],
                     "lloyd_name": lloyd, "coverage": coverage})
    return rows


def seed_scores(rows: list[dict], seeds: list[SeedPolicy]) -> dict[SeedPolicy, float]:
    """{seed: mean over the cells of coverage / lloyd_tuned}: one number per training seed, ``rows``' coverage
    keyed by the same seeds."""
    ratio = np.array([[row["coverage"][seed] / row["lloyd"] for row in rows] for seed in seeds])
    return dict(zip(seeds, ratio.mean(axis=1).tolist()))


def side_scores(scores: dict[SeedPolicy, float], side: str) -> list[float]:
    """The scores of one version's seeds, in their order."""
    return [v for seed, v in scores.items() if seed.side == side]


def side_means(scores: dict[SeedPolicy, float]) -> dict[str, float]:
    """{"baseline": mean of its seeds' scores, "candidate": ...}."""
    return {side: float(np.mean(side_scores(scores, side))) for side in SIDES}


def verdict(scores: dict[SeedPolicy, float], params: Params) -> dict:
    """The rule, applied: Δ = mean candidate score − mean baseline score, its bootstrap interval over training
    seeds (``report``'s level, resamples and seed) and P(a candidate seed beats a baseline seed); the candidate
    is kept when the interval lies above ``yardstick.min_gain``."""
    r = params.report
    boot = stats.Bootstrap.of(r)
    base, cand = side_scores(scores, "baseline"), side_scores(scores, "candidate")
    diff = stats.difference([cand], [base], boot)
    better = stats.probability_of_improvement([cand], [base], boot)
    keep = diff["lo"] > params.yardstick.min_gain
    return {"difference": diff, "probability_of_improvement": better, "min_gain": params.yardstick.min_gain,
            "keep": "candidate" if keep else "baseline",
            "rule": f"keep the candidate iff the {r.level:.0%} bootstrap interval over training seeds of its mean "
                    f"coverage / lloyd_tuned minus the baseline's lies above {params.yardstick.min_gain:+g}"}


def compare_versions(params_path: str, versions: Versions, workers: int = 1, executor: str = "local",
                     overrides: dict | None = None, progress: bool = False) -> dict:
    """Both versions on every cell of the yardstick (one job per lake), each seed's score and the
    verdict. → {cells, scores, verdict, by_event}: ``by_event`` gives each version's mean score per event."""
    params = load_params(params_path, overrides)
    check_versions(versions, params.yardstick.min_seeds)
    policies = versions.files()
    cells = yardstick_cells(params)
    jobs = [{"params": params_path, "overrides": overrides or {}, "lake": lake, "policies": policies,
             "cells": [dataclasses.asdict(c) for c in cells if c.lake == lake]}
            for lake in dict.fromkeys(c.lake for c in cells)]
    shown = "yardstick lakes" if progress else None
    rows = [row for rows_of in map_jobs(_yardstick_lake, jobs, executor, workers, shown) for row in rows_of]
    scores = seed_scores(rows, list(policies))
    by_event = {event: side_means(seed_scores([r for r in rows if r["event"] == event], list(policies)))
                for event in params.yardstick.events}
    return {"policies": labelled(policies), "yardstick": dataclasses.asdict(params.yardstick),
            "cells": [row | {"coverage": labelled(row["coverage"])} for row in rows], "scores": labelled(scores),
            "by_event": by_event, "verdict": verdict(scores, params)}


def labelled(by_seed: dict[SeedPolicy, object]) -> dict[str, object]:
    """``by_seed`` keyed by each seed's label, as written to JSON."""
    return {str(seed): value for seed, value in by_seed.items()}
