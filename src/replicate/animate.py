"""Animations: a GIF of one evaluation episode of a trained run (region, buoys, coverage polygons, trails)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from . import plots
from .config import Params
from .evaluate import actor_policy, eval_env, rollout, run_actors
from .geometry import coverage_fraction_exact, coverage_polygons
from .regions import Region


def animate_run(run_dir: str | Path, params: Params, region: Region, out: str | Path, seed: int | None = None,
                fps: int = 10, progress: bool = False) -> Path:
    """Roll out the run's deterministic actors for one episode and write it as a GIF (atomically)."""
    from matplotlib.animation import FuncAnimation, PillowWriter
    from matplotlib.patches import Polygon as MplPolygon

    net, meta, rc = run_actors(Path(run_dir), params, same_observation=False)
    ident = meta["identity"]
    env = eval_env(region, rc, 1, meta["observation"])  # what the actors were trained to observe
    trace = rollout(env, actor_policy(net, meta["observation"]), rc.world.episode_length,
                    params.evaluate.seed if seed is None else seed)["positions"][:, 0]  # [T + 1, N, 2]
    c = rc.coverage
    cover = coverage_fraction_exact(region.polygon, trace, c.radius, c.edges)  # [T + 1]

    fig, ax = plots.plt.subplots(figsize=(6, 5))
    minx, miny, maxx, maxy = region.polygon.bounds
    lo = np.minimum(trace.reshape(-1, 2).min(0) - c.radius, (minx - 0.5, miny - 0.5))
    hi = np.maximum(trace.reshape(-1, 2).max(0) + c.radius, (maxx + 0.5, maxy + 0.5))
    plots.draw_region(ax, region.polygon, env.patch)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    # the artists are drawn once and moved each frame (redrawing the axes per frame took 5x longer)
    colours = [plots.AGENT_COLOURS[k % 10] for k in range(trace.shape[1])]
    covers = [ax.add_patch(MplPolygon(np.zeros((1, 2)), closed=True, facecolor=col, alpha=0.35, edgecolor=col))
              for col in colours]
    trails = [ax.plot([], [], color=col, linewidth=0.8)[0] for col in colours]
    (dots,) = ax.plot([], [], "k.", ms=5)
    title = ax.set_title("", fontsize=9)

    def frame(t: int):
        for patch, poly in zip(covers, coverage_polygons(trace[t], c.radius, c.edges), strict=True):
            patch.set_xy(np.asarray(poly.exterior.coords))
        for k, trail in enumerate(trails):
            trail.set_data(trace[: t + 1, k, 0], trace[: t + 1, k, 1])
        dots.set_data(trace[t, :, 0], trace[t, :, 1])
        title.set_text(f"{ident['config']} {ident['method'].upper()}-MARL, {region.name}: step {t}, "
                       f"coverage {cover[t]:.2f}")

    anim = FuncAnimation(fig, frame, frames=len(trace))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".gif", delete=False) as tmp:
        tmp_path = Path(tmp.name)
    from tqdm.auto import tqdm

    try:
        with tqdm(total=len(trace), desc=f"drawing {out.name}", unit="frame", disable=not progress,
                  leave=False) as bar:
            anim.save(tmp_path, writer=PillowWriter(fps=fps), progress_callback=lambda i, n: bar.update(1))
        tmp_path.chmod(0o644)
        tmp_path.replace(out)
    finally:
        tmp_path.unlink(missing_ok=True)
        plots.plt.close(fig)
    return out
