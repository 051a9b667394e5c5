"""Reading back what a mission writes for the field (``plan``, ``cover``, ``evaluate --policy``): its GeoPackage's
layers with geopandas (pyogrio), and the checks every such file must pass."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

LAYERS = {"lake", "waypoints", "tracks", "layout", "coverage"}


def opened(out: Path, stem: str = "plan") -> dict:
    """Every layer of ``out/{stem}.gpkg``, read back with geopandas (pyogrio)."""
    import geopandas as gpd
    import pyogrio

    return {name: gpd.read_file(out / f"{stem}.gpkg", layer=name, engine="pyogrio")
            for name, _ in pyogrio.list_layers(out / f"{stem}.gpkg")}


def check_field_files(out: Path, stem: str, slack: float = 1e-9, walled: bool = True, animation: bool = True
                      ) -> tuple[dict, dict]:
    """The GeoPackage holds every layer in the lake's UTM zone, every waypoint lies in the water (``walled``: the
    shore is a wall, as for the general policy and the baselines; CR-MARL's paper world has none), no buoy is
    faster over the ground than the stated top speed and the drift (within ``slack`` of it, relative), the GeoJSON
    is in lon/lat, and the map and (``animation``) the animation exist → (layers, the summary)."""
    layers = opened(out, stem)
    assert set(layers) == LAYERS
    water, points = layers["lake"].geometry.iloc[0], layers["waypoints"]
    assert points.crs == layers["lake"].crs and layers["lake"].crs.to_epsg() // 100 in (326, 327)
    assert water.buffer(1e-6).contains(points.geometry).all() or not walled
    summary = json.loads((out / f"{stem}.json").read_text())
    drift = np.hypot(*summary["current_ms"]) if summary["current_ms"] else 0.0  # over the ground: top speed + drift
    assert points.speed_ms.max() <= (summary["top_speed_ms"] + drift) * (1 + slack)
    tracks = json.loads((out / "tracks.geojson").read_text())
    lonlat = np.concatenate([f["geometry"]["coordinates"] for f in tracks["features"]])
    assert np.abs(lonlat - summary["centre_lonlat"]).max() < 0.5  # degrees, around the lake's centre
    assert (out / f"{stem}.png").stat().st_size > 0 and (out / f"{stem}.gif").exists() == animation
    return layers, summary
