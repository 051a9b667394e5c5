"""The sections of ``params.yaml`` that say how results are read: the evaluation and its baselines, the searches
(Optuna studies and the record of the hand search), the report's verdict rules, the ablation and the speed targets
``make bench`` prints its figures against.

Each value's type and range stand beside it (``schema``).
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, model_validator

from replicate.core.schema import (
    ConfigError,
    Count,
    Flag,
    Fleet,
    In,
    NonNegative,
    Num,
    Positive,
    Seed,
    Share,
    Text,
    Whole,
    section,
)


def database_url(value: str) -> str:
    """An SQLAlchemy URL (``dialect[+driver]://...``), checked before a study opens it."""
    if not re.match(r"^[A-Za-z][\w+.-]*://", value):
        raise ValueError("must be an SQLAlchemy URL such as sqlite:///metrics/tuning/studies.db or "
                         "postgresql://USER@HOST/DB")
    return value


Storage = Annotated[Text, AfterValidator(database_url)]  # where an Optuna study lives


@section
class NaiveConfig:
    attraction: Num
    avoid_range: Num
    avoidance: Num
    damping: Num


@section
class LloydConfig:
    gain: Num
    damping: Num
    converged_steps: Whole


@section
class GeodesicConfig:
    """Geodesic Lloyd (``baselines.geodesic_lloyd``): the water's raster and how far ahead a buoy aims along its
    path; its gains are Lloyd's."""

    spacing: Positive  # m between the water graph's points (at most the coverage radius, checked by ``Params``)
    lookahead: Positive  # m of sailing to the waypoint a buoy steers toward


@section
class StartsConfig:
    """Where the buoys are released: ``corner`` is the paper's start patch at the region's lower-left corner,
    ``opposite`` the same patch at the upper-right corner, ``random`` uniform over the region."""

    start: Literal["corner", "opposite", "random"]
    horizon: Positive = 1.0  # episode length as a multiple of the region's T
    lose: Whole = 0  # buoys lost (removed, no longer covering) half-way through the episode


@section
class EvaluateConfig:
    episodes: Count
    seed: Seed
    converge_window: Count
    converge_tolerance: NonNegative
    converge_final: Count
    naive: NaiveConfig
    lloyd: LloydConfig
    geodesic: GeodesicConfig
    robustness: dict[str, StartsConfig]  # scenario name → its starts and events


@section
class Dimension:
    """One searched value: a number in [low, high] (``log``: sampled on a log scale; ``integer``: whole numbers)
    or one of ``choices``."""

    low: Num | None = None
    high: Num | None = None
    log: Flag = False
    integer: Flag = False
    choices: tuple[Any, ...] | None = None

    @model_validator(mode="after")
    def check(self):
        if self.choices is None and (self.low is None or self.high is None or not self.low < self.high):
            raise ConfigError(f"a searched value needs low < high or choices, got {self}")
        if self.log and (self.low is None or self.low <= 0):
            raise ConfigError(f"a log-scale range needs low > 0, got {self}")
        return self


@section
class Search:
    trials: Count
    space: dict[str, Dimension]  # searched key → its range


@section
class BaselineSearch:
    storage: Storage  # SQLAlchemy URL of the studies (the tune_baselines stage's SQLite file by default)
    naive: Search  # every gain of NaiveConfig
    lloyd: Search  # every gain of LloydConfig (converged_steps is not a gain)


@section
class MethodSearch:
    """A search of one method's training values inside a config (the study writes no config: its best values
    go into ``configs.CONFIG.per_method.METHOD`` by hand, with the study's name beside them)."""

    storage: Storage  # SQLAlchemy URL of the study (a committed SQLite file by default)
    result: Text  # JSON of the best values, read by the report
    config: Text
    method: Text
    regions: tuple[Text, ...]
    seeds: tuple[Seed, ...]  # training seeds of every trial, never reported
    episodes: Count
    trials: Count
    space: dict[str, Dimension]  # dotted key inside the config → its range


@section
class HandSearch:
    """The record of a search made by hand (``docs/TUNING.md``), for the report's budgets."""

    config: Text
    method: Text
    configurations: Count
    runs: Count
    cpu_seconds: NonNegative
    note: Text


@section
class GeneralBaselineSearch:
    """The gains of the general policy's comparisons (naive swarming, clairvoyant, decentralised and geodesic
    Lloyd): one set for every lake, tuned on
    its training worlds behind the wall (``tuning.tune_general_baselines``), in the spaces of ``baselines``."""

    storage: Storage  # SQLAlchemy URL of the studies
    result: Text  # JSON of the best gains, which ``replicate evaluate --policy`` reads
    starts: Count  # episodes per world and trial: half from the corner patch, half scattered
    naive_trials: Count
    lloyd_trials: Count
    decentralised_trials: Count  # decentralised Lloyd (``compare.decentralised``), in Lloyd's space of gains
    geodesic_trials: Count  # geodesic Lloyd (``baselines.geodesic_lloyd``), in Lloyd's space of gains


@section
class TuningConfig:
    sampler_seed: Seed  # the TPE sampler's seed: the same trials in the same order on every machine
    starts_seed: Seed  # evaluation starts of every trial (never ``evaluate.seed``)
    starts: Count  # evaluation episodes per trial
    baselines: BaselineSearch
    method: MethodSearch
    hand_search: HandSearch
    general_baselines: GeneralBaselineSearch


@section
class Target:
    at_least: Num  # coverage, or with ``of`` a fraction of that baseline's coverage
    of: Literal["lloyd_tuned"] | None = None


@section
class GeneralTargets:
    """The general policy's bars on the evaluation suite, as fractions of its yardsticks' coverage."""

    of_lloyd: Positive  # in still water, every cell at least this fraction of lloyd_tuned ...
    of_best: Positive  # ... and of the best layout (and above naive_tuned)
    narrow_gap: NonNegative  # a lake where lloyd_tuned falls this far short of the best layout: the policy must beat it
    lose_of_lloyd: Positive  # after a loss: at least this fraction of what lloyd_tuned re-covers
    current_of_lloyd: Positive  # in the drift: at least this fraction of lloyd_tuned in the same drift ...
    current_of_still: Positive  # ... and of its own still-water coverage


@section
class GeneralGoals:
    """What the learned general policy is built toward beyond the bars: each printed in REPORT.md with what the
    seeds measured and how far it falls short, on the test and real lakes."""

    mean_of_lloyd: Positive  # still water: the seeds' mean coverage over the cells, a multiple of lloyd_tuned's ...
    mean_of_decentralised: Positive  # ... and of decentralised Lloyd's
    of_planner: Positive  # still water: every cell, every seed at least this fraction of the planner
    lake_files_of_best: Positive  # each real lake file, still water, each start: of the best layout ...
    lake_fleet: Fleet  # ... at this many buoys
    channel: Text  # the long channel: this region with ``channel_fleet`` buoys from the corner, still water ...
    channel_fleet: Fleet
    channel_of_lloyd: Positive  # ... at least this multiple of lloyd_tuned
    seed_cpu_s: Positive  # one core's seconds a reported general seed may take


@section
class ReportConfig:
    """The verdict rules, fixed before the numbers (REPORT.md prints each beside its verdict)."""

    level: Annotated[Num, In(0, 1, open_lo=True, open_hi=True)]  # confidence level of every interval
    resamples: Count  # bootstrap resamples
    t_below: Count  # fewer seeds than this: a Student-t interval beside the percentile bootstrap
    seed: Seed  # the bootstrap's generator
    margin: NonNegative  # coverage: "A beats B" when the CI of mean(A) − mean(B) lies above this
    spread_margin: NonNegative  # metres: "CR spreads more" when the CI of Δ nearest-neighbour lies above this
    convergence_band: Literal["range", "final"]  # claim 1's band: a share of the curve's range, or of its final value
    spread: Literal["inside", "all"]  # claim 2's spread: nearest neighbours among the agents inside, or all agents
    about_episodes: Whole  # "about 5,000 episodes": within this many episodes of 5,000
    not_converged_after: Whole  # "not converged by 10,000": no convergence episode, or one after this
    majority: Share  # claim 1 holds for a method when at least this fraction of its seeds meets it
    partly: Share  # a claim over several cells: every cell holds → reproduced; at least this fraction → partly
    acceptable: NonNegative  # "acceptable coverage": the CI's lower bound at or above this fraction of the ceiling
    sensitivity: tuple[Positive, ...]  # factors applied to the margins and tolerances for the sensitivity column
    targets: dict[str, Target]  # region → tuned CR-MARL's coverage bar, on every seed
    target_seconds: Positive  # one core's seconds per 10,000-episode run
    general: GeneralTargets
    goals: GeneralGoals


@section
class BenchTargets:
    """The speed targets ``make bench`` prints each figure against (benchmarks, never timed tests)."""

    paper_run_s: Positive  # one core's seconds per 10,000-episode ``paper`` run (``tuned``: report.target_seconds)
    general_seed_s: Positive  # one core's seconds per general seed (general.episodes)
    from_scratch_min: Positive  # a forced ``dvc repro`` on two cores with 8 reported general seeds
    lake_evaluate_s: Positive  # wall seconds of ``evaluate --policy`` on a real lake, on two cores
    large_lake_evaluate_s: Positive  # ... on a generated 4,000-vertex lake with arms and islands
    peak_mb: Positive  # peak memory of a field command
    act_step_ms: Positive  # ``act --stream``: milliseconds per step, one core
    act_buoy_ms: Positive  # ... and per buoy and step with ``act_fleet`` buoys in one stream
    act_fleet: Fleet


@section
class AblationConfig:
    """Leave-one-out ablation of ``base``: for each change, a config equal to ``base`` except that the change's
    keys (dotted, inside a config) take ``reference``'s values. Named ``{base}-without-{change}``."""

    base: Text
    reference: Text
    method: Text
    regions: tuple[Text, ...]
    seeds: tuple[Seed, ...]
    changes: dict[str, tuple[Text, ...]]

