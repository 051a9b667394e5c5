"""Training the general policy (``replicate.general_train``) on a few small worlds: it runs, writes its run,
is reproducible, and its actor drives any fleet."""

import dataclasses
import gzip
import json

import numpy as np
import pytest
import torch

from replicate.general_train import FleetReplay, GeneralTrainer
from replicate.shared_maddpg import SharedActor


def tiny(params):
    """Two worlds (the square with 6 buoys and one small generated lake), 8 environments, 48 episodes."""
    return dataclasses.replace(params.general, regions=("square",), fleet=(6,), lakes=1, lake_fleet=(5, 5),
                               lake_ratio=(1.0, 1.0), n_envs=8, episodes=48, episode_length=20,
                               learning_starts=200, batch_size=32, buffer_size=5000, update_every=16,
                               lose_prob=0.5, current_prob=0.5)


@pytest.fixture(scope="module")
def two_runs(params, tmp_path_factory):
    out = tmp_path_factory.mktemp("general")
    summaries = [GeneralTrainer(params, 4, out / f"run{k}", progress=False, config=tiny(params)).run()
                 for k in range(2)]
    return out, summaries


def test_a_run_writes_its_actor_curve_and_summary(two_runs):
    out, (summary, _) = two_runs
    run = out / "run0"
    assert json.loads((run / "run.json").read_text())["status"] == "finished"
    assert [w["n_agents"] for w in summary["worlds"]] == [6, 5]
    lines = gzip.decompress((run / "curve.csv.gz").read_bytes()).decode().splitlines()
    assert len(lines) == 1 + 48 // 8 and lines[0].startswith("batch,episodes,world")
    saved = torch.load(run / "actor.pt")
    assert len(saved["columns"]) == 22 and saved["sensors"]["neighbours"] == 4
    actor = SharedActor(22, 2, saved["hidden"])
    actor.load_state_dict(saved["actor"])
    for n in (5, 9, 30):  # one network for any fleet
        assert actor(torch.zeros(3, n, 22))[0].shape == (3, n, 2)


def test_same_seed_same_run(two_runs):
    out, (a, b) = two_runs
    assert (out / "run0" / "curve.csv.gz").read_bytes() == (out / "run1" / "curve.csv.gz").read_bytes()
    assert a["selected_validation_coverage"] == b["selected_validation_coverage"]


def test_the_replay_pads_small_fleets():
    replay = FleetReplay(10, 4, 3)
    live = np.ones((2, 3), bool)
    arrays = {k: np.ones((2, 3, d)) if d else np.ones((2, 3)) for k, d in
              (("obs", 3), ("act", 2), ("rew", 0), ("next_obs", 3), ("pos", 2), ("next_pos", 2))}
    replay.add(live, live, **arrays)
    b = replay.sample(np.random.default_rng(0), 5, 0.9)
    assert b.obs.shape == (5, 4, 3) and not b.live[:, 3].any() and b.live[:, :3].all()
    assert (b.rew[:, 3] == 0).all() and torch.equal(b.disc, torch.full((5,), 0.9))


@pytest.mark.slow
def test_a_general_policy_runs_zero_shot_on_a_lake_the_repo_does_not_ship(two_runs, tmp_path):
    """`replicate export` of a general run, then `replicate evaluate --policy` on an L-shaped lake with an island
    given as GeoJSON in longitude/latitude, scattered starts, 9 and then 20 buoys: coverage with its interval,
    the baselines under the same rules, and no buoy ever outside the water."""
    import geopandas as gpd
    from shapely.geometry import Polygon

    from .test_training import cli

    out, _ = two_runs
    assert cli("export", str(out / "run0"), "--out", str(tmp_path / "general.pt")).wait(timeout=300) == 0
    deg = 1e-4  # ~11 m
    lake = Polygon([(103.9, 1.33), (103.9 + 6 * deg, 1.33), (103.9 + 6 * deg, 1.33 + 2 * deg),
                    (103.9 + 2 * deg, 1.33 + 2 * deg), (103.9 + 2 * deg, 1.33 + 6 * deg), (103.9, 1.33 + 6 * deg)],
                   holes=[[(103.9 + 0.6 * deg, 1.33 + 0.6 * deg), (103.9 + 1.2 * deg, 1.33 + 0.6 * deg),
                           (103.9 + 1.2 * deg, 1.33 + 1.2 * deg), (103.9 + 0.6 * deg, 1.33 + 1.2 * deg)]])
    gpd.GeoDataFrame({"name": ["l lake"]}, geometry=[lake], crs="EPSG:4326").to_file(tmp_path / "lake.geojson")
    for n in (9, 20):
        report = tmp_path / f"x{n}.json"
        events = ["--lose", "5"] if n == 20 else []
        proc = cli("--set", "evaluate.episodes=8", "evaluate", "--policy", str(tmp_path / "general.pt"), "--region",
                   str(tmp_path / "lake.geojson"), "--starts", "random", "--n-agents", str(n), *events,
                   "--out", str(report))
        assert proc.wait(timeout=600) == 0
        result = json.loads(report.read_text())
        cov = result["coverage"]
        assert 0 <= cov["lo"] <= cov["mean"] <= cov["hi"] <= 1 and cov["n"] == 8 and result["n_agents"] == n
        assert result["lose"] == (5 if n == 20 else 0) and result["max_outside_m"] == 0.0
        assert set(result["baselines"]) == {"naive", "lloyd"} and result["max_outside_m"] == 0.0
        assert result["ratio_to_lloyd"] == pytest.approx(cov["mean"] / result["baselines"]["lloyd"]["coverage"]["mean"])
