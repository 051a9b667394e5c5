"""What a field team loads: a plan's lake, tracks and layouts (or those of one episode of ``cover`` and ``evaluate
--policy``) as a GeoPackage (in the lake's UTM zone), GeoJSON (in lon/lat, WGS84), a CSV of every buoy's waypoints,
and its summary as JSON; all in metres, seconds and degrees; beside them the map (PNG) and the animation (GIF).

``plan.gpkg`` layers (CRS: the lake's UTM zone):

* ``lake``: the water, with its name, area and the outline's attribution;
* ``waypoints``: one point per method, buoy and control period (``time_s`` since launch, ``speed_ms`` over the
  ground in the period before it), what QGIS's temporal controller animates;
* ``tracks``: one line per method and buoy, with its length and top speed;
* ``layout``: where each buoy ends, per method, and the best layout found offline (``method = best_layout``);
* ``coverage``: each buoy's sensing polygon at the end (radius ``radius_m``), per method.

``tracks.geojson`` and ``layout.geojson`` hold the same lines and end points in lon/lat; ``waypoints.csv`` the
waypoints with both coordinates (``time_s, lon, lat, x_utm, y_utm, speed_ms``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from replicate.core import artifacts
from replicate.toolkit.plan import Plan, summary
from replicate.world.geometry import coverage_polygons

WGS84 = "EPSG:4326"
BEST = "best_layout"


def waypoint_table(p: Plan):
    """Every method's buoys at every control period → a GeoDataFrame of points (UTM)."""
    import geopandas as gpd

    rows = []
    period, u = p.units.period_s, p.units
    for track in p.tracks:
        xy = p.region.to_map(track.positions)  # [T + 1, N, 2] UTM metres
        speed = np.vstack([np.zeros((1, xy.shape[1])), u.speed_ms(track.speeds(p.params.world.dt))])
        for buoy in range(xy.shape[1]):
            for t in range(xy.shape[0]):
                rows.append((track.method, f"buoy_{buoy}", t, t * period, float(speed[t, buoy]), *xy[t, buoy]))
    frame = gpd.GeoDataFrame(
        rows, columns=["method", "buoy", "step", "time_s", "speed_ms", "x_utm", "y_utm"],
        geometry=gpd.points_from_xy([r[5] for r in rows], [r[6] for r in rows]), crs=p.region.utm_crs)
    lonlat = frame.geometry.to_crs(WGS84)
    return frame.assign(lon=lonlat.x, lat=lonlat.y)


def layers(p: Plan) -> dict:
    """The GeoPackage's layers (module docstring), in the lake's UTM zone."""
    import geopandas as gpd
    from shapely.geometry import LineString, Point

    crs, radius = p.region.utm_crs, p.params.coverage.radius
    lake = gpd.GeoDataFrame({"name": [p.region.name], "area_m2": [p.region.area * p.region.scale**2],
                             "attribution": [p.region.attribution]}, geometry=[p.region.map_polygon()], crs=crs)
    waypoints = waypoint_table(p)
    lines, ends, discs = [], [], []
    for track in p.tracks:
        xy = p.region.to_map(track.positions)
        for buoy in range(xy.shape[1]):
            path = LineString(xy[:, buoy])  # a mission lasts at least one control period: two points
            top = waypoints[(waypoints.method == track.method) & (waypoints.buoy == f"buoy_{buoy}")].speed_ms.max()
            lines.append((track.method, f"buoy_{buoy}", path.length, float(top), path))
            ends.append((track.method, f"buoy_{buoy}", float(track.coverage[-1]), Point(xy[-1, buoy])))
        for buoy, disc in enumerate(coverage_polygons(xy[-1], radius * p.region.scale, p.params.coverage.edges)):
            discs.append((track.method, f"buoy_{buoy}", disc))
    best = p.region.to_map(p.best_xy)
    ends += [(BEST, f"buoy_{i}", p.best_coverage, Point(best[i])) for i in range(len(best))]
    return {
        "lake": lake,
        "waypoints": waypoints,
        "tracks": gpd.GeoDataFrame(lines, columns=["method", "buoy", "length_m", "max_speed_ms", "geometry"], crs=crs),
        "layout": gpd.GeoDataFrame(ends, columns=["method", "buoy", "coverage", "geometry"], crs=crs),
        "coverage": gpd.GeoDataFrame(discs, columns=["method", "buoy", "geometry"], crs=crs),
    }


def write_field_outputs(p: Plan, out: Path, stem: str = "plan") -> list[Path]:
    """Write the plan's files into ``out`` (each atomically, mode 0644): ``{stem}.gpkg``, ``tracks.geojson``,
    ``layout.geojson``, ``waypoints.csv`` and ``{stem}.json`` → their paths."""
    frames = layers(p)
    written = [out / f"{stem}.gpkg", out / "tracks.geojson", out / "layout.geojson", out / "waypoints.csv",
               out / f"{stem}.json"]
    with artifacts.atomic_path(written[0]) as tmp:
        for name, frame in frames.items():
            frame.to_file(tmp, layer=name, driver="GPKG", engine="pyogrio")
    for name, path in (("tracks", written[1]), ("layout", written[2])):
        artifacts.atomic_write_text(path, frames[name].to_crs(WGS84).to_json(drop_id=True))
    w = frames["waypoints"]
    artifacts.write_csv(written[3], ["method", "buoy", "step", "time_s", "lon", "lat", "x_utm", "y_utm", "speed_ms"],
                        ((m, b, s, f"{t:.3f}", f"{lon:.7f}", f"{lat:.7f}", f"{x:.2f}", f"{y:.2f}", f"{v:.4f}")
                         for m, b, s, t, lon, lat, x, y, v in zip(w.method, w.buoy, w.step, w.time_s, w.lon, w.lat,
                                                                  w.x_utm, w.y_utm, w.speed_ms, strict=True)))
    artifacts.write_json(written[4], summary(p))
    return written


def write_mission(p: Plan, out: Path, stem: str = "plan", progress: bool = False, animation: bool = True
                  ) -> list[Path]:
    """Everything a mission leaves for the field: ``write_field_outputs``, the map ``{stem}.png`` (UTM metres,
    scale bar, attribution) and (``animation``) the animated ``{stem}.gif`` → their paths."""
    from replicate.toolkit.plan_map import plan_animation, plan_map

    written = write_field_outputs(p, out, stem)
    written.append(plan_map(p, out / f"{stem}.png"))
    if animation:
        written.append(plan_animation(p, out / f"{stem}.gif", progress=progress))
    return written
