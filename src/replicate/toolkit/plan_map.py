"""A deployment plan's picture (``replicate plan``): the lake on its UTM map with a scale bar and the outline's
attribution, the general policy's tracks and final sensing polygons, tuned Lloyd's end points and the best layout;
beside it, each method's coverage against the mission's minutes."""

from __future__ import annotations

from pathlib import Path

import matplotlib.ticker
import numpy as np

from replicate.toolkit.plan import Plan, summary
from replicate.toolkit.plots import AGENT_COLOURS, draw_polygon, draw_region, plt, save
from replicate.world.geometry import coverage_polygons

MARKERS = ("s", "^", "D")  # the rivals' end points: tuned Lloyd, decentralised Lloyd


def scale_bar(ax, width_m: float) -> None:
    """A scale bar at the lower left of a map in metres: 1, 2 or 5 × 10^k m, about a fifth of ``width_m``."""
    target = width_m / 5
    base = 10 ** np.floor(np.log10(target))
    length = max(m * base for m in (1, 2, 5) if m * base <= target)
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    x, y = x0 + 0.05 * (x1 - x0), y0 + 0.05 * (y1 - y0)
    ax.plot([x, x + length], [y, y], color="k", linewidth=3, solid_capstyle="butt")
    ax.text(x + length / 2, y + 0.015 * (y1 - y0), f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m",
            ha="center", va="bottom", fontsize=8)


def plan_map(p: Plan, path) -> Path:
    """A deployment plan (``toolkit.plan.Plan``) on its map in UTM metres, with a scale bar and the outline's
    attribution: the general policy's tracks and final sensing polygons, tuned Lloyd's end points, the best
    layout; beside it, each method's coverage against the mission's minutes."""
    s, region = summary(p), p.region
    fig, (ax, cx) = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [1.3, 1]})
    draw_region(ax, region.map_polygon())
    policy, *rivals = p.tracks
    xy = region.to_map(policy.positions)
    for k in range(xy.shape[1]):
        ax.plot(xy[:, k, 0], xy[:, k, 1], color=AGENT_COLOURS[k % 10], linewidth=0.8, alpha=0.7)
    for k, c in enumerate(coverage_polygons(xy[-1], s["radius_m"], p.params.coverage.edges)):
        draw_polygon(ax, c, facecolor=AGENT_COLOURS[k % 10], alpha=0.35, edgecolor=AGENT_COLOURS[k % 10])
    for rival, marker in zip(rivals, MARKERS, strict=False):
        end = region.to_map(rival.positions[-1])
        ax.plot(end[:, 0], end[:, 1], marker, mfc="none", mec="k", ms=5, label=f"{rival.method}: end")
    best = region.to_map(p.best_xy)
    ax.plot(best[:, 0], best[:, 1], "x", color="#b2182b", ms=6, label="best layout")
    ax.plot(xy[0, :, 0], xy[0, :, 1], "k+", ms=5, label="launch")
    ax.set_xlabel(f"easting (m, {region.utm_crs})")
    ax.set_ylabel("northing (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
    ax.legend(loc="upper right", fontsize=7)
    minx, _, maxx, _ = region.map_polygon().bounds
    scale_bar(ax, maxx - minx)
    minutes = np.arange(p.steps + 1) * s["control_period_s"] / 60
    for track in p.tracks:
        cx.plot(minutes, track.coverage, label=track.method)
    cx.axhline(p.best_coverage, color="#b2182b", linestyle="--", linewidth=1, label="best layout (limit)")
    cx.set_xlabel("time since launch (min)")
    cx.set_ylabel("share of the lake covered")
    cx.legend(fontsize=8)
    cx.grid(alpha=0.3)
    fig.suptitle(f"{region.name}: {s['buoys']} buoys of {s['radius_m']:.4g} m at {s['top_speed_ms']:g} m/s, "
                 f"control period {s['control_period_s']:.3g} s", fontsize=11)
    fig.text(0.01, -0.02, f"Outline: {region.attribution or region.source}", fontsize=7)
    return save(fig, path)


def plan_animation(p: Plan, path, frames: int = 100, fps: int = 10, progress: bool = False) -> Path:
    """The plan as an animated GIF on its UTM map: the general policy's buoys with their sensing polygons and tuned
    Lloyd's (squares), a clock in minutes, and both coverages growing beside the best layout; at most ``frames``
    frames, evenly spaced over the mission."""
    from matplotlib.animation import FuncAnimation
    from matplotlib.patches import Polygon as MplPolygon

    from replicate.toolkit.animate import save_gif

    s, region = summary(p), p.region
    policy, *rivals = p.tracks
    xy, rival_xy = region.to_map(policy.positions), [region.to_map(r.positions) for r in rivals]
    minutes = np.arange(p.steps + 1) * s["control_period_s"] / 60
    shown = np.unique(np.linspace(0, p.steps, min(frames, p.steps + 1)).round().astype(int))
    fig, (ax, cx) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1.3, 1]})
    draw_region(ax, region.map_polygon())
    ax.set_xlabel(f"easting (m, {region.utm_crs})")
    ax.set_ylabel("northing (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
    colours = [AGENT_COLOURS[k % 10] for k in range(xy.shape[1])]
    discs = [ax.add_patch(MplPolygon(np.zeros((1, 2)), closed=True, facecolor=c, alpha=0.4, edgecolor=c))
             for c in colours]
    minx, miny, maxx, maxy = region.map_polygon().bounds
    pad = s["radius_m"] + 0.03 * max(maxx - minx, maxy - miny)  # the lake, not the empty patches at the origin
    ax.set_xlim(minx - pad, maxx + pad)
    ax.set_ylim(miny - pad, maxy + pad)
    scale_bar(ax, maxx - minx)
    (buoys,) = ax.plot([], [], "k.", ms=4, label="general policy")
    others = [ax.plot([], [], marker, mfc="none", mec="0.3", ms=4, label=r.method)[0]
              for r, marker in zip(rivals, MARKERS, strict=False)]
    ax.legend(loc="upper right", fontsize=7)
    clock = ax.set_title("", fontsize=10)
    cx.axhline(p.best_coverage, color="#b2182b", linestyle="--", linewidth=1, label="best layout (limit)")
    curves = [cx.plot([], [], label=t.method)[0] for t in p.tracks]
    cx.set_xlim(0, minutes[-1] if minutes[-1] > 0 else 1)
    cx.set_ylim(0, 1.1 * max(p.best_coverage, *(t.coverage.max() for t in p.tracks)))
    cx.set_xlabel("time since launch (min)")
    cx.set_ylabel("share of the lake covered")
    cx.legend(fontsize=8, loc="lower right")
    fig.text(0.01, 0.0, f"Outline: {region.attribution or region.source}", fontsize=7)

    def frame(i: int):
        t = shown[i]
        for disc, poly in zip(discs, coverage_polygons(xy[t], s["radius_m"], p.params.coverage.edges), strict=True):
            disc.set_xy(np.asarray(poly.exterior.coords))
        buoys.set_data(xy[t, :, 0], xy[t, :, 1])
        for dots, at in zip(others, rival_xy, strict=False):
            dots.set_data(at[t, :, 0], at[t, :, 1])
        for curve, track in zip(curves, p.tracks, strict=True):
            curve.set_data(minutes[: t + 1], track.coverage[: t + 1])
        clock.set_text(f"{region.name}: {minutes[t]:.1f} min, general policy {100 * policy.coverage[t]:.3g} %"
                       + "".join(f", {r.method} {100 * r.coverage[t]:.3g} %" for r in rivals))

    try:
        return save_gif(FuncAnimation(fig, frame, frames=len(shown)), len(shown), Path(path), fps, progress)
    finally:
        plt.close(fig)
