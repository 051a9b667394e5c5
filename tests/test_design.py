"""The design yardstick (``design.py``, ``replicate compare``): two versions of the general training, each the
policies of several training seeds, read on lakes of their own with the seed as the unit of the interval."""

import json

import pytest
import torch

from replicate import artifacts
from replicate.config import ConfigError, to_dict
from replicate.design import Versions, check_versions, design_cells, seed_scores, verdict
from replicate.env import observation_columns
from replicate.export import export_general
from replicate.shared_maddpg import SharedActor

from .test_training import cli

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
    cells = design_cells(params)
    d = params.design
    assert len(cells) == d.lakes * len(d.fleets) * len(d.starts) * len(d.events) == len(set(cells))
    assert {c.lake for c in cells}.isdisjoint({"square", "rectangle", "bedok"})


def test_the_verdict_resamples_seeds_and_keeps_the_candidate_only_above_the_margin(params):
    """Four seeds a side: every candidate seed above every baseline seed is kept; the same gain with seeds that
    overlap is not; a margin above the gain is not met."""
    apart = {"baseline/1": 0.980, "baseline/2": 0.981, "baseline/3": 0.982, "baseline/4": 0.983,
             "candidate/1": 0.990, "candidate/2": 0.991, "candidate/3": 0.992, "candidate/4": 0.993}
    v = verdict(apart, params)
    assert v["keep"] == "candidate" and v["difference"]["delta"] == pytest.approx(0.01)
    assert 0 < v["difference"]["lo"] < 0.01 < v["difference"]["hi"] and v["probability_of_improvement"]["p"] == 1
    overlap = {"baseline/1": 0.960, "baseline/2": 0.990, "baseline/3": 0.975, "baseline/4": 0.999,
               "candidate/1": 0.970, "candidate/2": 1.000, "candidate/3": 0.985, "candidate/4": 1.009}
    v = verdict(overlap, params)
    assert v["difference"]["delta"] == pytest.approx(0.01) and v["difference"]["lo"] < 0 and v["keep"] == "baseline"
    import dataclasses

    strict = dataclasses.replace(params, design=dataclasses.replace(params.design, min_gain=0.02))
    assert verdict(apart, strict)["keep"] == "baseline"


def test_a_seed_scores_its_mean_ratio_to_lloyd_over_the_cells():
    rows = [{"lloyd": 0.8, "coverage": {"a": 0.8, "b": 0.4}}, {"lloyd": 0.5, "coverage": {"a": 0.45, "b": 0.5}}]
    assert seed_scores(rows, ["a", "b"]) == pytest.approx({"a": 0.95, "b": 0.75})


def test_versions_that_cannot_be_compared_are_refused_by_name(params, tmp_path):
    a, b, c = (policy(params, tmp_path / f"s{k}", k) for k in (1, 2, 3))
    with pytest.raises(ConfigError, match="--candidate: give the policies of at least two training seeds"):
        check_versions(Versions((a, b), (c,)))
    with pytest.raises(ConfigError, match="no such file"):
        check_versions(Versions((a, b), (c, str(tmp_path / "missing.pt"))))
    with pytest.raises(ConfigError, match="given twice"):
        check_versions(Versions((a, b), (c, a)))
    other = policy(params, tmp_path / "other", 4, {**GAINS, "lloyd_tuned": {"gains": {"gain": 1.0, "damping": 0.5}}})
    with pytest.raises(ConfigError, match="other baseline gains"):
        check_versions(Versions((a, b), (c, other)))


@pytest.mark.slow
def test_compare_reads_both_versions_on_the_same_episodes_and_keeps_a_finished_result(params, tmp_path):
    """`replicate compare` on one design lake: every policy and Lloyd on every cell, a score per seed, the verdict
    and the rule in the JSON; the same --out is not replaced without --force (exit 2, the file unchanged)."""
    files = [policy(params, tmp_path / f"s{k}", k) for k in (1, 2, 3, 4)]
    out = tmp_path / "compare.json"
    small = ["--set", "design.lakes=1", "--set", "design.fleets=[5]", "--set", "design.starts=[random]",
             "--set", "design.events=[none,lose]", "--set", "design.episodes=2"]
    argv = ["compare", "--baseline", *files[:2], "--candidate", *files[2:], "--out", str(out), "--workers", "1"]
    assert cli(*small, *argv).wait(timeout=600) == 0
    result = json.loads(out.read_text())
    assert len(result["cells"]) == 2 and {c["event"] for c in result["cells"]} == {"none", "lose"}
    assert set(result["scores"]) == {"baseline/1", "baseline/2", "candidate/1", "candidate/2"}
    for cell in result["cells"]:
        assert cell["lloyd_name"] == "lloyd_tuned" and 0 < cell["lloyd"] <= 1
        assert all(0 <= v <= 1 for v in cell["coverage"].values())
    assert seed_scores(result["cells"], list(result["scores"])) == pytest.approx(result["scores"])
    assert result["verdict"]["keep"] in ("baseline", "candidate") and "over training seeds" in result["verdict"]["rule"]
    before = out.read_bytes()
    assert cli(*small, *argv).wait(timeout=600) == 2 and out.read_bytes() == before
