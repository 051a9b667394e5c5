"""Optuna studies of the baselines' gains and of a method's training values (``replicate.compare.tuning``), in SQLite
files the tests write."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from replicate.compare import tuning
from replicate.core.params import load_params, run_config
from replicate.core.schema import ConfigError
from replicate.core.studies import Dimension, Search
from replicate.learn import fingerprint

from ..conftest import ROOT


def small(tmp_path, trials=4, **overrides):
    p = load_params(ROOT / "params.yaml", {"tuning.starts": 6, "tuning.baselines.naive.trials": trials,
                                           "tuning.baselines.lloyd.trials": trials,
                                           "tuning.baselines.storage": f"sqlite:///{tmp_path}/b.db",
                                           "tuning.method.storage": f"sqlite:///{tmp_path}/m.db", **overrides})
    return p


def test_baseline_study_is_seeded_and_scores_on_the_tuning_starts(tmp_path, regions):
    p = small(tmp_path)
    first = tuning.tune_baseline(p, regions["square"], "naive")
    again = tuning.tune_baseline(small(tmp_path / "other"), regions["square"], "naive")
    assert first["gains"] == again["gains"] and first["tuning_coverage"] == again["tuning_coverage"]
    assert set(first["gains"]) == {"attraction", "avoid_range", "avoidance", "damping"}
    import optuna

    study = optuna.load_study(study_name=first["study"], storage=p.tuning.baselines.storage)
    per_trial = [t.user_attrs["cpu_seconds"] for t in study.trials]
    assert first["trials"] == 4 and len(per_trial) == 4 and min(per_trial) > 0  # a naive trial takes milliseconds
    assert first["cpu_seconds"] == round(sum(per_trial), 1)
    score = tuning.baseline_coverage("naive", first["gains"], p, regions["square"], p.tuning.starts_seed, 6)
    assert score == pytest.approx(first["tuning_coverage"])  # the objective is the coverage it reports


def test_a_finished_study_is_read_back_and_a_longer_one_resumes(tmp_path, regions):
    done = tuning.tune_baseline(small(tmp_path, trials=3), regions["square"], "lloyd")
    study = tuning.open_study(f"sqlite:///{tmp_path}/b.db", done["study"], 0)
    assert len(study.trials) == 3
    again = tuning.tune_baseline(small(tmp_path, trials=3), regions["square"], "lloyd")
    assert again["trials"] == 3 and again["gains"] == done["gains"]  # nothing rerun
    more = tuning.tune_baseline(small(tmp_path, trials=5), regions["square"], "lloyd")
    assert more["trials"] == 5 and more["study"] == done["study"]
    study = tuning.open_study(f"sqlite:///{tmp_path}/b.db", done["study"], 0)
    drawn = [tuple(t.params.values()) for t in study.trials]
    assert len(set(drawn)) == 5, "a resumed study draws new trials, not its first ones again"
    # every trial names the arithmetic that scored it and proposed it, in the storage other processes read
    assert {t.user_attrs["arithmetic"] for t in study.trials} == {fingerprint.search_fingerprint()}


def test_a_changed_search_is_a_study_of_its_own(tmp_path, regions):
    p = small(tmp_path, trials=2)
    a = tuning.tune_baseline(p, regions["square"], "lloyd")
    wider = dataclasses.replace(p.tuning.baselines.lloyd,
                                space={**p.tuning.baselines.lloyd.space, "gain": Dimension(low=0.1, high=50.0)})
    q = dataclasses.replace(p, tuning=dataclasses.replace(
        p.tuning, baselines=dataclasses.replace(p.tuning.baselines, lloyd=wider)))
    b = tuning.tune_baseline(q, regions["square"], "lloyd")
    assert a["study"] != b["study"] and b["trials"] == 2


def test_method_trial_trains_on_the_tuning_seeds_and_returns_a_coverage(tmp_path, regions, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    p = small(tmp_path, **{"tuning.method.episodes": 100, "tuning.method.trials": 1,
                           "tuning.method.seeds": [900], "configs.tuned.maddpg.learning_starts": 500})
    out = tuning.tune_method(p, {"square": regions["square"]})
    assert out["trials"] == 1 and 0.0 <= out["tuning_coverage"] <= 1.0
    assert out["incumbent_coverage"] == out["tuning_coverage"], "the first trial is the config's own values"
    assert set(out["values"]) == set(p.tuning.method.space)
    assert not list(tmp_path.glob("replicate-trial-*")), "a trial's runs are deleted"


def test_per_method_values_apply_to_their_method_only(params):
    p = load_params(ROOT / "params.yaml", {"configs.tuned.per_method": {"sw": {"maddpg.gamma": 0.97,
                                                                                "reward_scale": 0.002}}})
    sw, cr = run_config(p, "tuned", "sw").algo, run_config(p, "tuned", "cr").algo
    assert (sw.maddpg.gamma, sw.reward_scale) == (0.97, 0.002) and sw.per_method is None
    assert cr == run_config(params, "tuned", "cr").algo  # CR's run identity is untouched
    with pytest.raises(ConfigError, match="unknown key 'gama'"):
        load_params(ROOT / "params.yaml", {"configs.tuned.per_method": {"sw": {"maddpg.gama": 0.9}}})
    with pytest.raises(ConfigError, match="expected a number"):
        load_params(ROOT / "params.yaml", {"configs.tuned.per_method": {"sw": {"reward_scale": "big"}}})


def test_search_ranges_are_checked():
    with pytest.raises(ConfigError, match="low < high"):
        Dimension(low=1.0, high=1.0)
    with pytest.raises(ConfigError, match="log-scale"):
        Dimension(low=0.0, high=1.0, log=True)
    assert Search(3, {"x": Dimension(choices=(1, 2))}).trials == 3


def test_suggest_draws_inside_every_range():
    import optuna

    space = {"a": Dimension(low=0.1, high=10.0, log=True), "b": Dimension(choices=(None, 0.5)),
             "c": Dimension(low=1, high=5, integer=True)}
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(20):
        values = tuning.suggest(study.ask(), space)
        assert 0.1 <= values["a"] <= 10.0 and values["b"] in (None, 0.5) and isinstance(values["c"], int)
    assert np.isfinite(values["a"])


def test_general_baselines_are_tuned_once_on_the_training_worlds_behind_the_wall(tmp_path):
    """One set of naive and Lloyd gains for every lake: a seeded study over the general policy's training worlds
    (here the square with 6 buoys and one small generated lake), its objective the coverage it reports, read back
    when finished, written by `replicate tune general-baselines` and carried by an exported general policy."""
    small = {"general.regions": ["square"], "general.fleet": [6], "general.lakes": 1, "general.lake_fleet": [5, 5],
             "general.lake_ratio": [1.0, 1.0], "tuning.general_baselines.starts": 2,
             "tuning.general_baselines.naive_trials": 3, "tuning.general_baselines.lloyd_trials": 2,
             "tuning.general_baselines.decentralised_trials": 2, "tuning.general_baselines.geodesic_trials": 2}
    p = load_params(ROOT / "params.yaml", {**small, "tuning.general_baselines.storage": f"sqlite:///{tmp_path}/g.db"})
    worlds = tuning.general_worlds(p)
    assert [env.n_agents for _, env in worlds] == [6, 5] and all(env.wall for _, env in worlds)
    out = tuning.tune_general_baselines(p)
    kinds = ("naive_tuned", "lloyd_tuned", "decentralised_tuned", "geodesic_tuned")
    assert set(out) == set(kinds) and [out[k]["trials"] for k in kinds] == [3, 2, 2, 2]
    assert all(set(out[k]["gains"]) == {"gain", "damping"} for k in kinds[1:])
    score = tuning.general_baseline_coverage("lloyd", p, out["lloyd_tuned"]["gains"])
    assert score == pytest.approx(out["lloyd_tuned"]["tuning_coverage"])
    assert tuning.tune_general_baselines(p) == out  # finished: read back, nothing rerun
    side_by_side = load_params(ROOT / "params.yaml",
                               {**small, "tuning.general_baselines.storage": f"sqlite:///{tmp_path}/g2.db"})
    fanned = tuning.tune_general_baselines(side_by_side, workers=2)  # the three studies in two processes
    for kind in out:  # the same trials: the same gains and coverage (CPU seconds are measured, so they differ)
        assert {k: fanned[kind][k] for k in ("gains", "tuning_coverage", "trials")} == \
            {k: out[kind][k] for k in ("gains", "tuning_coverage", "trials")}
