"""Animations: a GIF of one episode (region, buoys, coverage polygons, trails): of a trained run, or of any trace
(the general policy through a loss or a current, ``pipeline.figures``)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from shapely import affinity

from replicate.compare.evaluate import actor_policy, evaluation_env, rollout, run_actors
from replicate.core.params import Params
from replicate.core.progress import bar as progress_bar
from replicate.toolkit import plots
from replicate.world.geometry import coverage_fraction_exact, coverage_polygons
from replicate.world.regions import Region
from replicate.world.units import Units

if TYPE_CHECKING:
    from shapely.geometry import Polygon


def animate_run(run_dir: str | Path, params: Params, region: Region, out: str | Path, seed: int | None = None,
                fps: int = 10, progress: bool = False, speed_ms: float | None = None) -> Path:
    """Roll out the run's deterministic actors for one episode and write it as a GIF (atomically); with
    ``speed_ms`` (the buoys' top speed, m/s) drawn in metres (on the lake's UTM map where it has one) with a clock
    in seconds (``world.units``), else in the paper's own units and steps."""
    net, meta, rc = run_actors(Path(run_dir), params, same_observation=False)
    ident = meta["identity"]
    env = evaluation_env(region, rc, 1, meta["observation"])  # what the actors were trained to observe
    trace = rollout(env, actor_policy(net, meta["observation"]), rc.world.episode_length,
                    params.evaluate.seed if seed is None else seed)["positions"][:, 0]  # [T + 1, N, 2]
    label = f"{ident['config']} {ident['method'].upper()}-MARL, {region.name}"
    si = None if speed_ms is None else (region, Units.of(rc.world, rc.coverage, rc.coverage.radius * region.scale,
                                                         speed_ms))
    return animate_trace(region.polygon, trace, None, rc.coverage.radius, rc.coverage.edges, label, out,
                         patch=env.patch, fps=fps, progress=progress, si=si)


def animate_trace(water: Polygon, trace: np.ndarray, alive: np.ndarray | None, radius: float, edges: int,
                  label: str, out: str | Path, patch: Polygon | None = None, flow: np.ndarray | None = None,
                  fps: int = 10, progress: bool = False, si: tuple[Region, Units] | None = None) -> Path:
    """One episode as a GIF (atomically): the water, each buoy's coverage polygon and trail, the coverage of the
    buoys in service in the title. ``trace`` [T + 1, N, 2]; ``alive`` [T + 1, N] (None: none lost; a lost buoy
    is drawn as a grey cross, without coverage); ``flow`` [2], a uniform current drawn as an arrow. With ``si``
    (the region ``water`` belongs to and the deployment's units) everything is drawn in metres on the region's
    map, the clock in seconds; without, in simulation metres and control steps."""
    from matplotlib.animation import FuncAnimation
    from matplotlib.patches import Polygon as MplPolygon

    alive = np.ones(trace.shape[:2], bool) if alive is None else alive
    cover = np.array([coverage_fraction_exact(water, trace[t][alive[t]][None], radius, edges)[0]
                      for t in range(len(trace))])  # [T + 1], of the buoys in service
    scale = 1.0 if si is None else si[0].scale  # metres per unit drawn
    if si is not None:
        region, units = si
        water, trace, radius = region.map_polygon(), region.to_map(trace), radius * scale
        patch = None if patch is None else affinity.affine_transform(patch, [scale, 0, 0, scale, *region.offset])

    fig, ax = plots.plt.subplots(figsize=(6, 5))
    lo, hi = frame_axes(ax, water, patch, trace, radius, scale, None if si is None else region)
    if flow is not None and np.any(flow):
        tail = (lo[0] + 0.3 * scale, hi[1] - 0.3 * scale)
        ax.annotate("", xy=(tail[0] + flow[0] * scale, tail[1] + flow[1] * scale), xytext=tail,
                    arrowprops={"arrowstyle": "->", "color": "#1f4e79", "lw": 2})
        speed = (f"{np.hypot(*flow):.1f} simulation m/s" if si is None
                 else f"{units.speed_ms(np.hypot(*flow)):.2f} m/s")
        ax.text(tail[0], hi[1] - 0.15 * scale, f"current {speed}", fontsize=8, color="#1f4e79")

    def clock(t: int) -> str:
        if si is None:
            return f"step {t}, coverage {cover[t]:.2f}"
        return f"{units.steps_time_s(t) / 60:.1f} min, coverage {100 * cover[t]:.3g} %"

    # the artists are drawn once and moved each frame (redrawing the axes per frame took 5x longer)
    colours = [plots.AGENT_COLOURS[k % 10] for k in range(trace.shape[1])]
    covers = [ax.add_patch(MplPolygon(np.zeros((1, 2)), closed=True, facecolor=col, alpha=0.35, edgecolor=col))
              for col in colours]
    trails = [ax.plot([], [], color=col, linewidth=0.8)[0] for col in colours]
    (dots,) = ax.plot([], [], "k.", ms=5)
    (lost,) = ax.plot([], [], "x", color="0.4", ms=6)
    title = ax.set_title("", fontsize=9)

    def frame(t: int):
        for k, (patch_k, poly) in enumerate(zip(covers, coverage_polygons(trace[t], radius, edges), strict=True)):
            patch_k.set_xy(np.asarray(poly.exterior.coords))
            patch_k.set_visible(bool(alive[t, k]))
        for k, trail in enumerate(trails):
            trail.set_data(trace[: t + 1, k, 0], trace[: t + 1, k, 1])
        dots.set_data(trace[t, alive[t], 0], trace[t, alive[t], 1])
        lost.set_data(trace[t, ~alive[t], 0], trace[t, ~alive[t], 1])
        gone = int((~alive[t]).sum())
        title.set_text(f"{label}: {clock(t)}" + (f", {gone} lost" if gone else ""))

    try:
        return save_gif(FuncAnimation(fig, frame, frames=len(trace)), len(trace), Path(out), fps, progress)
    finally:
        plots.plt.close(fig)


def frame_axes(ax, water: Polygon, patch: Polygon | None, trace: np.ndarray, radius: float, scale: float,
               region: Region | None) -> tuple[np.ndarray, np.ndarray]:
    """Draw the water on ``ax`` and frame it with every position of ``trace`` and a margin of half a simulation
    metre (``scale`` metres each); labelled in metres on ``region``'s map (None: the simulation's) → the
    corners (lo, hi)."""
    minx, miny, maxx, maxy = water.bounds
    lo = np.minimum(trace.reshape(-1, 2).min(0) - radius, (minx - 0.5 * scale, miny - 0.5 * scale))
    hi = np.maximum(trace.reshape(-1, 2).max(0) + radius, (maxx + 0.5 * scale, maxy + 0.5 * scale))
    plots.draw_region(ax, water, patch)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    if region is not None:
        ax.set_xlabel(f"easting (m, {region.utm_crs})" if region.utm_crs else "x (m)")
        ax.set_ylabel("northing (m)" if region.utm_crs else "y (m)")
        ax.ticklabel_format(useOffset=False, style="plain")
    return lo, hi


def save_gif(anim, frames: int, out: Path, fps: int, progress: bool) -> Path:
    """Write an animation as a GIF atomically (mode 0644), with a progress bar of its frames."""
    from matplotlib.animation import PillowWriter

    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".gif", delete=False) as tmp:
        tmp_path = Path(tmp.name)
    try:
        with progress_bar(progress, total=frames, desc=f"drawing {out.name}", unit="frame", leave=False) as bar:
            anim.save(tmp_path, writer=PillowWriter(fps=fps), progress_callback=lambda i, n: bar.update(1))
        tmp_path.chmod(0o644)
        tmp_path.replace(out)
    finally:
        tmp_path.unlink(missing_ok=True)
    return out
