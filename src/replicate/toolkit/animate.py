"""Animations: a GIF of one episode (region, buoys, coverage polygons, trails): of a trained run, or of any trace
(the general policy through a loss or a current, ``pipeline.figures``)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replicate.compare.evaluate import actor_policy, evaluation_env, rollout, run_actors
from replicate.core.params import Params
from replicate.toolkit import plots
from replicate.world.geometry import coverage_fraction_exact, coverage_polygons
from replicate.world.regions import Region

if TYPE_CHECKING:
    from shapely.geometry import Polygon


def animate_run(run_dir: str | Path, params: Params, region: Region, out: str | Path, seed: int | None = None,
                fps: int = 10, progress: bool = False) -> Path:
    """Roll out the run's deterministic actors for one episode and write it as a GIF (atomically)."""
    net, meta, rc = run_actors(Path(run_dir), params, same_observation=False)
    ident = meta["identity"]
    env = evaluation_env(region, rc, 1, meta["observation"])  # what the actors were trained to observe
    trace = rollout(env, actor_policy(net, meta["observation"]), rc.world.episode_length,
                    params.evaluate.seed if seed is None else seed)["positions"][:, 0]  # [T + 1, N, 2]
    label = f"{ident['config']} {ident['method'].upper()}-MARL, {region.name}"
    return animate_trace(region.polygon, trace, None, rc.coverage.radius, rc.coverage.edges, label, out,
                         patch=env.patch, fps=fps, progress=progress)


def animate_trace(water: Polygon, trace: np.ndarray, alive: np.ndarray | None, radius: float, edges: int,
                  label: str, out: str | Path, patch: Polygon | None = None, flow: np.ndarray | None = None,
                  fps: int = 10, progress: bool = False) -> Path:
    """One episode as a GIF (atomically): the water, each buoy's coverage polygon and trail, the coverage of the
    buoys in service in the title. ``trace`` [T + 1, N, 2]; ``alive`` [T + 1, N] (None: none lost; a lost buoy
    is drawn as a grey cross, without coverage); ``flow`` [2], a uniform current drawn as an arrow."""
    from matplotlib.animation import FuncAnimation
    from matplotlib.patches import Polygon as MplPolygon

    alive = np.ones(trace.shape[:2], bool) if alive is None else alive
    cover = np.array([coverage_fraction_exact(water, trace[t][alive[t]][None], radius, edges)[0]
                      for t in range(len(trace))])  # [T + 1], of the buoys in service

    fig, ax = plots.plt.subplots(figsize=(6, 5))
    minx, miny, maxx, maxy = water.bounds
    lo = np.minimum(trace.reshape(-1, 2).min(0) - radius, (minx - 0.5, miny - 0.5))
    hi = np.maximum(trace.reshape(-1, 2).max(0) + radius, (maxx + 0.5, maxy + 0.5))
    plots.draw_region(ax, water, patch)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    if flow is not None and np.any(flow):
        ax.annotate("", xy=(lo[0] + 0.3 + flow[0], hi[1] - 0.3 + flow[1]), xytext=(lo[0] + 0.3, hi[1] - 0.3),
                    arrowprops={"arrowstyle": "->", "color": "#1f4e79", "lw": 2})
        ax.text(lo[0] + 0.3, hi[1] - 0.15, f"current {np.hypot(*flow):.1f} simulation m/s", fontsize=8, color="#1f4e79")
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
        title.set_text(f"{label}: step {t}, coverage {cover[t]:.2f}" + (f", {gone} lost" if gone else ""))

    try:
        return save_gif(FuncAnimation(fig, frame, frames=len(trace)), len(trace), Path(out), fps, progress)
    finally:
        plots.plt.close(fig)


def save_gif(anim, frames: int, out: Path, fps: int, progress: bool) -> Path:
    """Write an animation as a GIF atomically (mode 0644), with a progress bar of its frames."""
    from matplotlib.animation import PillowWriter
    from tqdm.auto import tqdm

    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".gif", delete=False) as tmp:
        tmp_path = Path(tmp.name)
    try:
        with tqdm(total=frames, desc=f"drawing {out.name}", unit="frame", disable=not progress, leave=False) as bar:
            anim.save(tmp_path, writer=PillowWriter(fps=fps), progress_callback=lambda i, n: bar.update(1))
        tmp_path.chmod(0o644)
        tmp_path.replace(out)
    finally:
        tmp_path.unlink(missing_ok=True)
    return out
