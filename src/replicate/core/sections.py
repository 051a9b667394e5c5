"""The sections of ``params.yaml`` that make the world and the training: the world and its coverage, the rewards,
the methods and training configs, the regions, the training schedule, and the general policy (its worlds, sensors,
learner, evaluation suite) with the yardstick's lakes.

Each value's type and range stand beside it (``schema``); a rule that ties two values together is the section's
``check``. YAML holds the values, these sections the types (BenchMARL style).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

from pydantic import model_validator

from replicate.core.schema import (
    MAX_AGENTS,
    ConfigError,
    Count,
    Fleet,
    In,
    Int,
    NonNegative,
    Num,
    Positive,
    Seed,
    Share,
    Text,
    Whole,
    section,
)

# the suite's events: still water, a share of the fleet lost at T/2, a uniform drift, a vortex over the lake
EVENTS = ("none", "lose", "current", "vortex")
DRIFTS = ("current", "vortex")  # the events of moving water
START_KINDS = ("corner", "random")  # where the suite and the yardstick release a fleet


@section
class WorldConfig:
    n_agents: Annotated[Int, In(1, MAX_AGENTS)]
    agent_radius: Positive
    sensitivity: Positive
    mass: Positive
    dt: Positive
    damping: Annotated[Num, In(0, 1, open_hi=True)]
    episode_length: Count
    start_patch: Positive
    region_area: Positive


@section
class CoverageConfig:
    radius: Positive
    edges: Annotated[Int, In(3)]  # a coverage polygon needs at least 3 edges
    table_spacing: Positive  # a cell wider than half the coverage polygon resolves nothing ...
    raster_spacing: Positive  # ... (checked against radius below)

    @model_validator(mode="after")
    def check(self):
        for key in ("table_spacing", "raster_spacing"):
            if getattr(self, key) > self.radius / 2:
                raise ConfigError(f"coverage.{key} must be in (0, {self.radius / 2:g}], got {getattr(self, key)}")
        return self


@section
class SWRewardConfig:
    r1: Num
    r2: Num
    alpha: Num
    beta: Num
    prop_range: tuple[Num, Num]
    coll_range: tuple[Num, Num]


@section
class CRRewardConfig:
    r1: Num
    r2: Num
    r3: Num
    c1: Num
    c2: Num


@section
class MethodConfig:
    reward: Literal["sw", "cr"]
    reward_mode: Literal["shared", "individual"]


@section
class MADDPGConfig:
    hidden: Count
    actor_lr: Positive
    critic_lr: Positive
    gamma: Annotated[Num, In(0, 1, open_lo=True)]
    tau: Annotated[Num, In(0, 1, open_lo=True)]
    batch_size: Count
    buffer_size: Count
    learning_starts: Whole
    update_every: Annotated[Int, In(0, open_lo=True)]
    grad_clip: Positive
    actor_reg: NonNegative
    noise_start: NonNegative
    noise_end: NonNegative
    noise_decay: Share
    lr_end: NonNegative = 1.0  # learning rates fall linearly to this fraction of actor_lr/critic_lr by the last episode
    n_step: Count = 1  # transitions hold n-step returns (1: the paper's one-step TD target)


@section
class SensorsConfig:
    """What a buoy senses with ``observation: local`` (``sensors.py``): its velocity, the ``neighbours`` nearest
    buoys it hears within ``comm_range`` m, the shore along ``rays`` compass directions up to ``ray_range`` m and,
    with ``uncovered``, the share of water along each ray that no buoy it hears covers and, with ``raster``, a small
    map of the water and of what the buoys it hears cover on ``raster`` × ``raster`` cells around it."""

    neighbours: Annotated[Int, In(1, MAX_AGENTS)] = 4
    comm_range: Positive = 2.0
    rays: Annotated[Int, In(1, 360)] = 8
    ray_range: Positive = 2.0
    velocity: Literal["water", "ground"] = "water"  # through the water (a log) or over the ground (GPS)
    uncovered: tuple[Num, ...] = ()  # m: radii of ``uncovered_water``'s points along each ray; () = no such sensor
    raster: Annotated[Int, In(0, 31)] = 0  # cells a side of ``local_raster``'s square of half-side ray_range; 0 = none
    centroid: bool = False  # ``local_map.LocalCentroid``: the offset to the centroid of the water within ray_range
    # nearer to the buoy than to the ``neighbours`` it hears (its cell of decentralised Lloyd, memoryless)
    # Values added after general runs were trained: at their default they are left out of a run's identity
    # (``runs.general_identity``), so adding one keeps the finished runs valid.
    OPTIONAL: ClassVar[tuple[str, ...]] = ("uncovered", "raster", "centroid")

    @model_validator(mode="after")
    def check(self):
        if any(not 0 < r < self.ray_range for r in self.uncovered):
            raise ConfigError(f"sensors uncovered radii must lie in (0, ray_range = {self.ray_range}) m (water is "
                              f"known only short of it), got {list(self.uncovered)}")
        if self.raster and (self.raster < 3 or self.raster % 2 == 0):
            raise ConfigError(f"sensors raster: an odd number of cells a side, at least 3 (the buoy at the centre "
                              f"cell's centre), or 0 for none; got {self.raster}")
        return self


@section
class AlgoConfig:
    observation: Literal["position", "position_velocity", "local"]
    geofence: NonNegative | None
    reward_scale: Positive
    union_credit: Literal["shared", "difference"]
    n_envs: Count
    maddpg: MADDPGConfig
    # Options added after the paper runs. At their neutral default they are left out of a run's identity
    # (``to_dict(..., drop_defaults=True)``), so adding one does not invalidate finished runs.
    union_weight: NonNegative | None = None  # c2 of eq. (6) for this config; None = cr_reward.c2
    select_every: Whole = 0  # episodes between validation rollouts that pick the kept actors; 0 = keep the last
    select_episodes: Count = 20  # validation episodes (fixed starts, deterministic policy) per selection
    # "fence": the geofence above bounds the world (None: the paper's open plane); "wall": the shoreline does,
    # no buoy ever leaves the water (``shore.wall_step``)
    shore: Literal["fence", "wall"] = "fence"
    sensors: SensorsConfig = SensorsConfig()  # read with observation "local" only
    # Values for one method only, chosen by that method's own search (``params.yaml`` ``tuning.method``):
    # method → {dotted key inside this config: value}. ``run_config`` applies them; a run's config holds none.
    per_method: dict[str, dict[str, Any]] | None = None


@section
class RegionSpec:
    kind: Literal["box", "file"]
    width: Num | None = None
    height: Num | None = None
    path: Text | None = None
    episode_length: Count | None = None  # T for this region (every method and baseline); None = world's


@section
class TrainConfig:
    episodes: Count
    seeds: dict[str, tuple[Seed, ...]]  # config → the training seeds of its reported runs
    checkpoint_every: Count

    def seeds_of(self, config: str) -> tuple[int, ...]:
        """The reported seeds of ``config``; an ablation config ``BASE-without-CHANGE`` has no seeds of its own
        (``ablation.seeds`` gives them)."""
        if config not in self.seeds:
            raise ConfigError(f"train.seeds has no seeds for config {config!r}; known: {sorted(self.seeds)}")
        return self.seeds[config]


@section
class RegressionConfig:
    region: Text
    seed: Seed
    episodes: Count
    n_envs: Count
    learning_starts: Whole
    batch_size: Count
    tolerance: NonNegative


# of the general actor (``symmetry``): none, the compass's turns and mirrors averaged over (d4), or each observation
# turned into one canonical frame of them (d4_frame: the network runs once instead of 8 times)
Symmetry = Literal["none", "d4", "d4_frame"]


IMITATION_UNTIL = 0.25  # the default share of imitation before the actor-critic, and the value no other mode reads


@section
class SharedLearnerConfig:
    """The networks and optimisers of ``shared_maddpg.SharedMADDPG``."""

    hidden: Count = 64
    layers: Annotated[Int, In(1, 4)] = 2  # hidden layers of the actor's MLP and of the critic's Q head (MADDPG's 2)
    embed: Count = 64  # width of φ, the embedding of one other buoy that the critic pools
    actor_lr: Positive = 1e-3
    critic_lr: Positive = 1e-3
    tau: Annotated[Num, In(0, 1, open_lo=True)] = 0.01
    grad_clip: Positive = 0.5
    actor_reg: NonNegative = 1e-3  # on the pre-tanh action, as openai/maddpg
    pool_range: NonNegative = 0.0  # m: the critic pools only the others this close (0: every other buoy of the fleet)
    pool_neighbours: Annotated[Int, In(0, MAX_AGENTS)] = 0  # the critic pools each buoy's K nearest (0: all)
    symmetry: Symmetry = "none"  # "d4": the actor averaged over the compass's quarter turns and mirrors; "d4_frame":
    # run once in each observation's canonical frame of them
    imitation: Literal["none", "beside", "alone", "before"] = "none"  # the clairvoyant planner as a teacher: its
    # action for every buoy at every state the learner visits (DAgger's labels), imitated beside the actor-critic
    # loss, alone, or alone before the actor-critic takes over (``imitation_until``)
    imitation_weight: NonNegative = 1.0  # the weight of the imitation loss, mean squared action error per buoy
    imitation_until: Annotated[Num, In(0, 1, open_lo=True, open_hi=True)] = IMITATION_UNTIL  # "before": the share
    # of the training's batches (rounded up) in which the actor imitates alone; the actor-critic alone after it, and the
    # teacher labels no more
    hops: Annotated[Int, In(0, 3)] = 0  # rounds of messages between the buoys that hear each other
    # (``learn.messages``); 0: the actor reads its own sensors only
    average: Annotated[Num, In(0, 1, open_hi=True)] = 0.0  # the validated and deployed actor: a running average of
    # the trained actor's weights, θ̄ ← θ̄ + average·(θ − θ̄) at every update (Polyak averaging); 0: the trained actor
    lloyd_prior: NonNegative = 0.0  # per simulation metre: the actor's pre-tanh action is the network's plus this
    # gain × the offset to the buoy's local centroid (``sensors.centroid``): Lloyd's law as the prior the network
    # corrects (residual policy learning); 0: the network alone
    lloyd_prior_fade: Annotated[Num, In(0, 1, open_hi=True)] = 0.0  # the share of the training's batches over
    # which the prior's gain falls linearly to 0: the actor validated, kept and deployed is then the network alone,
    # the prior a guide of the early exploration; 0: the gain stays
    # left out of a run's identity at their default
    OPTIONAL: ClassVar[tuple[str, ...]] = ("layers", "symmetry", "imitation", "imitation_weight",
                                           "imitation_until", "hops", "average", "lloyd_prior", "lloyd_prior_fade")

    @property
    def deployed_prior(self) -> float:
        """The Lloyd prior's gain in the actor a training keeps: ``lloyd_prior``, or 0 where it fades."""
        return 0.0 if self.lloyd_prior_fade else self.lloyd_prior

    @model_validator(mode="after")
    def check(self):
        if self.hops and self.symmetry == "d4":
            raise ConfigError("general.learner: hops (messages) run in each buoy's own compass frame: set symmetry "
                              "to d4_frame (or none), not d4")
        if self.hops and self.lloyd_prior:
            raise ConfigError("general.learner: lloyd_prior is added to the MLP actor's action; hops (messages) have a "
                              "network of their own (``learn.messages``): set one of them to 0")
        if self.hops and self.layers != 2:
            raise ConfigError("general.learner: hops (messages) have a network of their own (``learn.messages``); "
                              f"layers ({self.layers}) is the MLP actor's: set layers to 2 or hops to 0")
        if self.lloyd_prior_fade and not self.lloyd_prior:
            raise ConfigError(f"general.learner.lloyd_prior_fade ({self.lloyd_prior_fade}) fades the Lloyd prior, "
                              "and lloyd_prior is 0: set lloyd_prior above 0 or lloyd_prior_fade to 0")
        if self.imitation != "before" and self.imitation_until != IMITATION_UNTIL:
            raise ConfigError(f"general.learner.imitation_until ({self.imitation_until}) is read by imitation "
                              f"'before' only, and imitation is {self.imitation!r}: set one or leave it at "
                              f"{IMITATION_UNTIL}")
        return self


def check_starts(starts: tuple[str, ...], where: str) -> None:
    if bad := [s for s in starts if s not in START_KINDS]:
        raise ConfigError(f"{where}: 'corner' or 'random', got {bad[0]!r}")


@section
class SuiteConfig:
    """The general policy's evaluation suite (``compare.suite``): lakes × fleets × starts × events."""

    test_lakes: Whole  # generated lakes of ``lakes.test_stream``: a seed stream no choice has read
    real_lakes: tuple[Text, ...]  # lake files (vector, any CRS), each at the paper's density for 9 buoys
    named_fleets: tuple[Fleet, ...]  # N on the square, the rectangle and Bedok (each at the paper's density)
    lake_fleets: tuple[Fleet, ...]  # N on every other lake (a test lake at its own density, a real one at 9's)
    starts: tuple[Text, ...]  # of ``START_KINDS``
    events: tuple[Text, ...]  # of ``EVENTS``, on every lake and fleet
    lose_fraction: Annotated[Num, In(0, 0.5, open_lo=True)]  # "lose": this share lost at T/2 (most of a fleet stays)
    current: NonNegative  # the "current" event: a uniform drift of this speed, m/s; "vortex": its peak speed
    episodes: Count  # per cell

    @model_validator(mode="after")
    def check(self):
        check_starts(self.starts, "general.suite.starts")
        ev = self.events
        if "none" not in ev or not set(ev) <= set(EVENTS) or len(set(ev)) < len(ev):
            raise ConfigError(f"general.suite.events: 'none' (still water, which the events are read against) and "
                              f"any of {list(EVENTS[1:])}, each once, got {list(ev)}")
        return self


@section
class YardstickConfig:
    """The yardstick (``compare.yardstick``): where two versions of the general training are compared before
    one is kept, on lakes of a seed stream of their own (``lakes.yardstick``: never trained on, never reported), with
    the training seed as the unit."""

    lakes: Count  # generated lakes of ``lakes.yardstick``, each at its own density
    fleets: tuple[Fleet, ...]  # N on every lake
    starts: tuple[Text, ...]  # of ``START_KINDS``
    events: tuple[Text, ...]  # of ``EVENTS``, sized as the suite's (``general.suite.lose_fraction``, ``current``)
    episodes: Count  # per cell
    seed: Seed  # the evaluation starts: not ``evaluate.seed``, whose starts are reported
    min_seeds: Annotated[Int, In(2)]  # training seeds a version needs: fewer make the interval over seeds too narrow
    min_gain: Annotated[Num, In(-1, 1)]  # the candidate is kept when the interval of its gain lies above this
    seeds: tuple[Seed, ...]  # the standing baseline's training seeds (``train_yardstick``): never reported

    @model_validator(mode="after")
    def check(self):
        for name, values in (("fleets", self.fleets), ("starts", self.starts)):
            if not values or len(set(values)) < len(values):
                raise ConfigError(f"yardstick.{name}: at least one, each once, got {list(values)}")
        check_starts(self.starts, "yardstick.starts")
        if not self.events or not set(self.events) <= set(EVENTS) or len(set(self.events)) < len(self.events):
            raise ConfigError(f"yardstick.events: any of {list(EVENTS)}, each once, got {list(self.events)}")
        if len(set(self.seeds)) < len(self.seeds) or len(self.seeds) < self.min_seeds:
            raise ConfigError(f"yardstick.seeds: at least yardstick.min_seeds ({self.min_seeds}) seeds, each once, got "
                              f"{list(self.seeds)}")
        return self


@section
class GeneralConfig:
    """One policy for every lake (``general_train``): the worlds it trains on, the events, the schedule."""

    regions: tuple[Text, ...]  # named regions of ``regions`` trained on, with ``fleet`` buoys each
    fleet: tuple[Fleet, ...]  # N of a named region's world, one drawn per world
    lakes: Whole  # generated training lakes (``lakes.training``: the same for every seed)
    lake_fleet: tuple[Fleet, Fleet]  # N range of a generated lake
    lake_ratio: tuple[Positive, Positive]  # N·A(Cov)/A(Reg) range of a generated lake
    random_starts: Share  # share of batches released scattered over the water (the rest in the corner patch)
    lose_prob: Share  # share of batches that lose buoys at T/2 ...
    lose_fraction: Share  # ... up to this share of the fleet
    current_prob: Share  # share of batches in moving water ...
    current_speed: NonNegative  # ... up to this drift speed, m/s (top speed is 2)
    n_envs: Count
    episodes: Count
    episode_length: Count
    reward_scale: Positive
    union_weight: Num  # c2 of eq. (6), with the difference credit
    cover_weight: NonNegative  # c1 of eq. (6): the weight of eq. (5)'s per-buoy terms (0: the difference credit alone)
    shore_penalty: NonNegative  # subtracted (after reward_scale) per step from a buoy resting on the shore
    gamma: Annotated[Num, In(0, 1, open_lo=True)]
    n_step: Annotated[Int, In(1, 50)]  # n-step TD targets (1: MADDPG's one-step target)
    lr_end: Annotated[Num, In(0, 1, open_lo=True)]  # both learning rates fall linearly to lr_end x their start
    batch_size: Count
    buffer_size: Count
    learning_starts: Whole  # transitions
    update_every: Count  # transitions (summed over the environments) per update
    noise_start: NonNegative
    noise_end: NonNegative
    noise_decay: Share  # share of training over which σ falls from start to end
    seeds: tuple[Seed, ...]
    sensors: SensorsConfig
    learner: SharedLearnerConfig
    suite: SuiteConfig
    lloyd_shaping: NonNegative = 0.0  # weight of the pay for each step's progress of Lloyd's cost of each buoy's cell
    lloyd_move: NonNegative = 0.0  # weight of the pay for what each buoy's own move took off Lloyd's cost (1st order)
    grown_horizon: bool = False  # a training world's episodes as long as an evaluation's there (T grown with its
    # linear size, ``scenario.horizon``); False: episode_length steps in every world
    channel_fleet: Annotated[Int, In(0, MAX_AGENTS)] = 0  # N of one more world: the rectangle at the paper's density
    # (a long, crowded channel), its episodes of its evaluation's T; 0: none
    neighbour_credit: Share = 0.0  # β: each buoy paid (1 − β) its own reward + β the mean over itself and the buoys
    # it hears (within sensors.comm_range); 0: its own alone
    OPTIONAL: ClassVar[tuple[str, ...]] = ("lloyd_shaping", "lloyd_move", "grown_horizon", "channel_fleet",
                                           "neighbour_credit")  # left out of a run's identity at their default

    @model_validator(mode="after")
    def check(self):
        if self.episodes < self.n_envs:
            raise ConfigError(f"general.episodes ({self.episodes}) must be at least general.n_envs ({self.n_envs}): "
                              "one batch")
        if self.lake_fleet[0] > self.lake_fleet[1] or self.lake_ratio[0] > self.lake_ratio[1]:
            raise ConfigError(f"general.lake_fleet and lake_ratio are [low, high] ranges, got {list(self.lake_fleet)} "
                              f"and {list(self.lake_ratio)}")
        if not self.seeds:
            raise ConfigError("general.seeds: at least one seed")
        if self.channel_fleet == 1:
            raise ConfigError("general.channel_fleet: 0 (no channel world) or a fleet of at least 2 buoys, got 1")
        if self.learner.lloyd_prior and not self.sensors.centroid:
            raise ConfigError(f"general.learner.lloyd_prior ({self.learner.lloyd_prior}) steers toward the local "
                              "centroid, which the buoy senses only with general.sensors.centroid: true; set it, or "
                              "lloyd_prior to 0")
        if self.learner.symmetry != "none" and self.sensors.rays % 4:
            raise ConfigError(f"general.learner.symmetry {self.learner.symmetry}: the compass's turns permute the "
                              "shore rays only when their number is a multiple of 4, got general.sensors.rays = "
                              f"{self.sensors.rays}")
        return self
