"""The yardstick (``compare.yardstick``, ``replicate compare``): two versions of the general training, each the
policies of several training seeds, read on lakes of their own with the seed as the unit of the interval."""

import dataclasses
import json
import shutil

import numpy as np
import pytest
import torch

from replicate.compare import stats
from replicate.compare.yardstick import (
    SeedPolicy,
    Versions,
    check_versions,
    seed_scores,
    verdict,
    yardstick_cells,
    yardstick_lakes,
)
from replicate.core import artifacts
from replicate.core.schema import ConfigError, to_dict
from replicate.learn.shared_maddpg import SharedActor
from replicate.toolkit.export import export_general
from replicate.world.env import observation_columns

from ..command import cli

GAINS = {"naive_tuned": {"gains": {"attraction": 1.0, "avoid_range": 1.0, "avoidance": 1.0, "damping": 1.0}},
         "lloyd_tuned": {"gains": {"gain": 10.0, "damping": 0.5}}}


def policy(params, folder, seed: int, gains=GAINS):
    """An untrained general actor of ``seed``'s weights, exported as ``replicate export`` does."""
    torch.manual_seed(seed)
    columns = observation_columns("local", params.general.sensors)
    actor = SharedActor(len(columns), 2, 16, "none", columns)
    folder.mkdir(parents=True, exist_ok=True)
    artifacts.torch_save(folder / "actor.pt", {
        "format": artifacts.CHECKPOINT_FORMAT, "actor": actor.state_dict(), "observation": "local",
        "sensors": to_dict(params.general.sensors), "columns": columns, "hidden": 16, "selected_episode": 0,
        "seed": seed})
    export_general(folder / "actor.pt", folder / "policy.pt", params.world.sensitivity, gains)
    return str(folder / "policy.pt")


def test_the_cells_cross_every_design_lake_with_fleets_starts_and_events(params):
    """The yardstick's cells cross its lakes with its fleets, starts and events; its lakes are the suite's design
    lakes, none of them a test lake."""
    from replicate.compare.suite import lake_kinds

    cells = yardstick_cells(params)
    d = params.yardstick
    assert len(cells) == d.lakes * len(d.fleets) * len(d.starts) * len(d.events) == len(set(cells))
    kinds = lake_kinds(params)
    assert len(yardstick_lakes(params)) == d.lakes and all(kinds[name] == "design" for name in yardstick_lakes(params))


def by_seed(baseline: list[float], candidate: list[float]) -> dict[SeedPolicy, float]:
    """Scores of each version's seeds, keyed as ``compare_versions`` keys them."""
    return {SeedPolicy(side, i): v for side, values in (("baseline", baseline), ("candidate", candidate))
            for i, v in enumerate(values, start=1)}


def test_the_verdict_resamples_seeds_and_keeps_the_candidate_only_above_the_margin(params):
    """Four seeds a side: every candidate seed above every baseline seed is kept; the same gain with seeds that
    overlap is not; a margin above the gain is not met."""
    apart = by_seed([0.980, 0.981, 0.982, 0.983], [0.990, 0.991, 0.992, 0.993])
    v = verdict(apart, params)
    assert v["keep"] == "candidate" and v["difference"]["delta"] == pytest.approx(0.01)
    assert 0 < v["difference"]["lo"] < 0.01 < v["difference"]["hi"] and v["probability_of_improvement"]["p"] == 1
    overlap = by_seed([0.960, 0.990, 0.975, 0.999], [0.970, 1.000, 0.985, 1.009])
    v = verdict(overlap, params)
    assert v["difference"]["delta"] == pytest.approx(0.01) and v["difference"]["lo"] < 0 and v["keep"] == "baseline"
    strict = dataclasses.replace(params, yardstick=dataclasses.replace(params.yardstick, min_gain=0.02))
    assert verdict(apart, strict)["keep"] == "baseline"


def test_with_two_equal_versions_the_rule_rarely_keeps_the_candidate_at_min_seeds(params):
    """Why ``yardstick.min_seeds``: the percentile interval over very few seeds is too narrow. Equal versions (both
    sides drawn from one distribution): at 2 seeds a side the candidate is kept far more often than the nominal
    2.5 %, at ``min_seeds`` close to it."""
    rng, boot = np.random.default_rng(0), stats.Bootstrap(0.95, 1000, 0)

    def kept(k: int, draws: int = 300) -> float:
        return np.mean([stats.difference([rng.normal(size=k)], [rng.normal(size=k)], boot)["lo"] > 0
                        for _ in range(draws)])

    assert kept(2) > 0.10
    assert kept(params.yardstick.min_seeds) < 0.06


def test_a_seed_is_written_by_its_label_and_files_keep_the_order_given():
    files = Versions(("a.pt", "b.pt"), ("c.pt", "d.pt")).files()
    assert [str(seed) for seed in files] == ["baseline/1", "baseline/2", "candidate/1", "candidate/2"]
    assert files[SeedPolicy("candidate", 2)] == "d.pt"


def test_a_seed_scores_its_mean_ratio_to_lloyd_over_the_cells():
    rows = [{"lloyd": 0.8, "coverage": {"a": 0.8, "b": 0.4}}, {"lloyd": 0.5, "coverage": {"a": 0.45, "b": 0.5}}]
    assert seed_scores(rows, ["a", "b"]) == pytest.approx({"a": 0.95, "b": 0.75})


def test_versions_that_cannot_be_compared_are_refused_by_name(params, tmp_path):
    a, b, c = (policy(params, tmp_path / f"s{k}", k) for k in (1, 2, 3))
    with pytest.raises(ConfigError, match="--candidate: give the policies of at least 2 training seeds"):
        check_versions(Versions((a, b), (c,)), 2)
    with pytest.raises(ConfigError, match="--baseline: give the policies of at least 8 training seeds"):
        check_versions(Versions((a, b), (c, a)), 8)
    with pytest.raises(ConfigError, match="--candidate .*missing.pt: no such file"):
        check_versions(Versions((a, b), (c, str(tmp_path / "missing.pt"))), 2)
    with pytest.raises(ConfigError, match="given twice"):
        check_versions(Versions((a, b), (c, a)), 2)
    with pytest.raises(ConfigError, match="--candidate .*actor.pt: not an exported general policy"):
        check_versions(Versions((a, b), (c, str(tmp_path / "s1" / "actor.pt"))), 2)
    bare = policy(params, tmp_path / "bare", 5, gains=None)
    with pytest.raises(ConfigError, match="carries no tuned baseline gains"):
        check_versions(Versions((a, b), (c, bare)), 2)
    other = policy(params, tmp_path / "other", 4, {**GAINS, "lloyd_tuned": {"gains": {"gain": 1.0, "damping": 0.5}}})
    with pytest.raises(ConfigError, match="other baseline gains"):
        check_versions(Versions((a, b), (c, other)), 2)


@pytest.mark.slow
def test_compare_reads_both_versions_on_the_same_episodes_and_keeps_a_finished_result(params, tmp_path):
    """`replicate compare` on one yardstick lake, with the candidate's seeds byte copies of the baseline's: every
    policy and Lloyd on every cell, the copies scoring exactly as their originals (the same episodes), so the
    difference is 0 and the baseline is kept; the same --out is not replaced without --force (exit 2, the file
    unchanged), and a version of one seed is refused (exit 2)."""
    files = [policy(params, tmp_path / f"s{k}", k) for k in (1, 2)]
    for k, f in enumerate(files, start=1):
        (tmp_path / f"copy{k}").mkdir()
        shutil.copy(f, tmp_path / f"copy{k}" / "policy.pt")
    copies = [str(tmp_path / f"copy{k}" / "policy.pt") for k in (1, 2)]
    out = tmp_path / "compare.json"
    small = ["--set", "yardstick.lakes=1", "--set", "yardstick.fleets=[5]", "--set", "yardstick.starts=[random]",
             "--set", "yardstick.events=[none,lose]", "--set", "yardstick.episodes=2", "--set", "yardstick.min_seeds=2"]
    argv = ["compare", "--baseline", *files, "--candidate", *copies, "--out", str(out), "--workers", "1"]
    assert cli(*small, *argv).wait(timeout=600) == 0
    result = json.loads(out.read_text())
    assert len(result["cells"]) == 2 and {c["event"] for c in result["cells"]} == {"none", "lose"}
    for cell in result["cells"]:
        assert cell["lloyd_name"] == "lloyd_tuned" and 0 < cell["lloyd"] <= 1
        cov = cell["coverage"]
        assert all(0 <= v <= 1 for v in cov.values()) and cov["baseline/1"] != cov["baseline/2"]
        assert cov["candidate/1"] == cov["baseline/1"] and cov["candidate/2"] == cov["baseline/2"]
    assert seed_scores(result["cells"], list(result["scores"])) == pytest.approx(result["scores"])
    v = result["verdict"]
    assert v["difference"]["delta"] == 0 and v["keep"] == "baseline" and "over training seeds" in v["rule"]
    before = out.read_bytes()
    assert cli(*small, *argv).wait(timeout=600) == 2 and out.read_bytes() == before
    one = ["compare", "--baseline", files[0], "--candidate", copies[0], "--out", str(tmp_path / "one.json")]
    assert cli(*small, *one).wait(timeout=600) == 2 and not (tmp_path / "one.json").exists()
