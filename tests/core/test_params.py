"""params.yaml against the typed config: the YAML holds values, the dataclasses types; they must match."""

from __future__ import annotations

import dataclasses

import pytest
import yaml

from replicate.core.params import STAGE_SECTIONS, Params, load_params, method_config, run_config
from replicate.core.schema import ConfigError, to_dict
from replicate.core.sections import AlgoConfig, MADDPGConfig

from ..conftest import ROOT


def test_params_yaml_matches_dataclasses(params):
    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    package_sections = {f.name for f in dataclasses.fields(Params)} - {"stages"}
    assert set(raw) - set(STAGE_SECTIONS) == package_sections
    for name in ("paper", "tuned"):
        assert set(raw["configs"][name]) == {f.name for f in dataclasses.fields(AlgoConfig)}
        assert set(raw["configs"][name]["maddpg"]) == {f.name for f in dataclasses.fields(MADDPGConfig)}
    assert params.configs["paper"].maddpg.actor_lr == 0.01  # SPEC §5 openai/maddpg default


def test_paper_config_is_the_spec(params):
    """SPEC §1-§5 values, read back from params.yaml."""
    w, m = params.world, params.configs["paper"].maddpg
    assert (w.n_agents, w.agent_radius, w.sensitivity, w.dt, w.damping) == (9, 0.08, 5.0, 0.1, 0.25)
    assert (params.coverage.radius, params.coverage.edges) == (0.5, 30)
    assert (m.hidden, m.gamma, m.tau, m.batch_size, m.buffer_size) == (64, 0.95, 0.01, 1024, 1_000_000)
    assert (m.learning_starts, m.update_every, m.grad_clip, m.actor_reg) == (1024 * 25, 100, 0.5, 1e-3)
    assert params.configs["paper"].observation == "position" and params.configs["paper"].geofence is None
    assert params.methods["sw"].reward_mode == "shared" and params.methods["cr"].reward_mode == "individual"
    assert params.train.episodes == 10_000


def write(tmp_path, mutate):
    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    mutate(raw)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda r: r["world"].update(n_agnets=9), r"params.yaml.world: unknown key\(s\) \['n_agnets'\]"),
        (lambda r: r["world"].pop("dt"), "params.yaml.world: missing key 'dt'"),
        (lambda r: r["world"].update(n_agents="nine"), "world.n_agents: expected an integer"),
        (lambda r: r["world"].update(n_agents=9.5), "world.n_agents: expected an integer"),
        (lambda r: r["configs"]["paper"].update(observation="pixels"), "observation: 'pixels' is not one of"),
        (lambda r: r["configs"]["paper"]["maddpg"].update(gamma=True), "maddpg.gamma: expected a number"),
        (lambda r: r["sw_reward"].update(prop_range=[0.85]), "prop_range: expected 2 items"),
        (lambda r: r.update(extra={}), r"unknown key\(s\) \['extra'\]"),
        (lambda r: r["ablation"]["changes"].update(typo=["maddpg.gama"]), "ablation.changes.typo: unknown key"),
        (lambda r: r["ablation"].update(base="best"), "ablation: unknown config 'best'"),
        (lambda r: r["ablation"].update(regions=["atlantis"]), "unknown region"),
        (lambda r: r["report"]["goals"].update(channel="atlantis"), "report.goals.channel: unknown region 'atlantis'"),
        (lambda r: r["regions"]["square"].update(episode_length=0), "regions.square.episode_length must be at least 1"),
        (lambda r: r["general"]["suite"].update(events=["lose"]), r"general.suite.events: 'none' \(still water, which"),
        (lambda r: r["general"]["suite"].update(events=["none", "storm"]), "general.suite.events: 'none'"),
        (lambda r: r["general"]["suite"].update(events=["none", "lose", "lose"]), "each once"),
        (lambda r: r["yardstick"].update(events=["storm"]), "yardstick.events: any of"),
        (lambda r: r["yardstick"].update(fleets=[9, 1]), "yardstick.fleets"),
        (lambda r: r["yardstick"].update(starts=["north"]), "yardstick.starts: 'corner' or 'random'"),
        (lambda r: r["yardstick"].update(fleets=[]), "yardstick.fleets: at least one, each once"),
        (lambda r: r["yardstick"].update(starts=["corner", "corner"]), "yardstick.starts: at least one, each once"),
        (lambda r: r["yardstick"].update(min_seeds=1), "yardstick.min_seeds"),
        (lambda r: r["yardstick"].update(seeds=[1, 2, 3]), r"yardstick.seeds: at least yardstick.min_seeds \(8\)"),
        (lambda r: r["yardstick"].update(seeds=[1, 1, 2, 3, 4, 5, 6, 7]), "yardstick.seeds: .* each once"),
        (lambda r: r["yardstick"].update(seeds=[3, 4, 5, 6, 7, 8, 9, 10]),
         r"yardstick.seeds: \[10\] also in general.seeds"),
        (lambda r: r.pop("yardstick"), "missing key 'yardstick'"),
        (lambda r: r["general"]["learner"].update(hops=2, layers=3),
         r"general.learner: hops \(messages\) have a network of their own"),
        (lambda r: r["general"]["learner"].update(layers=0), "layers"),
        (lambda r: r["general"]["learner"].update(lloyd_prior=10.0),
         r"general.learner.lloyd_prior \(10.0\) steers toward the local centroid"),
        (lambda r: (r["general"]["learner"].update(lloyd_prior=10.0, hops=2),
                    r["general"]["sensors"].update(centroid=True)), "lloyd_prior is added to the MLP actor"),
        (lambda r: r["general"]["learner"].update(lloyd_prior_fade=0.5),
         r"general.learner.lloyd_prior_fade \(0.5\) fades the Lloyd prior, and lloyd_prior is 0"),
        (lambda r: r["general"]["learner"].update(lloyd_prior_fade=1.0), "lloyd_prior_fade"),
    ],
)
def test_bad_params_are_refused(tmp_path, mutate, message):
    with pytest.raises(ConfigError, match=message):
        load_params(write(tmp_path, mutate))


def test_overrides_and_selection(params):
    p = load_params(ROOT / "params.yaml", {"train.episodes": 40})
    assert p.train.episodes == 40
    with pytest.raises(ConfigError, match="unknown key"):
        load_params(ROOT / "params.yaml", {"train.epsiodes": 40})
    with pytest.raises(ConfigError, match="unknown config"):
        run_config(params, "best", "cr")
    with pytest.raises(ConfigError, match="unknown method"):
        run_config(params, "paper", "xx")
    with pytest.raises(ConfigError, match="no such parameters file"):
        load_params(ROOT / "nope.yaml")


def test_a_region_may_set_its_own_episode_length(params):
    """``regions.NAME.episode_length`` is the T of every run and baseline on that region; the others keep the
    world's."""
    for name, spec in params.regions.items():
        t = run_config(params, "paper", "cr", name).world.episode_length
        assert t == (spec.episode_length or params.world.episode_length)
    assert params.regions["rectangle"].episode_length == 100
    assert run_config(params, "tuned", "sw", "rectangle").world.episode_length == 100
    assert run_config(params, "tuned", "cr").world.episode_length == params.world.episode_length
    assert run_config(params, "tuned", "cr", "a/lake.geojson").world.episode_length == params.world.episode_length


def test_configs_are_frozen(params):
    with pytest.raises(dataclasses.FrozenInstanceError):
        params.world.n_agents = 3  # type: ignore[misc]


def flat(d, prefix=""):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from flat(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


def test_ablation_covers_every_change_from_paper_to_tuned(params):
    """Each key where `tuned` differs from `paper` is in exactly one ablation change, and every change differs."""
    ab = params.ablation
    base = dict(flat(to_dict(method_config(params, ab.base, ab.method))))  # as the ablation's method trains it
    ref = dict(flat(to_dict(method_config(params, ab.reference, ab.method))))
    differing = {k for k in base if base[k] != ref[k]}
    listed = [k for keys in ab.changes.values() for k in keys]
    assert sorted(listed) == sorted(set(listed)), "a key belongs to one change only"
    assert differing == set(listed)
    deviations = (ROOT / "docs" / "DEVIATIONS.md").read_text()
    for change, keys in ab.changes.items():
        derived = dict(flat(to_dict(method_config(params, f"{ab.base}-without-{change}", ab.method))))
        assert {k for k in base if derived[k] != base[k]} == set(keys)
        assert all(derived[k] == ref[k] for k in keys)
        assert f"(`{change}`)" in deviations, f"docs/DEVIATIONS.md has no row for the {change} change"
    assert run_config(params, f"{ab.base}-without-geofence", "cr").algo.geofence == ref["geofence"]


def test_imitation_until_is_refused_without_imitation_before():
    """``general.learner.imitation_until`` is read by ``imitation: before`` only: set with another mode it is an
    error that names both, not a silent change of the run's identity."""
    from replicate.core.sections import SharedLearnerConfig

    assert SharedLearnerConfig(imitation="before", imitation_until=0.5).imitation_until == 0.5
    with pytest.raises(ConfigError, match="imitation_until .* 'before' only, and imitation is 'beside'"):
        SharedLearnerConfig(imitation="beside", imitation_until=0.5)
    with pytest.raises(ValueError, match="imitation_until"):
        SharedLearnerConfig(imitation="before", imitation_until=1.0)  # 1: never hands over, which is ``alone``
