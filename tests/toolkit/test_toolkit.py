"""Beyond the paper: exported policies, animations, covering a waterbody the repo does not ship."""

from __future__ import annotations

import dataclasses
import json
import subprocess

import geopandas as gpd
import numpy as np
import pytest
import torch
from PIL import Image
from shapely.geometry import Polygon

from replicate.core.artifacts import CheckpointError
from replicate.core.params import load_params
from replicate.learn.policy import load_policy
from replicate.learn.train import load_actors
from replicate.toolkit.animate import animate_run
from replicate.toolkit.deploy import act
from replicate.toolkit.export import export_policy
from replicate.world.coverage import coverage_ceiling

from ..command import SMALL, cli, small_trainer
from ..conftest import ROOT
from .gis import check_field_files


@pytest.fixture(scope="module")
def small_run(tmp_path_factory, params, regions):
    out = tmp_path_factory.mktemp("toolkit") / "run"
    # observing velocity too (`tuned` observes position only), so that export and `act --real` scale both parts
    small_trainer(params, regions["square"], out, seed=2, episodes=30, observation="position_velocity").run()
    return out


def small_params():
    overrides = dict(s.split("=") for s in SMALL[1::2])
    return load_params(ROOT / "params.yaml", {k: int(v) for k, v in overrides.items()})


def test_exported_policy_equals_training_actor(small_run, regions, tmp_path):
    meta = export_policy(small_run / "actors.pt", regions["square"], tmp_path / "policy.pt")
    assert meta["observation_layout"] == ["x", "y", "vx", "vy"] and meta["n_agents"] == 9
    module, loaded = load_policy(tmp_path / "policy.pt")
    assert loaded == meta
    net, _ = load_actors(small_run / "actors.pt")
    obs = torch.randn(64, 9, 4)
    with torch.no_grad():
        expected = torch.tanh(net(obs.transpose(0, 1))).transpose(0, 1)
    torch.testing.assert_close(module(obs), expected, rtol=0, atol=0)
    with torch.no_grad():
        single = torch.tanh(net(obs[:1].transpose(0, 1))).transpose(0, 1)[0]
    torch.testing.assert_close(module(obs[0]), single, rtol=0, atol=0)  # one swarm observation: [N, obs_dim]
    # same shape as `single`, so the same kernels: batch-64 and batch-1 matmuls may differ in the last bit
    np.testing.assert_allclose(act(tmp_path / "policy.pt", obs[0].numpy()), single.numpy(), rtol=0, atol=1e-7)
    with pytest.raises(ValueError, match="shape"):
        act(tmp_path / "policy.pt", np.zeros((9, 2)))
    with pytest.raises(CheckpointError, match="another region"):
        export_policy(small_run / "actors.pt", regions["rectangle"], tmp_path / "wrong.pt")
    (tmp_path / "broken.pt").write_bytes(b"not a policy")
    with pytest.raises(CheckpointError, match="not a readable exported policy"):
        load_policy(tmp_path / "broken.pt")


def test_act_command_with_real_coordinates(small_run, regions, tmp_path, replicate):
    bedok_like = dataclasses.replace(regions["square"], scale=300.0, offset=(380000.0, 148000.0),
                                     utm_crs="EPSG:32648")
    export_policy(small_run / "actors.pt", bedok_like, tmp_path / "policy.pt")
    export_policy(small_run / "actors.pt", regions["square"], tmp_path / "synthetic.pt")
    with pytest.raises(ValueError, match="synthetic, with no map coordinates"):  # --real would change nothing
        act(tmp_path / "synthetic.pt", np.zeros((9, 4)), real=True)
    sim = np.random.default_rng(0).uniform(-1, 1, (9, 4))
    real = sim.copy()
    real[:, :2] = np.array([380000.0, 148000.0]) + 300.0 * sim[:, :2]
    real[:, 2:] = 300.0 * sim[:, 2:]
    (tmp_path / "obs.json").write_text(json.dumps(real.tolist()))
    code = replicate("act", "--policy", str(tmp_path / "policy.pt"), "--obs-file", str(tmp_path / "obs.json"),
                     "--real")[0]
    assert code == 0
    got = json.loads(replicate.out)
    np.testing.assert_allclose([got[f"buoy_{i}"] for i in range(9)], act(tmp_path / "policy.pt", sim), atol=1e-5)


@pytest.mark.slow
def test_act_takes_negative_numbers_and_standard_input(small_run, regions, tmp_path):
    export_policy(small_run / "actors.pt", regions["square"], tmp_path / "policy.pt")
    sim = np.random.default_rng(1).uniform(-1.5, -0.5, (9, 4))  # every value negative
    inline = ";".join(",".join(f"{v:.6f}" for v in row) for row in sim)
    proc = cli("act", "--policy", str(tmp_path / "policy.pt"), "--obs", inline, stdout=subprocess.PIPE, text=True)
    assert proc.wait(timeout=300) == 0
    piped = subprocess.run([*cli_argv(), "act", "--policy", str(tmp_path / "policy.pt"), "--obs-file", "-"],
                           input=json.dumps(np.round(sim, 6).tolist()), capture_output=True, text=True, cwd=ROOT,
                           timeout=300)
    assert piped.returncode == 0, piped.stderr
    assert json.loads(piped.stdout) == json.loads(proc.stdout.read())
    expected = act(tmp_path / "policy.pt", np.round(sim, 6))
    np.testing.assert_allclose([json.loads(piped.stdout)[f"buoy_{i}"] for i in range(9)], expected, atol=1e-5)


def cli_argv() -> list[str]:
    import sys

    return [sys.executable, "-m", "replicate"]


@pytest.mark.slow
def test_one_cli_shape_for_every_verb(small_run, tmp_path):
    """A run is a positional RUN for evaluate, export and animate; --set works before or after the verb."""
    out, observes = tmp_path / "m.json", "configs.tuned.observation=position_velocity"  # as small_run does
    assert cli("evaluate", str(small_run), "--set", observes, "--set", "evaluate.episodes=3", "--out",
               str(out)).wait(600) == 0
    assert json.loads(out.read_text())["coverage"]["n"] == 3
    assert cli("--set", observes, "evaluate", str(small_run), "--set", "evaluate.episodes=4",
               "--out", str(out), "--force").wait(600) == 0  # the first result is replaced only with --force
    assert json.loads(out.read_text())["coverage"]["n"] == 4  # both --set, before and after the verb, apply
    assert cli("export", str(small_run), "--out", str(tmp_path / "p.pt")).wait(600) == 0
    for verb in ("train", "evaluate", "cover", "animate", "tune", "init", "export", "act"):
        text = subprocess.run([*cli_argv(), verb, "--help"], capture_output=True, text=True, cwd=ROOT).stdout
        assert "--set KEY=VALUE" in text and "--params FILE" in text, verb
        if verb in ("train", "cover"):
            assert "(default: 0)" in text and "episodes" in text, verb


def test_animation_has_one_frame_per_step(small_run, regions, tmp_path):
    short = dataclasses.replace(small_params(), world=dataclasses.replace(small_params().world, episode_length=12))
    gif = animate_run(small_run, short, regions["square"], tmp_path / "episode.gif")
    with Image.open(gif) as im:
        assert im.n_frames == 12 + 1
    assert not list(tmp_path.glob(".*.gif"))


def test_animate_speaks_metres_and_minutes(small_run, regions, tmp_path, monkeypatch):
    """With the buoys' top speed (`animate --speed-ms`), Bedok's episode is drawn on its UTM map in metres and the
    title's clock is in minutes of that speed (the control period of ``world.units``): read from the last frame."""
    from replicate.toolkit import animate
    from replicate.world.units import Units

    seen = {}

    def last_frame(anim, frames, out, fps, progress):
        anim._draw_was_started = True  # read, not rendered
        anim._func(frames - 1)
        ax = anim._fig.axes[0]
        seen.update(title=ax.get_title(), x=ax.get_xlabel(), xlim=ax.get_xlim())
        return out

    monkeypatch.setattr(animate, "save_gif", last_frame)
    short = dataclasses.replace(small_params(), world=dataclasses.replace(small_params().world, episode_length=12))
    bedok = regions["bedok"]
    animate_run(small_run, short, bedok, tmp_path / "episode.gif", speed_ms=0.5)
    period = Units.of(short.world, short.coverage, 0.5 * bedok.scale, 0.5).period_s
    assert seen["x"] == f"easting (m, {bedok.utm_crs})" and seen["xlim"][0] > 1e5  # UTM eastings
    assert f"{12 * period / 60:.1f} min, coverage" in seen["title"] and "step" not in seen["title"]


@pytest.mark.slow
def test_cover_a_lake_the_repo_does_not_ship(tmp_path):
    """`replicate cover --method cr --region FILE` (CR-MARL trained on the lake) offline end to end, at real scale
    with 5 buoys of 150 m."""
    lake = Polygon([(6.56, 46.50), (6.575, 46.502), (6.58, 46.51), (6.565, 46.512), (6.555, 46.505)])
    gpd.GeoDataFrame({"name": ["test lake"]}, geometry=[lake], crs="EPSG:4326").to_file(tmp_path / "lake.geojson")
    proc = cli(*SMALL, "cover", "--method", "cr", "--region", str(tmp_path / "lake.geojson"), "--episodes", "20",
               "--n-agents", "5", "--radius-m", "150", "--speed-ms", "0.5", "--out", str(tmp_path / "out"),
               "--no-progress",
               stdout=subprocess.PIPE, text=True)
    assert proc.wait(timeout=600) == 0
    text = proc.stdout.read()
    assert "of the Lloyd layout" in text and "EPSG:32632" in text
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["n_agents"] == 5 and summary["radius_m"] == pytest.approx(150.0)
    assert summary["scale_m_per_sim_m"] == pytest.approx(300.0)
    assert summary["episode_length"] >= 50
    ceiling = coverage_ceiling(summary["area_m2"] / 300.0**2, 5, 0.5, 30)
    assert 0.15 < ceiling < 0.3  # 5 × 0.07 km² on a lake of about 1.5 km²
    assert 0.0 <= summary["coverage"]["mean"] <= ceiling + 1e-9
    assert 0.8 * ceiling < summary["lloyd_coverage"]["mean"] <= ceiling + 1e-9
    layers, episode = check_field_files(tmp_path / "out", "episode", 1e-3, walled=False)  # to 1e-4 sim m
    assert set(layers["tracks"].method) == {"CR-MARL (tuned)", "lloyd"}
    assert episode["steps"] == summary["episode_length"]  # Lloyd's converging run cut to the policy's minutes
    assert summary["top_speed_ms"] == episode["top_speed_ms"] == 0.5  # buoys of 0.5 m/s: 150 m / 0.5 m/s periods
    assert summary["control_period_s"] == pytest.approx(150 / 0.5 * 2 * np.sqrt(2) / 0.5 * 0.1)
    assert episode["methods"]["lloyd"]["coverage"] <= episode["best_layout"]["coverage"] + 1e-9
    (tmp_path / "lake.geojson").unlink()  # the run folder records its region: export needs nothing else
    export = cli("export", str(tmp_path / "out" / "run"), "--out", str(tmp_path / "lake.pt"), stderr=subprocess.PIPE,
                 text=True)
    assert export.wait(timeout=300) == 0, export.stderr.read()


def test_cover_place_offline_names_the_alternative(tmp_path, replicate):
    code, err = replicate("cover", "--place", "Bedok Reservoir, Singapore", "--out", str(tmp_path / "o"))
    assert code == 2 and "--region FILE" in err


@pytest.mark.slow
def test_every_verb_works_from_any_folder(tmp_path):
    """Outside the repository the defaults and the Bedok outline installed with the package are used."""
    train = cli(*SMALL, "train", "--config", "tuned", "--method", "cr", "--region", "bedok", "--episodes", "20",
                "--out", "X", "--no-progress", cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    assert train.wait(timeout=600) == 0, train.stderr.read()
    assert (tmp_path / "X" / "actors.pt").exists()
    lake = Polygon([(6.56, 46.50), (6.575, 46.502), (6.58, 46.51), (6.565, 46.512), (6.555, 46.505)])
    gpd.GeoDataFrame({"name": ["lake"]}, geometry=[lake], crs="EPSG:4326").to_file(tmp_path / "lake.geojson")
    cover = cli("--set", "evaluate.episodes=4", "cover", "--region", "lake.geojson", "--no-progress", cwd=tmp_path,
                stderr=subprocess.PIPE, text=True)  # the general policy installed with the package
    assert cover.wait(timeout=600) == 0, cover.stderr.read()
    summary = json.loads((tmp_path / "my-runs" / "cover" / "summary.json").read_text())  # the default --out
    assert summary["policy"].endswith("general.pt") and summary["max_outside_m"] == 0.0


def test_init_writes_the_defaults_once(tmp_path, replicate):
    assert replicate("init", str(tmp_path / "mine"))[0] == 0
    written = tmp_path / "mine" / "params.yaml"
    assert written.read_text() == (ROOT / "params.yaml").read_text()
    assert load_params(written).train.episodes == load_params(ROOT / "params.yaml").train.episodes
    code, err = replicate("init", str(tmp_path / "mine"))
    assert code == 2 and "--force" in err


def test_built_package_carries_the_defaults(tmp_path):
    """`pip install .` installs copies of params.yaml, the Bedok outline and the general policy inside the
    package."""
    import shutil
    import sys
    import zipfile

    source = tmp_path / "source"  # a copy: building in the repository would leave build/ behind
    shutil.copytree(ROOT / "src", source / "src", symlinks=True, ignore=shutil.ignore_patterns("*.egg-info"))
    for rel in ("pyproject.toml", "params.yaml", "data/bedok_outline.geojson", "policies/general.pt"):
        (source / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, source / rel)
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path), str(source)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    wheel = zipfile.ZipFile(next(tmp_path.glob("*.whl")))
    assert wheel.read("replicate/defaults/params.yaml") == (ROOT / "params.yaml").read_bytes()
    assert wheel.read("replicate/defaults/bedok_outline.geojson") == (ROOT / "data/bedok_outline.geojson").read_bytes()
    assert wheel.read("replicate/defaults/general.pt") == (ROOT / "policies/general.pt").read_bytes()


def test_ctrl_c_wrapped_by_a_library_is_still_an_interruption(monkeypatch, capsys):
    """numba re-raises a KeyboardInterrupt that lands while it loads a cached function as an error of its own;
    the CLI still answers as to Ctrl-C (exit 130 and the resume hint), and a plain error stays an error."""
    from replicate.toolkit.cli import command, export

    def wrapped(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("numba could not unpickle") from exc

    monkeypatch.setattr(export, "run", wrapped)
    assert command.main(["export", "some-run"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not command.caused_by_ctrl_c(RuntimeError("plain"))


def test_a_policy_of_local_sensors_exports_its_sensors(params, regions, tmp_path):
    """Actors trained on the local observation export with each sensor and its settings in the metadata, and
    act on the 22 columns it names."""
    small_trainer(params, regions["square"], tmp_path / "run", seed=1, episodes=20, observation="local",
                  shore="wall").run()
    meta = export_policy(tmp_path / "run" / "actors.pt", regions["square"], tmp_path / "policy.pt")
    assert len(meta["observation_layout"]) == 22 and "x" not in meta["observation_layout"]
    assert [s["sensor"] for s in meta["sensors"]] == ["own_velocity", "neighbours", "shore_distances"]
    assert meta["sensors"][0]["frame"] == "through the water (log)"  # a per-region config's default
    assert meta["sensors"][1]["k"] == 4 and meta["sensors"][2]["ray_range_m"] == 2.0
    assert sum(len(s["columns"]) for s in meta["sensors"]) == 22
    assert act(tmp_path / "policy.pt", np.zeros((9, 22))).shape == (9, 2)
