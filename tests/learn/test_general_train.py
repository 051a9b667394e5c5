"""Training the general policy (``replicate.learn.general_train``) on a few small worlds: it runs, writes its run,
is reproducible, and its actor drives any fleet."""

import dataclasses
import gzip
import json
import subprocess

import numpy as np
import pytest
import torch

from replicate.learn import fingerprint
from replicate.learn.general_train import GeneralTrainer
from replicate.learn.shared_maddpg import SharedActor
from replicate.world.sensors import ON_SHORE, on_shore, shore_rays

from ..toolkit.gis import check_field_files


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
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "finished"
    assert record["arithmetic"] == fingerprint.general_fingerprint()  # which numbers trained it, recorded
    assert [w["n_agents"] for w in summary["worlds"]] == [6, 5]
    lines = gzip.decompress((run / "curve.csv.gz").read_bytes()).decode().splitlines()
    assert len(lines) == 1 + 48 // 8 and lines[0].startswith("batch,episodes,world")
    saved = torch.load(run / "actor.pt")
    assert len(saved["columns"]) == 22 and saved["sensors"]["neighbours"] == 4
    assert saved["sensors"]["velocity"] == "ground"  # over the ground, as params.yaml reads it
    assert not any(c.startswith("uncovered") for c in saved["columns"])  # the uncovered-water sensor is off
    assert saved["symmetry"] == "d4_frame"  # the compass symmetry by one canonical frame, as params.yaml trains it
    actor = SharedActor(22, 2, saved["hidden"], saved["symmetry"], saved["columns"])
    actor.load_state_dict(saved["actor"])
    for n in (5, 9, 30):  # one network for any fleet
        assert actor(torch.zeros(3, n, 22))[0].shape == (3, n, 2)


def test_same_seed_same_run(two_runs):
    out, (a, b) = two_runs
    assert (out / "run0" / "curve.csv.gz").read_bytes() == (out / "run1" / "curve.csv.gz").read_bytes()
    assert a["selected_validation_coverage"] == b["selected_validation_coverage"]


def test_an_averaged_actor_starts_from_the_given_weights_and_is_the_one_validated_and_kept(params, tmp_path):
    """``general.learner.average``: starting weights go to the trained actor, its target and its average alike; the
    validation scores and keeps the average's weights, not the trained actor's."""
    cfg = tiny(params)
    cfg = dataclasses.replace(cfg, learner=dataclasses.replace(cfg.learner, average=0.1))
    start = GeneralTrainer(params, 5, tmp_path / "a", progress=False, config=tiny(params)).agent.actor.state_dict()
    trainer = GeneralTrainer(params, 6, tmp_path / "b", progress=False, config=cfg, actor=start)
    agent = trainer.agent
    for net in (agent.actor, agent.actor_target, agent.actor_average):
        assert all(torch.equal(net.state_dict()[k], v) for k, v in start.items())
    with torch.no_grad():
        for p in agent.actor_average.parameters():
            p.mul_(0.5)  # the average and the trained actor now differ
    trainer.validate(0)
    kept = trainer.loop.kept[0]["actor"]
    assert all(torch.equal(kept[k], v) for k, v in agent.actor_average.state_dict().items())
    assert not all(torch.equal(kept[k], v) for k, v in agent.actor.state_dict().items())


def test_a_buoy_the_wall_stopped_is_on_the_shore(params, regions):
    """Buoys driven into the shore at full thrust rest on it (the wall stops them a hair inside the water: their
    shortest ray is above 0): ``on_shore`` finds every one of them, and none of the buoys left mid-lake."""
    from replicate.world.env import CoverageEnv, observation_columns

    env = CoverageEnv(regions["square"], dataclasses.replace(params.world, n_agents=4), params.coverage, n_envs=3,
                      observation="local", sensors_config=params.general.sensors, wall=True)
    env.reset(seed=0, start="random")
    env.pos[:] = [[-0.4, 0.0], [0.4, 0.0], [0.0, -0.4], [0.0, 0.4]]
    env.vel[:] = 0.0
    push = np.zeros((3, 4, 2))
    push[:, :2, 0] = [-1.0, 1.0]  # buoys 0 and 1 drive west and east into the shore; 2 and 3 drift still
    for _ in range(30):
        obs = env.step(push).obs
    columns = observation_columns("local", params.general.sensors)
    assert 0 < obs[:, :2, [k for k, c in enumerate(columns) if c.startswith("shore_")]].min() < ON_SHORE
    shore = on_shore(obs, shore_rays(columns))
    assert shore[:, :2].all() and not shore[:, 2:].any()


@pytest.mark.slow
def test_a_general_policy_runs_zero_shot_on_a_lake_the_repo_does_not_ship(two_runs, tmp_path):
    """`replicate export` of a general run, then `replicate evaluate --policy` on an L-shaped lake with an island
    given as GeoJSON in longitude/latitude, scattered starts, 9 and then 20 buoys: coverage with its interval,
    the baselines under the same rules (hand-set gains, then the gains the exported policy carries), the best
    layout of the buoys in service, and no buoy ever outside the water."""
    import geopandas as gpd
    from shapely.geometry import Polygon

    from ..command import cli

    out, _ = two_runs
    gains = {"naive_tuned": {"gains": {"attraction": 8.0, "avoid_range": 1.0, "avoidance": 10.0, "damping": 0.1}},
             "lloyd_tuned": {"gains": {"gain": 50.0, "damping": 0.2}},
             "decentralised_tuned": {"gains": {"gain": 40.0, "damping": 0.0}}}
    (tmp_path / "gains.json").write_text(json.dumps(gains))
    assert cli("export", str(out / "run0"), "--out", str(tmp_path / "general.pt")).wait(timeout=300) == 0
    assert cli("export", str(out / "run0"), "--out", str(tmp_path / "carrying.pt"), "--baseline-gains",
               str(tmp_path / "gains.json")).wait(timeout=300) == 0
    deg = 1e-4  # ~11 m
    lake = Polygon([(103.9, 1.33), (103.9 + 6 * deg, 1.33), (103.9 + 6 * deg, 1.33 + 2 * deg),
                    (103.9 + 2 * deg, 1.33 + 2 * deg), (103.9 + 2 * deg, 1.33 + 6 * deg), (103.9, 1.33 + 6 * deg)],
                   holes=[[(103.9 + 0.6 * deg, 1.33 + 0.6 * deg), (103.9 + 1.2 * deg, 1.33 + 0.6 * deg),
                           (103.9 + 1.2 * deg, 1.33 + 1.2 * deg), (103.9 + 0.6 * deg, 1.33 + 1.2 * deg)]])
    gpd.GeoDataFrame({"name": ["l lake"]}, geometry=[lake], crs="EPSG:4326").to_file(tmp_path / "lake.geojson")
    cases = ((9, "general.pt", {"naive", "lloyd"}), (20, "carrying.pt", {"naive_tuned", "lloyd_tuned"}))
    for n, policy, rivals in cases:
        report = tmp_path / f"x{n}.json"
        events = ["--lose", "5", "--geodesic"] if n == 20 else []  # geodesic Lloyd only when asked
        proc = cli("--set", "evaluate.episodes=8", "evaluate", "--policy", str(tmp_path / policy), "--region",
                   str(tmp_path / "lake.geojson"), "--starts", "random", "--n-agents", str(n), *events,
                   "--out", str(report))
        assert proc.wait(timeout=600) == 0
        result = json.loads(report.read_text())
        cov = result["coverage"]
        assert 0 <= cov["lo"] <= cov["mean"] <= cov["hi"] <= 1 and cov["n"] == 8 and result["n_agents"] == n
        assert result["lose"] == (5 if n == 20 else 0) and result["max_outside_m"] == 0.0
        limits = {"best_layout", "upper_bound"}
        assert set(result["baselines"]) == rivals | limits | ({"geodesic_lloyd"} if n == 20 else set())
        lloyd = result["baselines"][sorted(rivals)[0]]["coverage"]["mean"]
        assert result["ratio_to_lloyd"] == pytest.approx(cov["mean"] / lloyd)
        best, bound = result["baselines"]["best_layout"], result["baselines"]["upper_bound"]
        assert best["buoys"] == bound["buoys"] == n - (5 if n == 20 else 0)
        found = [b["coverage"]["mean"] for k, b in result["baselines"].items() if k not in limits]
        assert max(found) <= best["coverage"]["mean"] + 0.01 <= bound["coverage"]["mean"] + 0.01
        assert cov["mean"] <= bound["coverage"]["mean"]  # the bound is above every method


@pytest.mark.slow
def test_an_episode_for_the_figures_shows_the_loss_from_its_step(two_runs, params, regions, tmp_path):
    """``evaluate.general_episode``: positions [T + 1, N, 2] and the buoys in service [T + 1, N], the lost ones out
    of service from the frame of the step before which they were lost."""
    from replicate.compare.evaluate import general_episode
    from replicate.toolkit.export import export_general

    out, _ = two_runs
    export_general(out / "run0" / "actor.pt", tmp_path / "general.pt")
    trace, alive = general_episode(tmp_path / "general.pt", regions["square"], params, 9, "corner", lose=3)
    t = params.general.episode_length
    assert trace.shape == (t + 1, 9, 2) and alive.shape == (t + 1, 9)
    assert alive[: t // 2].all() and (alive[t // 2:].sum(axis=1) == 6).all()
    assert (trace[t // 2:, ~alive[-1]] == trace[t // 2, ~alive[-1]]).all()  # the lost stay where they were lost


@pytest.mark.slow
def test_cover_uses_the_general_policy_zero_shot_and_fine_tuned(two_runs, tmp_path):
    """`replicate cover --policy FILE`: the general policy on a lake the repo does not ship, zero-shot with its
    baselines under the wall; then `--finetune`, which keeps the starting weights when training (here too short
    to update once) does not beat them on the lake's validation starts."""
    import geopandas as gpd
    from shapely.geometry import Polygon

    from ..command import cli

    out, _ = two_runs
    assert cli("export", str(out / "run0"), "--out", str(tmp_path / "general.pt")).wait(timeout=300) == 0
    lake = Polygon([(6.56, 46.50), (6.575, 46.502), (6.58, 46.51), (6.565, 46.512), (6.555, 46.505)])
    gpd.GeoDataFrame({"name": ["lake"]}, geometry=[lake], crs="EPSG:4326").to_file(tmp_path / "lake.geojson")
    small = ["--set", "evaluate.episodes=4", "--set", "general.n_envs=4"]
    zero = cli(*small, "cover", "--region", str(tmp_path / "lake.geojson"), "--policy", str(tmp_path / "general.pt"),
               "--n-agents", "6", "--out", str(tmp_path / "zero"), "--no-progress", stdout=subprocess.PIPE, text=True)
    assert zero.wait(timeout=600) == 0
    assert "general policy, zero-shot: coverage" in zero.stdout.read()
    summary = json.loads((tmp_path / "zero" / "summary.json").read_text())
    assert summary["n_agents"] == 6 and summary["finetune_episodes"] == 0 and summary["max_outside_m"] == 0.0
    assert set(summary["baselines"]) == {"naive", "lloyd", "best_layout", "upper_bound"}
    assert summary["coverage"]["mean"] <= summary["baselines"]["best_layout"]["coverage"]["mean"] + 0.01
    layers, episode = check_field_files(tmp_path / "zero", "episode")
    assert set(layers["tracks"].method) == {"general policy", "lloyd", "decentralised_lloyd", "planner"}
    assert len(layers["waypoints"]) == 4 * 6 * (summary["episode_length"] + 1)  # the four tracks, every step
    tuned = cli(*small, "cover", "--region", str(tmp_path / "lake.geojson"), "--policy", str(tmp_path / "general.pt"),
                "--n-agents", "6", "--finetune", "8", "--out", str(tmp_path / "tuned"), "--no-progress")
    assert tuned.wait(timeout=600) == 0
    again = json.loads((tmp_path / "tuned" / "summary.json").read_text())
    assert again["finetune_episodes"] == 8 and again["finetune"]["selected_episode"] == 0  # the starting weights
    assert again["coverage"] == summary["coverage"]
    assert (tmp_path / "tuned" / "policy.pt").exists() and (tmp_path / "tuned" / "finetune" / "curve.csv.gz").exists()


def test_the_pipeline_keeps_the_best_validated_seed_and_skips_finished_ones(tmp_path):
    """``pipeline.general.train_general``: each seed trained once, the best-validated one exported with the
    baselines' gains; run again with the same settings, nothing is trained."""
    import yaml

    from replicate.learn.policy import load_policy
    from replicate.pipeline.general import train_general

    from ..conftest import ROOT

    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    raw["general"].update(regions=["square"], fleet=[6], lakes=1, lake_fleet=[5, 5], lake_ratio=[1.0, 1.0],
                          n_envs=4, episodes=8, episode_length=10, learning_starts=50, batch_size=16,
                          buffer_size=1000, update_every=8, seeds=[10, 11])
    raw["regions"]["bedok"]["path"] = str(ROOT / raw["regions"]["bedok"]["path"])
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    gains = {"naive_tuned": {"gains": {"attraction": 8.0, "avoid_range": 1.0, "avoidance": 10.0, "damping": 0.1}},
             "lloyd_tuned": {"gains": {"gain": 50.0, "damping": 0.2}},
             "decentralised_tuned": {"gains": {"gain": 40.0, "damping": 0.0}}}
    (tmp_path / "gains.json").write_text(json.dumps(gains))
    first = train_general(str(tmp_path / "params.yaml"), str(tmp_path / "policies"), str(tmp_path / "gains.json"), 1)
    scores = {r["seed"]: r["selected_validation_coverage"] for r in first["runs"]}
    assert first["kept_seed"] == max(scores, key=scores.get) and not any(r["skipped"] for r in first["runs"])
    _, meta = load_policy(tmp_path / "policies" / "general.pt")
    assert meta["n_agents"] == "any" and meta["trained"]["seed"] == first["kept_seed"]
    assert {k: v["gains"] for k, v in meta["baseline_gains"].items()} == {k: v["gains"] for k, v in gains.items()}
    for run in first["runs"]:  # every seed exported; the deployed file is the kept seed's
        assert load_policy(tmp_path / "policies" / run["policy"])[1]["trained"]["seed"] == run["seed"]
    kept = tmp_path / "policies" / "runs" / f"general-s{first['kept_seed']}" / "policy.pt"
    assert (tmp_path / "policies" / "general.pt").read_bytes() == kept.read_bytes()
    again = train_general(str(tmp_path / "params.yaml"), str(tmp_path / "policies"), str(tmp_path / "gains.json"), 1)
    assert all(r["skipped"] for r in again["runs"]) and again["kept_seed"] == first["kept_seed"]


@pytest.mark.slow
def test_the_standing_baseline_is_read_by_compare_only_while_params_match_it(tmp_path):
    """``pipeline.general.train_yardstick`` trains ``yardstick.seeds`` as ``train_general`` trains its seeds, without a
    deployed policy; ``yardstick.standing_baseline`` gives its exported policies, and refuses by name a folder
    without one, an unreadable summary, other seeds than ``yardstick.seeds`` or runs trained with other values (a
    stale baseline would score every change since); `replicate compare` without --baseline reads it beside the
    parameters file."""
    import shutil

    import yaml

    from replicate.compare.yardstick import standing_baseline
    from replicate.core.params import load_params
    from replicate.core.schema import ConfigError
    from replicate.learn.policy import load_policy
    from replicate.pipeline.general import train_yardstick

    from ..command import cli
    from ..conftest import ROOT

    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    raw["general"].update(regions=["square"], fleet=[6], lakes=1, lake_fleet=[5, 5], lake_ratio=[1.0, 1.0],
                          n_envs=4, episodes=8, episode_length=10, learning_starts=50, batch_size=16,
                          buffer_size=1000, update_every=8)
    raw["yardstick"].update(seeds=[2, 3], min_seeds=2)
    raw["regions"]["bedok"]["path"] = str(ROOT / raw["regions"]["bedok"]["path"])
    params_file = tmp_path / "params.yaml"

    def write(raw):
        params_file.write_text(yaml.safe_dump(raw, sort_keys=False))
        return load_params(params_file)

    params = write(raw)
    gains = {"naive_tuned": {"gains": {"attraction": 8.0, "avoid_range": 1.0, "avoidance": 10.0, "damping": 0.1}},
             "lloyd_tuned": {"gains": {"gain": 50.0, "damping": 0.2}},
             "decentralised_tuned": {"gains": {"gain": 40.0, "damping": 0.0}}}
    (tmp_path / "gains.json").write_text(json.dumps(gains))
    folder = tmp_path / "yardstick"
    with pytest.raises(ConfigError, match="no standing baseline here"):
        standing_baseline(params, folder)
    summary = train_yardstick(str(params_file), str(folder), str(tmp_path / "gains.json"), 1)
    assert [r["seed"] for r in summary["runs"]] == [2, 3] and not (folder / "general.pt").exists()
    files = standing_baseline(params, folder)
    assert [load_policy(f)[1]["trained"]["seed"] for f in files] == [2, 3]

    # compare without --baseline, from another folder: the baseline is read beside the parameters file
    copies = []
    for k, f in enumerate(files):
        (tmp_path / f"cand{k}").mkdir()
        copies.append(str(shutil.copy(f, tmp_path / f"cand{k}" / "policy.pt")))
    small = ["--set", "yardstick.lakes=1", "--set", "yardstick.fleets=[5]", "--set", "yardstick.starts=[random]",
             "--set", "yardstick.events=[none]", "--set", "yardstick.episodes=2"]
    out = tmp_path / "c.json"
    assert cli("--params", str(params_file), *small, "compare", "--candidate", *copies, "--out", str(out),
               cwd=tmp_path / "cand0").wait(timeout=600) == 0
    result = json.loads(out.read_text())
    assert result["policies"]["baseline/1"] == str(folder / "runs" / "general-s2" / "policy.pt")
    assert result["verdict"]["difference"]["delta"] == 0  # byte copies score as their originals

    # a seed trained by `replicate train-general` with the same values records the same identity: the stage keeps it
    run = folder / "runs" / "general-s4"
    assert cli("--params", str(params_file), "train-general", "--seed", "4", "--out", str(run),
               "--no-progress").wait(timeout=300) == 0
    raw["yardstick"]["seeds"] = [2, 3, 4]
    params = write(raw)
    with pytest.raises(ConfigError, match=r"seeds are \[2, 3\], yardstick.seeds \[2, 3, 4\]"):
        standing_baseline(params, folder)
    again = train_yardstick(str(params_file), str(folder), str(tmp_path / "gains.json"), 1)
    assert [r["skipped"] for r in again["runs"]] == [True, True, True] and len(standing_baseline(params, folder)) == 3

    raw["general"]["gamma"] = 0.95
    with pytest.raises(ConfigError, match="general-s2: the standing baseline was trained with other values"):
        standing_baseline(write(raw), folder)
    (folder / "summary.json").write_text("{not json")
    with pytest.raises(ConfigError, match="summary.json: not a standing baseline's summary"):
        standing_baseline(params, folder)


@pytest.mark.slow
def test_the_evaluation_suite_scores_every_cell(two_runs, tmp_path):
    """``pipeline.general.evaluate_general`` on a small suite: every lake × fleet × start × event once, the
    policy and each baseline scored, the best layout above them all, no buoy outside the water."""
    import yaml

    from replicate.compare.suite import suite_cells
    from replicate.core.sections import EVENTS
    from replicate.pipeline.general import evaluate_general
    from replicate.toolkit.export import export_general

    from ..conftest import ROOT

    out, _ = two_runs
    policies = tmp_path / "policies"  # the layout of ``train_general``: two seeds (the same weights), one kept
    for k, seed in enumerate((4, 5)):
        export_general(out / f"run{k}" / "actor.pt", policies / "runs" / f"general-s{seed}" / "policy.pt")
    runs = [{"seed": s, "policy": f"runs/general-s{s}/policy.pt"} for s in (4, 5)]
    (policies / "summary.json").write_text(json.dumps({"kept_seed": 5, "runs": runs}))
    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    raw["general"]["suite"].update(test_lakes=1, real_lakes=[], named_fleets=[5], lake_fleets=[6], starts=["random"],
                                   episodes=2)
    raw["yardstick"]["lakes"] = 1  # one design lake
    raw["regions"]["bedok"]["path"] = str(ROOT / raw["regions"]["bedok"]["path"])
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    result = evaluate_general(str(tmp_path / "params.yaml"), str(policies), str(tmp_path / "g.json"), 1)
    assert result["seeds"] == ["s5", "s4"] and result["policy"] == str(policies / "general.pt")
    cells = {(c["region"], c["n_agents"], c["event"]): c for c in result["cells"]}
    from replicate.core.params import load_params

    # 3 named, 1 design and 1 test lake
    assert len(cells) == len(suite_cells(load_params(tmp_path / "params.yaml"))) == 5 * len(EVENTS)
    assert cells[("square", 5, "lose")]["lose"] == 1 and cells[("bedok", 5, "current")]["lose"] == 0
    kinds = {c["region"]: c["kind"] for c in result["cells"]}
    assert kinds["square"] == "trained" and kinds["bedok"] == "real"
    assert sum(k == "test" for k in kinds.values()) == sum(k == "design" for k in kinds.values()) == 1
    for c in result["cells"]:
        found = {k: b["coverage"]["mean"] for k, b in c["baselines"].items()}
        bound, best = found.pop("upper_bound"), found["best_layout"]
        assert c["max_outside_m"] == 0.0 and c["coverage"]["n"] == 2
        assert c["seeds"]["s5"]["coverage"] == c["coverage"] == c["seeds"]["s4"]["coverage"]  # the same weights
        assert {"decentralised_lloyd", "planner"} <= set(found) and max(found.values()) <= best + 0.01
        assert max(best, c["coverage"]["mean"]) <= bound  # the bound holds every method and the best layout
    assert json.loads((tmp_path / "g.json").read_text())["cells"] == result["cells"]


def test_grown_horizon_trains_each_world_as_long_as_it_is_evaluated(params, tmp_path):
    """``general.grown_horizon``: a training lake larger than the paper's area plays episodes of its evaluation's T
    (``scenario.horizon``), the square at the paper's area its ``episode_length``; every step of both is stored."""
    from replicate.world.scenario import horizon

    gc = dataclasses.replace(tiny(params), lake_fleet=(15, 15), lake_ratio=(0.6, 0.6), grown_horizon=True,
                             episode_length=10, episodes=32, buffer_size=20000)
    trainer = GeneralTrainer(params, 4, tmp_path / "grown", progress=False, config=gc)
    square, lake = trainer.worlds
    long = horizon(gc, lake.region, params.world.region_area)
    assert square.steps == 10 < long == lake.steps
    assert [w.steps for w, _, _ in trainer.validation] == [10, 10, long]  # validated on the same horizons
    trainer.run()  # 4 batches of 8 environments, the worlds in turn
    assert trainer.loop.memories[0].size == 2 * 8 * 10 + 2 * 8 * long


def test_channel_world_is_the_rectangle_at_the_papers_density_trained_for_its_evaluation_horizon(params, tmp_path):
    """``general.channel_fleet``: one more world, the rectangle with that many buoys at the paper's density (its area
    N · A(Reg)/N_paper, its shape the rectangle's), whose episodes last its evaluation's T while the other worlds keep
    ``episode_length``; the baselines' gains are tuned on it too, and at 0 there is none."""
    from replicate.learn.training_worlds import baseline_worlds
    from replicate.world.scenario import horizon

    gc = dataclasses.replace(tiny(params), channel_fleet=20, episode_length=10, episodes=24, buffer_size=20000)
    trainer = GeneralTrainer(params, 4, tmp_path / "channel", progress=False, config=gc)
    square, lake, channel = trainer.worlds
    area = params.world.region_area
    assert (channel.region.name, channel.n_agents) == ("channel", 20)
    assert channel.region.polygon.area == pytest.approx(20 / params.world.n_agents * area)
    minx, miny, maxx, maxy = channel.region.polygon.bounds
    assert (maxx - minx) / (maxy - miny) == pytest.approx(9.0)  # the rectangle's 9 × 1, scaled
    long = horizon(gc, channel.region, area)
    assert square.steps == lake.steps == 10 < long == channel.steps
    assert [(w.n_agents, s, w.steps) for w, s, _ in trainer.validation][-2:] == [(20, "corner", long),
                                                                                (20, "random", long)]
    trainer.run()  # 3 batches of 8 environments, one in each world
    assert trainer.loop.memories[0].size == 2 * 8 * 10 + 8 * long
    assert [n for _, n in baseline_worlds(params, gc)][-1] == 20
    assert len(baseline_worlds(params, dataclasses.replace(gc, channel_fleet=0))) == 2


@pytest.mark.parametrize("fade", [0.0, 0.5])
def test_fine_tuning_keeps_the_policy_files_lloyd_prior(params, tmp_path, fade):
    """`replicate cover --finetune` trains a policy with a Lloyd prior as it was exported, prior included (the
    file's gain, not params.yaml's 0, and unfaded whatever params.yaml's ``lloyd_prior_fade``): with too few
    transitions to update, the kept actor is the starting one and its exported file acts as the original does."""
    import sys

    from replicate.learn.policy import load_policy
    from replicate.toolkit.cover import finetuned
    from replicate.world.regions import box_region

    from ..conftest import ROOT

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from lloyd_prior import prior_alone

    small = dataclasses.replace(params, general=dataclasses.replace(params.general, n_envs=4, learning_starts=10**6))
    policy = prior_alone(small, 10.0, tmp_path / "prior")[0]
    if fade:  # params.yaml fades a prior of its own
        gc = small.general
        small = dataclasses.replace(small, general=dataclasses.replace(
            gc, sensors=dataclasses.replace(gc.sensors, centroid=True),
            learner=dataclasses.replace(gc.learner, lloyd_prior=3.0, lloyd_prior_fade=fade)))
    module, meta = load_policy(policy)
    region = box_region("square", 3.0, 3.0)
    finetuned(policy, module, meta, small, region, 10, 4, 0, tmp_path / "tuned", False)
    again, again_meta = load_policy(tmp_path / "tuned" / "policy.pt")
    assert again_meta["lloyd_prior"]["gain_per_sim_m"] == 10.0
    obs = torch.randn(9, len(meta["observation_layout"]), generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(again(obs), module(obs))
        assert (module(obs) - torch.tanh(10.0 * obs[:, -2:])).abs().max() < 1e-6


def test_a_fading_lloyd_prior_falls_to_0_and_only_the_network_alone_is_kept(params, tmp_path):
    """``lloyd_prior_fade``: the prior's gain falls linearly to 0 over that share of the batches, in the actor and
    its target alike; validation waits until it is 0, so the kept actor, its checkpoint and its exported file steer
    by the network alone."""
    from replicate.learn.schedules import prior_gain
    from replicate.toolkit.export import export_general

    cfg = tiny(params)
    learner = dataclasses.replace(cfg.learner, lloyd_prior=10.0, lloyd_prior_fade=0.5)
    assert [prior_gain(learner, p) for p in (0.0, 0.25, 0.5, 0.9)] == [10.0, 5.0, 0.0, 0.0]
    assert learner.deployed_prior == 0.0 and cfg.learner.deployed_prior == cfg.learner.lloyd_prior
    cfg = dataclasses.replace(cfg, learner=learner, sensors=dataclasses.replace(cfg.sensors, centroid=True))
    trainer = GeneralTrainer(params, 7, tmp_path / "run", progress=False, config=cfg)
    gains, play = [], trainer.play
    trainer.play = lambda world, sigma: gains.append(trainer.agent.actor_target.prior) or play(world, sigma)
    summary = trainer.run()
    assert gains == pytest.approx([10 * 2 / 3, 10 / 3, 0, 0, 0, 0])  # a batch plays with the gain of its end
    assert trainer.agent.actor.prior == trainer.agent.actor_target.prior == 0.0
    lines = gzip.decompress((tmp_path / "run" / "curve.csv.gz").read_bytes()).decode().splitlines()
    validated = [row.split(",")[1] for row in lines[1:] if row.split(",")[-1] not in ("", "nan")]
    assert validated == ["32", "48"]  # 6 batches of 8 over 2 worlds: due after batches 2, 4, 6; gain 0 from 3 on
    assert summary["selected_episode"] in (32, 48)
    saved = torch.load(tmp_path / "run" / "actor.pt")
    assert SharedActor.from_checkpoint(saved).prior == 0.0
    assert "lloyd_prior" not in export_general(tmp_path / "run" / "actor.pt", tmp_path / "run" / "policy.pt")
