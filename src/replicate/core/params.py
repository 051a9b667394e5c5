"""Typed, frozen parameters read from ``params.yaml``: ``load_params`` reads the file into ``Params``, one section
per top-level key (``sections``: the world and the training; ``studies``: how results are read), and refuses
an unknown, missing, mistyped or out-of-range value with a message naming its key path (``schema``).
``run_config`` selects what one training run needs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import model_validator

from replicate.core.schema import ConfigError, build, dotted_parent, section, to_dict
from replicate.core.sections import (
    AlgoConfig,
    CoverageConfig,
    CRRewardConfig,
    GeneralConfig,
    MethodConfig,
    RegionSpec,
    RegressionConfig,
    SWRewardConfig,
    TrainConfig,
    WorldConfig,
    YardstickConfig,
)
from replicate.core.studies import AblationConfig, BenchTargets, EvaluateConfig, ReportConfig, TuningConfig

DEFAULT_PARAMS = Path("params.yaml")


def packaged(name: str) -> Path:
    """A file installed with the package (``replicate/defaults/``): the repository's ``params.yaml``, the
    bundled Bedok outline and the general policy (``policies/general.pt``), so that every command works from any
    folder after ``pip install``."""
    from importlib.resources import files

    return Path(str(files("replicate") / "defaults" / name))


@section
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
    yardstick: YardstickConfig
    bench: BenchTargets
    stages: dict[str, Any] = field(default_factory=dict)

    @model_validator(mode="after")
    def check(self):
        """What ties sections together: names that must exist, the per-method and ablated configs, ranges that
        depend on another section's value, seeds that must stay apart."""
        ab = self.ablation
        for name in (ab.base, ab.reference):
            if name not in self.configs:
                raise ConfigError(f"ablation: unknown config {name!r}; known: {sorted(self.configs)}")
        if ab.method not in self.methods:
            raise ConfigError(f"ablation.method: unknown method {ab.method!r}")
        if unknown := sorted(set(ab.regions) - set(self.regions)):
            raise ConfigError(f"ablation.regions: unknown region(s) {unknown}")
        for change in ab.changes:
            ablation_config(self, change)  # every key must exist
        for name in self.pipeline_configs():
            if name not in self.train.seeds:
                raise ConfigError(f"train.seeds: no seeds for config {name!r}")
        for name, algo in self.configs.items():
            for method in algo.per_method or {}:  # every key must exist, type-check and lie in its range
                method_config(self, name, method)
        if self.evaluate.geodesic.spacing > self.coverage.radius:
            raise ConfigError(f"evaluate.geodesic.spacing must be in (0, {self.coverage.radius:g}] (the coverage "
                              f"radius), got {self.evaluate.geodesic.spacing}")
        if unknown := sorted(set(self.general.regions) - set(self.regions)):
            raise ConfigError(f"general.regions: unknown region(s) {unknown}; known: {sorted(self.regions)}")
        if self.report.goals.channel not in self.regions:
            raise ConfigError(f"report.goals.channel: unknown region {self.report.goals.channel!r}; known: "
                              f"{sorted(self.regions)}")
        if reported := sorted(set(self.yardstick.seeds) & set(self.general.seeds)):
            raise ConfigError(f"yardstick.seeds: {reported} also in general.seeds; the standing baseline's seeds are "
                              "never the reported ones, choose others")
        return self

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
    return build(AlgoConfig, base, f"ablation {change}")


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


@dataclass(frozen=True, order=True)
class RegionKey:
    """A result on one region that is not a training cell, keyed ``WHAT/REGION`` in ``metrics/summary.json`` and the
    studies: a baseline (``lloyd_tuned/bedok``), an ablation change, a tuned baseline's study."""

    what: str
    region: str

    @property
    def key(self) -> str:
        return f"{self.what}/{self.region}"

    @classmethod
    def parse(cls, key: str) -> RegionKey:
        what, region = key.split("/")
        return cls(what, region)


@section
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


def load_params(path: str | Path | None = DEFAULT_PARAMS, overrides: Mapping[str, Any] | None = None) -> Params:
    """Read and validate ``params.yaml``; ``overrides`` maps dotted keys to values (``train.episodes``). ``None``
    is the file installed with the package (the command line's default: a stray ``params.yaml`` in the working
    folder, DVC's default name, is never read unless given); the default ``params.yaml`` is the one in the working
    folder (the pipeline's), else the installed one."""
    path = packaged("params.yaml") if path is None else Path(path)
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
        params = build(Params, {**raw, "stages": stages}, str(path))
    except ConfigError as exc:
        culprit = next((f"--set {k}={v}" for k, v in (overrides or {}).items() if k in str(exc)), None)
        if culprit is None:
            raise
        raise ConfigError(f"{culprit}: {str(exc).replace(str(path) + '.', '')}") from None
    return params


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
    return build(AlgoConfig, tree, where)


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
