"""Typed, frozen configuration read from ``params.yaml``.

YAML holds the values, these dataclasses hold the types (BenchMARL style). ``from_mapping`` refuses unknown,
missing and mistyped keys with a message naming the key path, so a typo in ``params.yaml`` never passes
silently.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

DEFAULT_PARAMS = Path("params.yaml")


def packaged(name: str) -> Path:
    """A file installed with the package (``replicate/defaults/``): the repository's ``params.yaml``, the
    bundled Bedok outline and the general policy (``policies/general.pt``), so that every command works from any
    folder after ``pip install``."""
    from importlib.resources import files

    return Path(str(files("replicate") / "defaults" / name))


class ConfigError(ValueError):
    """A configuration value is unknown, missing or of the wrong type."""


MAX_AGENTS = 200  # buoys per region: the pairwise terms grow as N², and 1,000 buoys took 5.6 GB
MAX_SEED = 2**32 - 1  # the largest seed every generator takes (torch's manual_seed among them)


def positive(value: float, where: str) -> float:
    """``value`` if it is a finite number above 0, else a ConfigError naming ``where``."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{where} must be a positive number, got {value!r}")
    return value


def within(value: float, where: str, lo: float, hi: float = math.inf, open_lo: bool = False) -> float:
    """``value`` if it is a finite number in [lo, hi] ((lo, hi] with ``open_lo``), else a ConfigError naming
    ``where`` and the range."""
    ok = isinstance(value, (int, float)) and math.isfinite(value) and (value > lo if open_lo else value >= lo)
    if not (ok and value <= hi):
        span = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]" if math.isfinite(hi) else \
            (f"above {lo:g}" if open_lo else f"at least {lo:g}")
        raise ConfigError(f"{where} must be {'in ' if math.isfinite(hi) else ''}{span}, got {value!r}")
    return value


# The ranges a training config's values must lie in: key inside a config → (lowest, highest, lowest excluded).
ALGO_RANGES: dict[str, tuple[float, float, bool]] = {
    "reward_scale": (0, math.inf, True),
    "n_envs": (1, math.inf, False),
    "select_every": (0, math.inf, False),
    "select_episodes": (1, math.inf, False),
    "maddpg.hidden": (1, math.inf, False),
    "maddpg.actor_lr": (0, math.inf, True),
    "maddpg.critic_lr": (0, math.inf, True),
    "maddpg.gamma": (0, 1, True),
    "maddpg.tau": (0, 1, True),
    "maddpg.batch_size": (1, math.inf, False),
    "maddpg.buffer_size": (1, math.inf, False),
    "maddpg.learning_starts": (0, math.inf, False),
    "maddpg.update_every": (0, math.inf, True),
    "maddpg.grad_clip": (0, math.inf, True),
    "maddpg.actor_reg": (0, math.inf, False),
    "maddpg.noise_start": (0, math.inf, False),
    "maddpg.noise_end": (0, math.inf, False),
    "maddpg.noise_decay": (0, 1, False),
    "maddpg.lr_end": (0, math.inf, False),
    "maddpg.n_step": (1, math.inf, False),
    "sensors.neighbours": (1, MAX_AGENTS, False),
    "sensors.comm_range": (0, math.inf, True),
    "sensors.rays": (1, 360, False),
    "sensors.ray_range": (0, math.inf, True),
}


def check_algo(algo: AlgoConfig, where: str) -> None:
    """Every value of ``ALGO_RANGES`` in its range, and the optional ones (geofence, union weight) ≥ 0."""
    for dotted, (lo, hi, open_lo) in ALGO_RANGES.items():
        node = algo
        for part in dotted.split("."):
            node = getattr(node, part)
        within(node, f"{where}.{dotted}", lo, hi, open_lo)
    for key in ("geofence", "union_weight"):
        if getattr(algo, key) is not None:
            within(getattr(algo, key), f"{where}.{key}", 0)


def check_general(g: GeneralConfig, regions: dict) -> None:
    """The ``general`` section's values in their ranges and its regions known."""
    unknown = sorted(set(g.regions) - set(regions))
    if unknown:
        raise ConfigError(f"general.regions: unknown region(s) {unknown}; known: {sorted(regions)}")
    for key in ("random_starts", "lose_prob", "lose_fraction", "current_prob", "noise_decay"):
        within(getattr(g, key), f"general.{key}", 0, 1)
    for key in ("n_envs", "episodes", "episode_length", "batch_size", "buffer_size", "update_every"):
        within(getattr(g, key), f"general.{key}", 1)
    for key in ("learning_starts", "lakes", "current_speed", "noise_start", "noise_end"):
        within(getattr(g, key), f"general.{key}", 0)
    if g.episodes < g.n_envs:
        raise ConfigError(f"general.episodes ({g.episodes}) must be at least general.n_envs ({g.n_envs}): one batch")
    within(g.gamma, "general.gamma", 0, 1, open_lo=True)
    for key in ("cover_weight", "shore_penalty"):
        within(getattr(g, key), f"general.{key}", 0)
    within(g.n_step, "general.n_step", 1, 50)
    within(g.lr_end, "general.lr_end", 0, 1, open_lo=True)
    within(g.reward_scale, "general.reward_scale", 0, open_lo=True)
    for n in (*g.fleet, *g.lake_fleet):
        within(n, "general.fleet and general.lake_fleet", 2, MAX_AGENTS)
    if g.lake_fleet[0] > g.lake_fleet[1] or not 0 < g.lake_ratio[0] <= g.lake_ratio[1]:
        raise ConfigError(f"general.lake_fleet and lake_ratio are [low, high] ranges, got {list(g.lake_fleet)} "
                          f"and {list(g.lake_ratio)}")
    if not g.seeds:
        raise ConfigError("general.seeds: at least one seed")
    for key in ("neighbours", "comm_range", "rays", "ray_range"):
        lo, hi, open_lo = ALGO_RANGES[f"sensors.{key}"]
        within(getattr(g.sensors, key), f"general.sensors.{key}", lo, hi, open_lo)
    for key in ("hidden", "embed"):
        within(getattr(g.learner, key), f"general.learner.{key}", 1)
    for key in ("actor_lr", "critic_lr", "grad_clip"):
        within(getattr(g.learner, key), f"general.learner.{key}", 0, open_lo=True)
    within(g.learner.tau, "general.learner.tau", 0, 1, open_lo=True)
    within(g.learner.pool_range, "general.learner.pool_range", 0)
    within(g.learner.pool_neighbours, "general.learner.pool_neighbours", 0, MAX_AGENTS)
    if g.learner.symmetry != "none" and g.sensors.rays % 4:
        raise ConfigError(f"general.learner.symmetry {g.learner.symmetry}: the compass's turns permute the shore "
                          "rays only when their number is a multiple of 4, got general.sensors.rays = "
                          f"{g.sensors.rays}")
    su = g.suite
    for n in (*su.named_fleets, *su.lake_fleets):
        within(n, "general.suite fleets", 2, MAX_AGENTS)
    for start in su.starts:
        if start not in ("corner", "random"):
            raise ConfigError(f"general.suite.starts: 'corner' or 'random', got {start!r}")
    if "none" not in su.events or not set(su.events) <= set(EVENTS) or len(set(su.events)) < len(su.events):
        raise ConfigError(f"general.suite.events: 'none' (still water, which the events are read against) and any "
                          f"of {list(EVENTS[1:])}, each once, got {list(su.events)}")
    within(su.lose_fraction, "general.suite.lose_fraction", 0, 0.5, open_lo=True)  # a fleet keeps most of itself
    within(su.current, "general.suite.current", 0)
    within(su.episodes, "general.suite.episodes", 1)
    within(su.held_out, "general.suite.held_out", 0)


def check_design(d: DesignConfig) -> None:
    """The design yardstick's values in their ranges."""
    within(d.lakes, "design.lakes", 1)
    for name, values in (("fleets", d.fleets), ("starts", d.starts)):
        if not values or len(set(values)) < len(values):
            raise ConfigError(f"design.{name}: at least one, each once, got {list(values)}")
    for n in d.fleets:
        within(n, "design.fleets", 2, MAX_AGENTS)
    for start in d.starts:
        if start not in ("corner", "random"):
            raise ConfigError(f"design.starts: 'corner' or 'random', got {start!r}")
    if not d.events or not set(d.events) <= set(EVENTS) or len(set(d.events)) < len(d.events):
        raise ConfigError(f"design.events: any of {list(EVENTS)}, each once, got {list(d.events)}")
    within(d.episodes, "design.episodes", 1)
    check_seed(d.seed, "design.seed")
    within(d.min_seeds, "design.min_seeds", 2)
    within(d.min_gain, "design.min_gain", -1, 1)
    for seed in d.seeds:
        check_seed(seed, "design.seeds")
    if len(set(d.seeds)) < len(d.seeds) or len(d.seeds) < d.min_seeds:
        raise ConfigError(f"design.seeds: at least design.min_seeds ({d.min_seeds}) seeds, each once, got "
                          f"{list(d.seeds)}")


def check_seed(seed: int, where: str = "--seed") -> int:
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{where} must be a whole number from 0 to {MAX_SEED}, got {seed!r}")
    return seed


@dataclass(frozen=True)
class WorldConfig:
    n_agents: int
    agent_radius: float
    sensitivity: float
    mass: float
    dt: float
    damping: float
    episode_length: int
    start_patch: float
    region_area: float


@dataclass(frozen=True)
class CoverageConfig:
    radius: float
    edges: int
    table_spacing: float
    raster_spacing: float


@dataclass(frozen=True)
class SWRewardConfig:
    r1: float
    r2: float
    alpha: float
    beta: float
    prop_range: tuple[float, float]
    coll_range: tuple[float, float]


@dataclass(frozen=True)
class CRRewardConfig:
    r1: float
    r2: float
    r3: float
    c1: float
    c2: float


@dataclass(frozen=True)
class MethodConfig:
    reward: Literal["sw", "cr"]
    reward_mode: Literal["shared", "individual"]


@dataclass(frozen=True)
class MADDPGConfig:
    hidden: int
    actor_lr: float
    critic_lr: float
    gamma: float
    tau: float
    batch_size: int
    buffer_size: int
    learning_starts: int
    update_every: int
    grad_clip: float
    actor_reg: float
    noise_start: float
    noise_end: float
    noise_decay: float
    lr_end: float = 1.0  # learning rates fall linearly to this fraction of actor_lr/critic_lr by the last episode
    n_step: int = 1  # transitions hold n-step returns (1: the paper's one-step TD target)


@dataclass(frozen=True)
class SensorsConfig:
    """What a buoy senses with ``observation: local`` (``sensors.py``): its velocity, the ``neighbours`` nearest
    buoys it hears within ``comm_range`` m, the shore along ``rays`` compass directions up to ``ray_range`` m and,
    with ``uncovered``, the share of water along each ray that no buoy it hears covers."""

    neighbours: int = 4
    comm_range: float = 2.0
    rays: int = 8
    ray_range: float = 2.0
    velocity: Literal["water", "ground"] = "water"  # through the water (a log) or over the ground (GPS)
    uncovered: tuple[float, ...] = ()  # m: radii of ``uncovered_water``'s points along each ray; () = no such sensor

    def __post_init__(self) -> None:
        object.__setattr__(self, "uncovered", tuple(self.uncovered))  # from a policy's JSON metadata: a list
        if self.velocity not in ("water", "ground"):
            raise ConfigError(f"sensors velocity must be 'water' or 'ground', got {self.velocity!r}")
        if any(not 0 < r < self.ray_range for r in self.uncovered):
            raise ConfigError(f"sensors uncovered radii must lie in (0, ray_range = {self.ray_range}) m (water is "
                              f"known only short of it), got {list(self.uncovered)}")


@dataclass(frozen=True)
class AlgoConfig:
    observation: Literal["position", "position_velocity", "local"]
    geofence: float | None
    reward_scale: float
    union_credit: Literal["shared", "difference"]
    n_envs: int
    maddpg: MADDPGConfig
    # Options added after the paper runs. At their neutral default they are left out of a run's identity
    # (``to_dict(..., drop_defaults=True)``), so adding one does not invalidate finished runs.
    union_weight: float | None = None  # c2 of eq. (6) for this config; None = cr_reward.c2
    select_every: int = 0  # episodes between validation rollouts that pick the kept actors; 0 = keep the last
    select_episodes: int = 20  # validation episodes (fixed starts, deterministic policy) per selection
    # "fence": the geofence above bounds the world (None: the paper's open plane); "wall": the shoreline does,
    # no buoy ever leaves the water (``shore.wall_step``)
    shore: Literal["fence", "wall"] = "fence"
    sensors: SensorsConfig = SensorsConfig()  # read with observation "local" only
    # Values for one method only, chosen by that method's own search (``params.yaml`` ``tuning.method``):
    # method → {dotted key inside this config: value}. ``run_config`` applies them; a run's config holds none.
    per_method: dict[str, dict[str, Any]] | None = None


@dataclass(frozen=True)
class RegionSpec:
    kind: Literal["box", "file"]
    width: float | None = None
    height: float | None = None
    path: str | None = None
    episode_length: int | None = None  # T for this region (every method and baseline); None = world's


@dataclass(frozen=True)
class TrainConfig:
    episodes: int
    seeds: dict[str, tuple[int, ...]]  # config → the training seeds of its reported runs
    checkpoint_every: int

    def seeds_of(self, config: str) -> tuple[int, ...]:
        """The reported seeds of ``config``; an ablation config ``BASE-without-CHANGE`` has no seeds of its own
        (``ablation.seeds`` gives them)."""
        if config not in self.seeds:
            raise ConfigError(f"train.seeds has no seeds for config {config!r}; known: {sorted(self.seeds)}")
        return self.seeds[config]


@dataclass(frozen=True)
class RegressionConfig:
    region: str
    seed: int
    episodes: int
    n_envs: int
    learning_starts: int
    batch_size: int
    tolerance: float


@dataclass(frozen=True)
class NaiveConfig:
    attraction: float
    avoid_range: float
    avoidance: float
    damping: float


@dataclass(frozen=True)
class LloydConfig:
    gain: float
    damping: float
    converged_steps: int


@dataclass(frozen=True)
class GeodesicConfig:
    """Geodesic Lloyd (``baselines.geodesic_lloyd``): the water's raster and how far ahead a buoy aims along its
    path; its gains are Lloyd's."""

    spacing: float  # m between the water graph's points
    lookahead: float  # m of sailing to the waypoint a buoy steers toward


@dataclass(frozen=True)
class StartsConfig:
    """Where the buoys are released: ``corner`` is the paper's start patch at the region's lower-left corner,
    ``opposite`` the same patch at the upper-right corner, ``random`` uniform over the region."""

    start: Literal["corner", "opposite", "random"]
    horizon: float = 1.0  # episode length as a multiple of the region's T
    lose: int = 0  # buoys lost (removed, no longer covering) half-way through the episode


@dataclass(frozen=True)
class EvaluateConfig:
    episodes: int
    seed: int
    converge_window: int
    converge_tolerance: float
    converge_final: int
    naive: NaiveConfig
    lloyd: LloydConfig
    geodesic: GeodesicConfig
    robustness: dict[str, StartsConfig] = field(default_factory=dict)  # scenario name → its starts and events


@dataclass(frozen=True)
class Dimension:
    """One searched value: a number in [low, high] (``log``: sampled on a log scale; ``integer``: whole numbers)
    or one of ``choices``."""

    low: float | None = None
    high: float | None = None
    log: bool = False
    integer: bool = False
    choices: tuple[Any, ...] | None = None

    def __post_init__(self) -> None:
        if self.choices is None and (self.low is None or self.high is None or not self.low < self.high):
            raise ConfigError(f"a searched value needs low < high or choices, got {self}")
        if self.log and (self.low is None or self.low <= 0):
            raise ConfigError(f"a log-scale range needs low > 0, got {self}")


@dataclass(frozen=True)
class Search:
    trials: int
    space: dict[str, Dimension]  # searched key → its range


@dataclass(frozen=True)
class BaselineSearch:
    storage: str  # SQLAlchemy URL of the studies (the tune_baselines stage's SQLite file by default)
    naive: Search  # every gain of NaiveConfig
    lloyd: Search  # every gain of LloydConfig (converged_steps is not a gain)


@dataclass(frozen=True)
class MethodSearch:
    """A search of one method's training values inside a config (the study writes no config: its best values
    go into ``configs.CONFIG.per_method.METHOD`` by hand, with the study's name beside them)."""

    storage: str  # SQLAlchemy URL of the study (a committed SQLite file by default)
    result: str  # JSON of the best values, read by the report
    config: str
    method: str
    regions: tuple[str, ...]
    seeds: tuple[int, ...]  # training seeds of every trial, never reported
    episodes: int
    trials: int
    space: dict[str, Dimension]  # dotted key inside the config → its range


@dataclass(frozen=True)
class HandSearch:
    """The record of a search made by hand (``docs/TUNING.md``), for the report's budgets."""

    config: str
    method: str
    configurations: int
    runs: int
    cpu_seconds: float
    note: str


@dataclass(frozen=True)
class GeneralBaselineSearch:
    """Naive swarming's and Lloyd's gains for the general policy's comparisons: one set for every lake, tuned on
    its training worlds behind the wall (``tuning.tune_general_baselines``), in the spaces of ``baselines``."""

    storage: str  # SQLAlchemy URL of the studies
    result: str  # JSON of the best gains, which ``replicate evaluate --policy`` reads
    starts: int  # episodes per world and trial: half from the corner patch, half scattered
    naive_trials: int
    lloyd_trials: int


@dataclass(frozen=True)
class TuningConfig:
    sampler_seed: int  # the TPE sampler's seed: the same trials in the same order on every machine
    starts_seed: int  # evaluation starts of every trial (never ``evaluate.seed``)
    starts: int  # evaluation episodes per trial
    baselines: BaselineSearch
    method: MethodSearch
    hand_search: HandSearch
    general_baselines: GeneralBaselineSearch


@dataclass(frozen=True)
class Target:
    at_least: float  # coverage, or with ``of`` a fraction of that baseline's coverage
    of: Literal["lloyd_tuned"] | None = None


@dataclass(frozen=True)
class GeneralTargets:
    """The general policy's bars on the evaluation suite, as fractions of its yardsticks' coverage."""

    of_lloyd: float  # in still water, every cell at least this fraction of lloyd_tuned ...
    of_best: float  # ... and of the best layout (and above naive_tuned)
    narrow_gap: float  # a lake where lloyd_tuned falls this far short of the best layout: the policy must beat it
    lose_of_lloyd: float  # after a loss: at least this fraction of what lloyd_tuned re-covers
    current_of_still: float  # in the drift: at least this fraction of its own still-water coverage


@dataclass(frozen=True)
class ReportConfig:
    """The verdict rules, fixed before the numbers (REPORT.md prints each beside its verdict)."""

    level: float  # confidence level of every interval
    resamples: int  # bootstrap resamples
    seed: int  # the bootstrap's generator
    margin: float  # coverage: "A beats B" when the CI of mean(A) − mean(B) lies above this
    spread_margin: float  # metres: "CR spreads more" when the CI of Δ nearest-neighbour lies above this
    about_episodes: int  # "about 5,000 episodes": within this many episodes of 5,000
    not_converged_after: int  # "not converged by 10,000": no convergence episode, or one after this
    majority: float  # claim 1 holds for a method when at least this fraction of its seeds meets it
    partly: float  # a claim over several cells: every cell holds → reproduced; at least this fraction → partly
    acceptable: float  # "acceptable coverage": the CI's lower bound at or above this fraction of the ceiling
    sensitivity: tuple[float, ...]  # factors applied to the margins and tolerances for the sensitivity column
    targets: dict[str, Target]  # region → tuned CR-MARL's coverage bar, on every seed
    target_seconds: float  # one core's seconds per 10,000-episode run
    general: GeneralTargets


@dataclass(frozen=True)
class AblationConfig:
    """Leave-one-out ablation of ``base``: for each change, a config equal to ``base`` except that the change's
    keys (dotted, inside a config) take ``reference``'s values. Named ``{base}-without-{change}``."""

    base: str
    reference: str
    method: str
    regions: tuple[str, ...]
    seeds: tuple[int, ...]
    changes: dict[str, tuple[str, ...]]


Symmetry = Literal["none", "d4"]  # of the general actor (``symmetry``): none, or the compass's turns and mirrors


@dataclass(frozen=True)
class SharedLearnerConfig:
    """The networks and optimisers of ``shared_maddpg.SharedMADDPG``."""

    hidden: int = 64
    embed: int = 64  # width of φ, the embedding of one other buoy that the critic pools
    actor_lr: float = 1e-3
    critic_lr: float = 1e-3
    tau: float = 0.01
    grad_clip: float = 0.5
    actor_reg: float = 1e-3  # on the pre-tanh action, as openai/maddpg
    pool_range: float = 0.0  # m: the critic pools only the others this close (0: every other buoy of the fleet)
    pool_neighbours: int = 0  # the critic pools only each buoy's K nearest others (0: all of them)
    symmetry: Symmetry = "none"  # "d4": the actor averaged over the compass's quarter turns and mirrors


EVENTS = ("none", "lose", "current")  # the suite's events: still water, a share of the fleet lost at T/2, a drift


@dataclass(frozen=True)
class SuiteConfig:
    """The general policy's evaluation suite (``pipeline.general``): lakes × fleets × starts × events."""

    held_out: int  # generated lakes of ``lakes.held_out``, never trained on
    named_fleets: tuple[int, ...]  # N on the square, the rectangle and Bedok (each at the paper's density)
    lake_fleets: tuple[int, ...]  # N on every held-out lake (each at its own density)
    starts: tuple[str, ...]
    events: tuple[str, ...]  # of ``EVENTS``, on every lake and fleet
    lose_fraction: float  # the "lose" event: this share of the fleet lost at T/2
    current: float  # the "current" event: a uniform drift of this speed, m/s
    episodes: int  # per cell


@dataclass(frozen=True)
class DesignConfig:
    """The design yardstick (``design.py``): where two versions of the general training are compared before one
    is kept, on lakes of a seed stream of their own (``lakes.design``: never trained on, never reported), with
    the training seed as the unit."""

    lakes: int  # generated lakes of ``lakes.design``, each at its own density
    fleets: tuple[int, ...]  # N on every lake
    starts: tuple[str, ...]
    events: tuple[str, ...]  # of ``EVENTS``, sized as the suite's (``general.suite.lose_fraction``, ``current``)
    episodes: int  # per cell
    seed: int  # the evaluation starts: not ``evaluate.seed``, whose starts are reported
    min_seeds: int  # training seeds a version needs: fewer make the interval over seeds too narrow
    min_gain: float  # the candidate is kept when the interval of its gain over the baseline lies above this
    seeds: tuple[int, ...]  # the standing baseline's training seeds (``train_design``): never reported


@dataclass(frozen=True)
class GeneralConfig:
    """One policy for every lake (``general_train``): the worlds it trains on, the events, the schedule."""

    regions: tuple[str, ...]  # named regions of ``regions`` trained on, with ``fleet`` buoys each
    fleet: tuple[int, ...]  # N of a named region's world, one drawn per world
    lakes: int  # generated training lakes (``lakes.training``: the same for every seed)
    lake_fleet: tuple[int, int]  # N range of a generated lake
    lake_ratio: tuple[float, float]  # N·A(Cov)/A(Reg) range of a generated lake
    random_starts: float  # share of batches released scattered over the water (the rest in the corner patch)
    lose_prob: float  # share of batches that lose buoys at T/2 ...
    lose_fraction: float  # ... up to this share of the fleet
    current_prob: float  # share of batches in moving water ...
    current_speed: float  # ... up to this drift speed, m/s (top speed is 2)
    n_envs: int
    episodes: int
    episode_length: int
    reward_scale: float
    union_weight: float  # c2 of eq. (6), with the difference credit
    cover_weight: float  # c1 of eq. (6): the weight of eq. (5)'s per-buoy terms (0: the difference credit alone)
    shore_penalty: float  # subtracted (after reward_scale) per step from a buoy resting on the shore
    gamma: float
    n_step: int  # n-step TD targets (1: MADDPG's one-step target)
    lr_end: float  # both learning rates fall linearly to lr_end x their start over training (1.0: constant)
    batch_size: int
    buffer_size: int
    learning_starts: int  # transitions
    update_every: int  # transitions (summed over the environments) per update
    noise_start: float
    noise_end: float
    noise_decay: float  # share of training over which σ falls from start to end
    seeds: tuple[int, ...]
    sensors: SensorsConfig
    learner: SharedLearnerConfig
    suite: SuiteConfig


@dataclass(frozen=True)
class Params:
    """Everything in ``params.yaml``. Stage-specific sections the package does not read are kept as mappings."""

    world: WorldConfig
    coverage: CoverageConfig
    sw_reward: SWRewardConfig
    cr_reward: CRRewardConfig
    methods: dict[str, MethodConfig]
    configs: dict[str, AlgoConfig]
    regions: dict[str, RegionSpec]
    train: TrainConfig
    regression: RegressionConfig
    evaluate: EvaluateConfig
    ablation: AblationConfig
    tuning: TuningConfig
    report: ReportConfig
    general: GeneralConfig
    design: DesignConfig
    stages: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        w, c = self.world, self.coverage
        for where, value in (("world.agent_radius", w.agent_radius), ("world.sensitivity", w.sensitivity),
                             ("world.mass", w.mass), ("world.dt", w.dt), ("world.start_patch", w.start_patch),
                             ("world.region_area", w.region_area), ("coverage.radius", c.radius),
                             ("coverage.table_spacing", c.table_spacing),
                             ("coverage.raster_spacing", c.raster_spacing)):
            positive(value, where)
        if not 1 <= w.n_agents <= MAX_AGENTS:
            raise ConfigError(f"world.n_agents must be between 1 and {MAX_AGENTS}, got {w.n_agents}")
        if c.edges < 3:
            raise ConfigError(f"coverage.edges: a coverage polygon needs at least 3 edges, got {c.edges}")
        if not 0 <= w.damping < 1:
            raise ConfigError(f"world.damping must be in [0, 1), got {w.damping}")
        if w.episode_length < 1:
            raise ConfigError(f"world.episode_length must be at least 1, got {w.episode_length}")
        ab = self.ablation
        for name in (ab.base, ab.reference):
            if name not in self.configs:
                raise ConfigError(f"ablation: unknown config {name!r}; known: {sorted(self.configs)}")
        if ab.method not in self.methods:
            raise ConfigError(f"ablation.method: unknown method {ab.method!r}")
        unknown = sorted(set(ab.regions) - set(self.regions))
        if unknown:
            raise ConfigError(f"ablation.regions: unknown region(s) {unknown}")
        for change in ab.changes:
            ablation_config(self, change)  # every key must exist
        for name in self.pipeline_configs():
            if name not in self.train.seeds:
                raise ConfigError(f"train.seeds: no seeds for config {name!r}")
        for name, algo in self.configs.items():
            check_algo(algo, f"configs.{name}")
        for name, algo in self.configs.items():
            for method in algo.per_method or {}:  # every key must exist, type-check and lie in its range
                check_algo(method_config(self, name, method), f"configs.{name}.per_method.{method}")
        for key in ("table_spacing", "raster_spacing"):  # a cell wider than the coverage polygon resolves nothing
            within(getattr(c, key), f"coverage.{key}", 0, c.radius / 2, open_lo=True)
        within(self.evaluate.episodes, "evaluate.episodes", 1)
        within(self.evaluate.geodesic.spacing, "evaluate.geodesic.spacing", 0, c.radius, open_lo=True)
        within(self.evaluate.geodesic.lookahead, "evaluate.geodesic.lookahead", 0, open_lo=True)
        gb = self.tuning.general_baselines
        for key in ("starts", "naive_trials", "lloyd_trials"):
            within(getattr(gb, key), f"tuning.general_baselines.{key}", 1)
        for name, spec in self.regions.items():
            if spec.episode_length is not None and spec.episode_length < 1:
                raise ConfigError(f"regions.{name}.episode_length must be at least 1, got {spec.episode_length}")

        check_general(self.general, self.regions)
        check_design(self.design)
        reported = sorted(set(self.design.seeds) & set(self.general.seeds))
        if reported:
            raise ConfigError(f"design.seeds: {reported} also in general.seeds; the standing baseline's seeds are "
                              "never the reported ones, choose others")

    def pipeline_configs(self) -> list[str]:
        return list(self.stages.get("pipeline", {}).get("configs", []))

    def all_configs(self) -> dict[str, AlgoConfig]:
        """The written configs plus one derived config per ablation change."""
        derived = {ablated_name(self.ablation.base, c): ablation_config(self, c) for c in self.ablation.changes}
        return {**self.configs, **derived}


SELECTION_KEYS = ("select_every", "select_episodes")


def selection_only(params: Params, change: str) -> bool:
    """A change that only picks which actors are kept: its "without" run is the base run itself (training is
    identical), evaluated with its last actors instead of the selected ones."""
    return set(params.ablation.changes[change]) <= set(SELECTION_KEYS)


def ablated_name(base: str, change: str) -> str:
    """The name of ``base`` without ``change``: the config of one leave-one-out ablation run."""
    return f"{base}-without-{change}"


def ablation_config(params: Params, change: str) -> AlgoConfig:
    """``ablation.base`` with the keys of ``change`` set to their values in ``ablation.reference``."""
    ab = params.ablation
    if change not in ab.changes:
        raise ConfigError(f"unknown ablation change {change!r}; known: {sorted(ab.changes)}")
    base = to_dict(params.configs[ab.base])
    ref = to_dict(params.configs[ab.reference])
    for dotted in ab.changes[change]:
        node, key = dotted_parent(base, dotted, f"ablation.changes.{change}")
        src, _ = dotted_parent(ref, dotted, f"ablation.changes.{change}")
        node[key] = src[key]
    return from_mapping(AlgoConfig, base, f"ablation {change}")


def dotted_parent(tree: dict, dotted: str, where: str) -> tuple[dict, str]:
    """The mapping that holds the existing key ``a.b.c`` of a nested mapping, and its last part ``c``."""
    *sections, key = dotted.split(".")
    node = tree
    for k in sections:
        if not isinstance(node.get(k), dict):
            raise ConfigError(f"{where}: no section {k!r} in {dotted!r}")
        node = node[k]
    if key not in node:
        raise ConfigError(f"{where}: unknown key {key!r} in {dotted!r}")
    return node, key


# Top-level sections that belong to pipeline stages (dvc.yaml) and are validated there.
STAGE_SECTIONS = ("fetch_outline", "project_utm", "pipeline", "figures")


@dataclass(frozen=True, order=True)
class Cell:
    """One cell of the training matrix: a config trained with a method on a region (over its seeds). Its
    ``key`` names it in ``metrics/summary.json``."""

    config: str
    method: str
    region: str

    @property
    def key(self) -> str:
        return f"{self.config}/{self.method}/{self.region}"

    @classmethod
    def parse(cls, key: str) -> Cell:
        config, method, region = key.split("/")
        return cls(config, method, region)


@dataclass(frozen=True)
class RunConfig:
    """What one training run needs: the shared world plus one config x method."""

    world: WorldConfig
    coverage: CoverageConfig
    sw_reward: SWRewardConfig
    cr_reward: CRRewardConfig
    method: MethodConfig
    algo: AlgoConfig
    config_name: str
    method_name: str


def _check(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        return from_mapping(tp, value, where)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _check(inner[0], value, where)
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{where}: {value!r} is not one of {list(args)}")
        return value
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return {str(k): _check(args[1], v, f"{where}.{k}") for k, v in value.items()}
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected {len(args)} items, got {len(value)}")
        return tuple(_check(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported annotation {tp!r} at {where}")  # pragma: no cover - programming error


def from_mapping(cls: type, data: Any, where: str = "params") -> Any:
    """Build dataclass ``cls`` from ``data``, refusing unknown, missing and mistyped keys."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(fields)}")
    kwargs = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING:
                continue
            raise ConfigError(f"{where}: missing key {name!r}")
        kwargs[name] = _check(hints[name], data[name], f"{where}.{name}")
    return cls(**kwargs)


def load_params(path: str | Path = DEFAULT_PARAMS, overrides: Mapping[str, Any] | None = None) -> Params:
    """Read and validate ``params.yaml``; ``overrides`` maps dotted keys to values (``train.episodes``). The
    default ``params.yaml`` is the one in the working folder, else the one installed with the package."""
    path = Path(path)
    if path == DEFAULT_PARAMS and not path.exists():
        path = packaged("params.yaml")
    if not path.exists():
        raise ConfigError(f"{path}: no such parameters file; `replicate init DIR` writes an editable copy of the "
                          "defaults")
    try:
        with open(path) as fh:
            raw = yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ConfigError(f"{path}: not valid YAML{at} ({getattr(exc, 'problem', exc)}); fix the file, or start "
                          "from the repository's params.yaml") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the parameters file ({exc})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    for dotted, value in (overrides or {}).items():
        node, key = dotted_parent(raw, dotted, f"override {dotted!r}")
        node[key] = value
    stages = {k: raw.pop(k) for k in STAGE_SECTIONS if k in raw}
    try:
        params = from_mapping(Params, raw, str(path))
    except ConfigError as exc:
        culprit = next((f"--set {k}={v}" for k, v in (overrides or {}).items() if k in str(exc)), None)
        if culprit is None:
            raise
        raise ConfigError(f"{culprit}: {str(exc).replace(str(path) + '.', '')}") from None
    return dataclasses.replace(params, stages=stages)


def region_world(params: Params, region: str | None) -> WorldConfig:
    """The world on ``region``: ``params.world`` with the region's own ``episode_length``, if it sets one (a
    name that is not in ``params.regions``, or None, keeps the world's)."""
    spec = params.regions.get(region) if region is not None else None
    if spec is None or spec.episode_length is None:
        return params.world
    return dataclasses.replace(params.world, episode_length=spec.episode_length)


def with_values(algo: AlgoConfig, values: Mapping[str, Any], where: str) -> AlgoConfig:
    """``algo`` with the dotted keys of ``values`` (``maddpg.gamma``) set, type-checked; without ``per_method``."""
    tree = to_dict(algo)
    tree.pop("per_method", None)
    for dotted, value in values.items():
        node, key = dotted_parent(tree, dotted, where)
        node[key] = value
    return from_mapping(AlgoConfig, tree, where)


def method_config(params: Params, config: str, method: str) -> AlgoConfig:
    """Config ``config`` as method ``method`` trains it: its values with the method's own (``per_method``)."""
    configs = params.all_configs()
    if config not in configs:
        raise ConfigError(f"unknown config {config!r}; known: {sorted(configs)}")
    if method not in params.methods:
        raise ConfigError(f"unknown method {method!r}; known: {sorted(params.methods)}")
    algo = configs[config]
    own = (algo.per_method or {}).get(method)
    if not own and algo.per_method is None:
        return algo
    return with_values(algo, own or {}, f"configs.{config}.per_method.{method}")


def run_config(params: Params, config: str, method: str, region: str | None = None) -> RunConfig:
    """Select one configuration (``paper``/``tuned``/an ablation of it) and method (``sw``/``cr``), on
    ``region`` (its world from ``region_world``)."""
    algo = method_config(params, config, method)
    return RunConfig(
        world=region_world(params, region),
        coverage=params.coverage,
        sw_reward=params.sw_reward,
        cr_reward=params.cr_reward,
        method=params.methods[method],
        algo=algo,
        config_name=config,
        method_name=method,
    )


def to_dict(obj: Any, drop_defaults: bool = False) -> Any:
    """A dataclass as plain JSON/YAML-friendly data (tuples become lists). ``drop_defaults`` leaves out fields
    that have a default and hold it: the form used for run identities."""
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if drop_defaults and f.default is not dataclasses.MISSING and value == f.default:
                continue
            out[f.name] = to_dict(value, drop_defaults)
        return out
    if isinstance(obj, dict):
        return {k: to_dict(v, drop_defaults) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v, drop_defaults) for v in obj]
    return obj
