"""Bad inputs get one clear line naming the input and the fix, exit 2, and leave nothing behind."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import geopandas as gpd
import pytest
from shapely.geometry import Polygon

from replicate.core.artifacts import CheckpointError
from replicate.toolkit.cli import main as cli_main

TRAIN = ["train", "--config", "tuned", "--method", "cr", "--region", "square", "--episodes", "50", "--no-progress"]


def run(capsys, *argv) -> tuple[int, str]:
    code = cli_main(list(argv))
    return code, capsys.readouterr().err


@pytest.mark.parametrize("key, value, message", [
    ("configs.tuned.maddpg.batch_size", 0, "batch_size must be at least 1"),
    ("configs.tuned.maddpg.hidden", 0, "hidden must be at least 1"),
    ("configs.tuned.maddpg.buffer_size", 0, "buffer_size must be at least 1"),
    ("configs.tuned.maddpg.update_every", 0, "update_every must be above 0"),
    ("configs.tuned.maddpg.gamma", 2, r"gamma must be in (0, 1]"),
    ("configs.tuned.maddpg.tau", 2, r"tau must be in (0, 1]"),
    ("configs.tuned.maddpg.actor_lr", -1, "actor_lr must be above 0"),
    ("configs.tuned.maddpg.learning_starts", -5, "learning_starts must be at least 0"),
    ("configs.tuned.maddpg.noise_start", -1, "noise_start must be at least 0"),
    ("configs.tuned.select_every", -1, "select_every must be at least 0"),
    ("configs.tuned.select_episodes", 0, "select_episodes must be at least 1"),
    ("configs.tuned.reward_scale", 0, "reward_scale must be above 0"),
    ("coverage.raster_spacing", 5, r"raster_spacing must be in (0, 0.25]"),
    ("evaluate.episodes", 0, "evaluate.episodes must be at least 1"),
    ("world.n_agents", "abc", "--set world.n_agents=abc: world.n_agents: expected an integer"),
])
def test_out_of_range_values_are_refused_before_anything_is_written(capsys, tmp_path, key, value, message):
    code, err = run(capsys, *TRAIN, "--set", f"{key}={value}", "--out", str(tmp_path / "run"))
    assert code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_a_folder_that_is_not_a_run_is_named(capsys, tmp_path):
    (tmp_path / "empty").mkdir()
    code, err = run(capsys, "evaluate", str(tmp_path / "empty"))
    assert code == 2 and "not a run folder (no run.json); give a folder that `replicate train` wrote" in err
    (tmp_path / "damaged").mkdir()
    (tmp_path / "damaged" / "run.json").write_text("{}")
    code, err = run(capsys, "export", str(tmp_path / "damaged"))
    assert code == 2 and "not a run's record (no region)" in err
    (tmp_path / "damaged" / "run.json").write_text("not json")
    code, err = run(capsys, "animate", str(tmp_path / "damaged"))
    assert code == 2 and "not a readable run record" in err


@pytest.mark.parametrize("verb", ["evaluate", "export", "animate"])
def test_out_files_are_checked_before_the_work(capsys, tmp_path, verb):
    """An --out that is a folder, or a file already there (without --force), is refused at once."""

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "run.json").write_text(json.dumps({"region": "square"}))
    (tmp_path / "folder").mkdir()
    (tmp_path / "done.txt").write_text("a result")
    code, err = run(capsys, verb, str(run_dir), "--out", str(tmp_path / "folder"))
    assert code == 2 and "is a folder; give the path of a file" in err
    code, err = run(capsys, verb, str(run_dir), "--out", str(tmp_path / "done.txt"))
    assert code == 2 and "exists; pass --force to replace it" in err
    assert (tmp_path / "done.txt").read_text() == "a result"
    os.mkfifo(tmp_path / "pipe")  # a pipe (or /dev/null) is not replaced by a file, even with --force
    code, err = run(capsys, verb, str(run_dir), "--out", str(tmp_path / "pipe"), "--force")
    assert code == 2 and "not a regular file (a device or a pipe)" in err
    assert stat.S_ISFIFO((tmp_path / "pipe").stat().st_mode)


def test_a_missing_observation_file_is_named(capsys, tmp_path):
    code, err = run(capsys, "act", "--policy", str(tmp_path / "p.pt"), "--obs-file", str(tmp_path / "nosuch.json"))
    assert code == 2 and "--obs-file" in err and "no such file" in err


def test_outline_files_with_nan_vertices_or_an_unknown_crs_are_named(capsys, tmp_path):
    nan = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, "geometry": {
        "type": "Polygon", "coordinates": [[[103.9, 1.33], [103.91, 1.33], [float("nan"), 1.34], [103.9, 1.33]]]}}]}
    (tmp_path / "nan.geojson").write_text(json.dumps(nan))
    code, err = run(capsys, *TRAIN[:-5], "--region", str(tmp_path / "nan.geojson"), "--out", str(tmp_path / "a"))
    assert code == 2 and "coordinates that are not numbers" in err and not (tmp_path / "a").exists()
    square = Polygon([(380000, 150000), (380400, 150000), (380400, 150300), (380000, 150300)])
    doc = json.loads(gpd.GeoSeries([square]).to_json())
    doc["crs"] = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::999999"}}
    (tmp_path / "badcrs.geojson").write_text(json.dumps(doc))
    code, err = run(capsys, *TRAIN[:-5], "--region", str(tmp_path / "badcrs.geojson"), "--out", str(tmp_path / "b"))
    assert code == 2 and "declares the CRS 'urn:ogc:def:crs:EPSG::999999'" in err


@pytest.mark.parametrize("argv, message", [
    (["evaluate", "--policy", "nowhere.pt", "--region", "square"], "--policy nowhere.pt: no such file"),
    (["evaluate", "--n-agents", "20", "--baseline", "lloyd", "--region", "square"],
     "--n-agents: options of a general policy; give --policy FILE"),
    (["evaluate", "--policy", "actor.pt", "--region", "square"], "export it first"),
    (["evaluate", "--policy", "actor.pt"], "--policy needs --region"),
    (["train-general", "--out", "g", "--episodes", "3"], "--episodes must be at least general.n_envs"),
    (["train-general", "--out", "g", "--set", "general.regions=[pond]"], "general.regions: unknown region(s)"),
    (["export", "general", "--baseline-gains", "nowhere.json"],
     "--baseline-gains nowhere.json: no such file; `replicate tune general-baselines` writes it"),
    (["export", "general", "--baseline-gains", "actor.pt"], "--baseline-gains actor.pt: not the general baselines'"),
    (["export", "general", "--baseline-gains", "partial.json"],
     "--baseline-gains partial.json: not the general baselines' gains (lloyd_tuned.gains: missing key 'damping'"),
    (["export", "general", "--lloyd-prior", "-1"], "--lloyd-prior is a gain per simulation metre, 0 or above"),
    (["export", "run", "--lloyd-prior", "3"], "--baseline-gains and --lloyd-prior go with a general run"),
    (["export", "general", "--lloyd-prior", "inf"], "--lloyd-prior is a gain per simulation metre, 0 or above"),
    (["export", "general", "--lloyd-prior", "3"], "--lloyd-prior writes another policy than the run's own"),
    (["export", "--policy", "actor.pt", "--radius-m", "1", "--speed-ms", "1", "--out", "o.pt", "--lloyd-prior", "3"],
     "give no run folder, --region, --baseline-gains or --lloyd-prior with it"),
    (["tune", "general-baselines", "--set", "tuning.general_baselines.starts=0"],
     "tuning.general_baselines.starts must be at least 1"),
    (["tune", "general-baselines", "--set", "evaluate.geodesic.spacing=0"],
     "evaluate.geodesic.spacing must be above 0, got 0"),
    (["cover", "--region", "square"], "a named region such as 'square' goes with `replicate evaluate --policy`"),
    (["cover", "--region", "lake.geojson", "--episodes", "100"], "--episodes goes with --method cr"),
    (["cover", "--region", "lake.geojson", "--policy", "nowhere.pt"], "--policy nowhere.pt: no such file"),
    (["cover", "--region", "lake.geojson", "--finetune", "-5"], "--finetune must be 0 (zero-shot)"),
    (["cover", "--region", "lake.geojson", "--method", "cr", "--finetune", "64"],
     "--policy and --finetune go with --method general"),
    (["cover", "--region", "lake.geojson", "--policy", "actor.pt"], "export it first"),
    (["cover", "--region", "lake.geojson", "--finetune", "5"], "--finetune must be 0 (zero-shot) or at least"),
    (["cover", "--region", "lake.geojson", "--config", "paper"], "--config goes with --method cr"),
    (["compare", "--candidate", "actor.pt", "--out", "c.json"],  # against the standing baseline beside params.yaml
     "--candidate: give the policies of at least 8 training seeds"),
])
def test_general_policy_inputs_are_refused_by_name(capsys, tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "actor.pt").write_bytes(b"x")
    (tmp_path / "partial.json").write_text('{"naive_tuned": {"gains": {"attraction": 1, "avoid_range": 1, '
                                           '"avoidance": 1, "damping": 0}}, "lloyd_tuned": {"gains": {"gain": 2}}}')
    (tmp_path / "general").mkdir()
    (tmp_path / "general" / "actor.pt").write_bytes(b"x")  # a general run's folder, as export tells them apart
    params = str(Path(__file__).resolve().parents[2] / "params.yaml")
    code, err = run(capsys, "--params", params, *argv)
    assert code == 2 and message in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["actor.pt", "general", "partial.json"], "nothing written"
    assert sorted(p.name for p in (tmp_path / "general").iterdir()) == ["actor.pt"]


@pytest.mark.parametrize("argv, message", [
    (["cover", "--region", "lake.csv", "--out", "o"], "lake.csv: holds a table without geometries"),
    (["cover", "--region", "data/bedok_outline.geojson", "--radius-m", "0.01", "--out", "o"],
     "crossing it takes 760700 steps (at most 5000); give a radius of at least 0.123 m"),
    (["cover", "--region", "data/bedok_outline.geojson", "--radius-m", "1e12", "--out", "o"],
     "--radius-m 1e+12: one buoy's coverage is wider than the whole lake (8.333e+05 m²"),
    (["--set", "coverage.table_spacing=1e-9", "train", "--episodes", "50", "--out", "o"],
     "its grid at coverage.table_spacing = 1e-09 would hold"),
    (["--set", "tuning.baselines.storage=notaurl", "tune", "baselines", "--out", "o.json"],
     "tuning.baselines.storage must be an SQLAlchemy URL"),
])
def test_inputs_that_once_raised_or_ran_out_of_memory_are_named(capsys, tmp_path, monkeypatch, argv, message):
    """A table without geometries, a lake thousands of coverage radii across, a grid of 1e-9 m, a study storage
    that is not a URL: each refused by name before anything is allocated or written (exit 2)."""
    root = Path(__file__).resolve().parents[2]
    (tmp_path / "lake.csv").write_text("x,y\n0,0\n1,0\n1,1\n")
    (tmp_path / "data").symlink_to(root / "data")
    monkeypatch.chdir(tmp_path)
    code, err = run(capsys, "--params", str(root / "params.yaml"), *argv)
    assert code == 2 and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "lake.csv"], "nothing written"


def test_silent_wrong_results_are_refused(capsys, tmp_path, monkeypatch):
    """An unknown declared CRS (read as WGS 84 before), a damaged policy file (it loaded and ran), a drift faster
    than a buoy, a damaged run record: each named, exit 2; a 3-D outline is read as its 2-D shadow."""
    from replicate.learn.policy import load_policy
    from replicate.toolkit.export import export_general
    from replicate.world.regions import RegionError, region_from_file

    root = Path(__file__).resolve().parents[2]
    square = [[0, 0], [0.9, 0], [0.9, 0.9], [0, 0.9], [0, 0]]
    unknown = {"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": "EPSG:99999"}},
               "features": [{"type": "Feature", "properties": {}, "geometry": {"type": "Polygon",
                                                                                "coordinates": [square]}}]}
    (tmp_path / "unknown.geojson").write_text(json.dumps(unknown))
    with pytest.raises(RegionError, match="declares the CRS 'EPSG:99999', which is not a known CRS"):
        region_from_file(tmp_path / "unknown.geojson")
    lifted = [[103.92 + x / 100, 1.34 + y / 100, 7.5] for x, y in square]
    (tmp_path / "heights.geojson").write_text(json.dumps({**unknown, "crs": None, "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [lifted]}}]}))
    assert region_from_file(tmp_path / "heights.geojson").area == pytest.approx(9.0)

    export_general(root / "policies" / "runs" / "general-s10" / "actor.pt", tmp_path / "p.pt")
    data = bytearray((tmp_path / "p.pt").read_bytes())
    at = data.index(b"archive/data/0") + 64  # inside the first tensor's bytes
    data[at:at + 256] = bytes(b ^ 0xFF for b in data[at:at + 256])
    (tmp_path / "damaged.pt").write_bytes(bytes(data))
    load_policy(tmp_path / "p.pt")
    with pytest.raises(CheckpointError, match="damaged: its weights or metadata are not the ones exported"):
        load_policy(tmp_path / "damaged.pt")

    monkeypatch.chdir(root)
    code, err = run(capsys, "evaluate", "--policy", str(tmp_path / "p.pt"), "--region", "square", "--current",
                    "1e9,0", "--out", str(tmp_path / "c.json"))
    assert code == 2 and "the buoys would be swept off" in err and not (tmp_path / "c.json").exists()
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").write_text("{not json")
    code, err = run(capsys, "train", "--out", str(tmp_path / "run"))
    assert code == 2 and "run.json: not a readable run record" in err


def test_a_projected_file_with_x_and_y_swapped_is_refused_and_an_unchecked_policy_is_said(tmp_path):
    """Eastings and northings swapped in a UTM file land thousands of kilometres off the zone: refused with
    where they land. A policy exported before policies carried a checksum is read with a note saying so."""
    import io
    import warnings

    import geopandas as gpd
    import shapely
    import torch

    from replicate.learn.policy import load_policy
    from replicate.world.regions import RegionError, region_from_file

    root = Path(__file__).resolve().parents[2]
    utm = gpd.read_file(root / "data" / "lakes" / "lake_karaguz.geojson").to_crs(32641)
    utm.to_file(tmp_path / "utm.geojson")
    assert region_from_file(tmp_path / "utm.geojson").utm_crs == "EPSG:32641"
    utm.set_geometry(shapely.transform(utm.geometry.values, lambda xy: xy[:, ::-1])).to_file(tmp_path / "swap.geojson")
    with pytest.raises(RegionError, match=r"land at 108.*outside where EPSG:32641 is used .*are x and y swapped"):
        region_from_file(tmp_path / "swap.geojson")
    pond = shapely.Point(0, 0).buffer(0.01)  # national CRSs, one across the 180th meridian, one past its zone
    for crs, lon, lat in (("EPSG:4269", -89.4, 43.1), ("EPSG:3338", -150, 62), ("EPSG:25833", 25.5, 70.0),
                          ("EPSG:3460", 178.4, -17.8)):
        gpd.GeoDataFrame(geometry=[shapely.affinity.translate(pond, lon, lat)], crs="EPSG:4326").to_crs(crs).to_file(
            tmp_path / "national.geojson")
        assert region_from_file(tmp_path / "national.geojson").centre_lonlat()[0] == pytest.approx(lon, abs=0.01)

    module, meta = load_policy(root / "policies" / "general.pt")
    meta.pop("checksum")
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.jit.save(module, buf, _extra_files={"metadata.json": json.dumps(meta)})
    (tmp_path / "old.pt").write_bytes(buf.getvalue())
    with pytest.warns(UserWarning, match="old.pt: carries no checksum .* export it again"):
        load_policy(tmp_path / "old.pt")
