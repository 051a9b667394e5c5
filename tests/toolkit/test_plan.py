"""``replicate plan``: a deployment in metres and seconds, written as files a GIS opens."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ..conftest import ROOT
from .gis import check_field_files

LAKES = ROOT / "data" / "lakes"


@pytest.mark.parametrize("lake", ["lake_karaguz", "mae_kuang_reservoir", "lake_silach"])
def test_a_plan_on_each_real_lake_stays_in_the_water_below_top_speed(replicate, tmp_path, lake):
    """9 buoys of 25 m at 1.0 m/s, the whole default mission: the GeoPackage opens, every waypoint lies in the
    water (the lake layer, in its UTM zone), no buoy exceeds 1.0 m/s over any control period, the clock advances
    by the stated control period, and the summary's times and coverages are those of its waypoints."""
    out = tmp_path / "plan"
    code, err = replicate("plan", "--region", str(LAKES / f"{lake}.geojson"), "--buoys", "9", "--radius-m", "25",
                          "--speed-ms", "1.0", "--out", str(out))
    assert code == 0, err
    layers, summary = check_field_files(out, "plan")
    points = layers["waypoints"]
    assert layers["lake"].crs.to_epsg() in (32641, 32647)
    assert points.speed_ms.max() <= 1.0 + 1e-9 and summary["top_speed_ms"] == pytest.approx(1.0)
    assert points.speed_ms.max() > 0.5  # and they moved
    period = summary["control_period_s"]
    assert period == pytest.approx(25 / 0.5 * 2 * np.sqrt(2) * 0.1)  # 14.14 s: the similarity transform's
    for (_, _), group in points.groupby(["method", "buoy"]):
        assert np.allclose(np.diff(group.sort_values("step").time_s), period)
    assert len(points) == 4 * 9 * (summary["steps"] + 1)  # the policy, tuned and decentralised Lloyd, the planner
    for method, m in summary["methods"].items():
        assert 0 < m["seconds_to_90pct"] <= m["seconds_to_95pct"] <= summary["mission_s"]
        assert m["coverage"] <= summary["best_layout"]["coverage"] * (1 + 1e-6)  # the limit holds
        assert (layers["layout"].method == method).sum() == 9
    assert "OpenStreetMap" in summary["attribution"]
    assert "covers" in replicate.out and "best layout" in replicate.out


def test_the_geojson_is_in_lon_lat_and_the_csv_has_both_coordinates(replicate, tmp_path):
    """A short mission from a launch point: GeoJSON in WGS84 around the lake, the CSV's lon/lat and UTM columns
    describe the same points, and every buoy starts within the launch patch."""
    import geopandas as gpd
    import pandas as pd
    from pyproj import Transformer

    out, launch = tmp_path / "plan", (60.8794, 56.1033)  # lon, lat: a point on Lake Karaguz
    code, err = replicate("plan", "--region", str(LAKES / "lake_karaguz.geojson"), "--buoys", "5", "--radius-m",
                          "40", "--speed-ms", "0.8", "--launch", f"{launch[0]},{launch[1]}", "--duration-min", "10",
                          "--out", str(out))
    assert code == 0, err
    tracks = gpd.read_file(out / "tracks.geojson")
    assert tracks.crs.to_epsg() == 4326 and len(tracks) == 4 * 5  # the policy, two Lloyds, the planner
    lon, lat = tracks.geometry.get_coordinates().mean()
    assert abs(lon - launch[0]) < 0.1 and abs(lat - launch[1]) < 0.1
    table = pd.read_csv(out / "waypoints.csv")
    assert list(table.columns) == ["method", "buoy", "step", "time_s", "lon", "lat", "x_utm", "y_utm", "speed_ms"]
    x, y = Transformer.from_crs("EPSG:4326", "EPSG:32641", always_xy=True).transform(table.lon, table.lat)
    assert np.abs(x - table.x_utm).max() < 0.05 and np.abs(y - table.y_utm).max() < 0.05
    lx, ly = Transformer.from_crs("EPSG:4326", "EPSG:32641", always_xy=True).transform(*launch)
    first = table[table.step == 0]
    assert np.hypot(first.x_utm - lx, first.y_utm - ly).max() <= 40 / 2 * np.sqrt(2) + 0.01  # the patch: side R
    summary = json.loads((out / "plan.json").read_text())
    assert summary["mission_s"] >= 600 and summary["mission_s"] - 600 < summary["control_period_s"]
    assert summary["centre_lonlat"] == pytest.approx([60.879, 56.103], abs=0.01)  # where a user checks the lake is
    assert "centred at 60.87" in replicate.out
    assert table.speed_ms.max() <= 0.8 + 1e-9
    from PIL import Image

    with Image.open(out / "plan.gif") as gif:  # the animation: one frame per control period of a short mission
        assert gif.n_frames == min(100, summary["steps"] + 1) and gif.n_frames > 10


@pytest.mark.parametrize(("argv", "message"), [
    (["--launch", "0,0"], "outside lake_karaguz's water"),
    (["--launch", "56.1033,60.8794"], "lies"),  # swapped: latitude first lands far from the lake
    (["--launch", "60.67,96"], "latitude in [-90, 90] degrees"),
    (["--current-ms", "1.5,0"], "at least the buoys' top speed"),
    (["--speed-ms", "0"], "--speed-ms must be a positive number"),
    (["--buoys", "1"], "--buoys must be from 2"),
    (["--duration-min", "100000"], "give a shorter mission"),
])
def test_bad_missions_are_refused_by_name(replicate, tmp_path, argv, message):
    out = tmp_path / "plan"
    code, err = replicate("plan", "--region", str(LAKES / "lake_karaguz.geojson"), "--buoys", "9", "--radius-m", "25",
                          "--out", str(out), *argv)
    assert code == 2 and message in err, err
    assert not out.exists()  # nothing half-written


def test_evaluate_keeps_a_lake_in_metres_and_states_its_units(replicate, tmp_path):
    """``evaluate --policy --radius-m --speed-ms --current-ms``: the lake in metres, the drift converted, and the
    output's control period and mission in seconds (one fleet, few episodes: the arithmetic, not the score)."""
    out = tmp_path / "e.json"
    code, err = replicate("--set", "evaluate.episodes=4", "evaluate", "--policy", "src/replicate/defaults/general.pt",
                          "--region", str(LAKES / "lake_karaguz.geojson"), "--n-agents", "12", "--radius-m", "300",
                          "--speed-ms", "0.5", "--current-ms", "0.1,0", "--out", str(out))
    assert code == 0, err
    result = json.loads(out.read_text())
    si = result["si"]
    assert si["radius_m"] == pytest.approx(300) and si["top_speed_ms"] == pytest.approx(0.5)
    assert si["control_period_s"] == pytest.approx(300 / 0.5 * 2 * np.sqrt(2) / 0.5 * 0.1)
    assert si["mission_s"] == pytest.approx(result["steps"] * si["control_period_s"])
    assert result["current"][0] == pytest.approx(0.1 / 0.5 * 2 * np.sqrt(2))  # 20 % of top speed
    layers, episode = check_field_files(tmp_path / "e-episode", "episode", animation=False)  # its first episode
    assert episode["steps"] == result["steps"] and episode["current_ms"] == pytest.approx([0.1, 0.0])
    assert episode["top_speed_ms"] == pytest.approx(0.5) and len(layers["layout"]) == 12 * 4  # + the planner
    assert result["field_files"][0] == str(tmp_path / "e-episode" / "episode.gpkg")
    code, err = replicate("evaluate", "--policy", "src/replicate/defaults/general.pt", "--region", "square",
                          "--radius-m", "300", "--out", str(tmp_path / "f.json"))
    assert code == 2 and "not a file" in err
