"""The paper's figures (SPEC §9), one PNG per panel, drawn from the package's own geometry and run outputs.

Every function takes data (regions, positions, curves, metrics) and a path, writes the PNG atomically and
returns the path. Nothing here computes a metric: values come from ``world.coverage``, ``compare.metrics`` and
``compare.evaluate``.
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import shapely  # noqa: E402
from shapely.geometry import Polygon  # noqa: E402

from replicate.compare.metrics import moving_average  # noqa: E402
from replicate.core import artifacts  # noqa: E402
from replicate.world.geometry import cover_terms_exact, coverage_polygons  # noqa: E402

AGENT_COLOURS = plt.get_cmap("tab10").colors


def save(fig, path: str | Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    artifacts.atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def draw_polygon(ax, poly, **kw):
    for part in getattr(poly, "geoms", [poly]):
        if part.is_empty or part.geom_type != "Polygon":
            continue
        x, y = part.exterior.xy
        ax.fill(x, y, **kw)


def draw_region(ax, region: Polygon, patch: Polygon | None = None):
    draw_polygon(ax, region, facecolor="#d6ecfa", edgecolor="#1f4e79", linewidth=1.5, label="region")
    for part in getattr(region, "geoms", [region]):
        for hole in part.interiors:  # islands are land
            x, y = hole.xy
            ax.fill(x, y, facecolor="#e8e2cf", edgecolor="#1f4e79", linewidth=1.0)
    if patch is not None:
        draw_polygon(ax, patch, facecolor="none", edgecolor="k", linestyle="--", linewidth=1, label="start patch")
    ax.set_aspect("equal")
    ax.set_xlabel("x (simulation m)")
    ax.set_ylabel("y (simulation m)")


def three_cases(region: Polygon, radius: float, edges: int, path) -> Path:
    """Agent vs region, eq. (5)'s three cases: inside, partially overlapping, fully outside."""
    minx, miny, maxx, maxy = region.bounds
    cx = (minx + maxx) / 2
    xy = np.array([[[cx - 0.5, (miny + maxy) / 2], [maxx, miny + 0.3 * (maxy - miny)], [maxx + 1.2, maxy - 0.6]]])
    terms = cover_terms_exact(region, xy, radius, edges)
    cov = coverage_polygons(xy[0], radius, edges)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    draw_region(ax, region)
    labels = ["(1) inside", "(2) partially overlapping", "(3) fully outside"]
    for k in range(3):
        draw_polygon(ax, cov[k], facecolor=AGENT_COLOURS[k], alpha=0.45, edgecolor=AGENT_COLOURS[k])
        text = f"{labels[k]}\nA = {terms.area[0, k]:.3f} m²"
        if terms.disjoint[0, k]:
            text += f"\ndist = {terms.distance[0, k]:.2f} m"
        ax.plot(*xy[0, k], "o", color="k", ms=3)
        ax.annotate(text, xy[0, k], xytext=(0, 42), textcoords="offset points", ha="center", fontsize=8)
    ax.set_title("Agent coverage polygon vs region (eq. 5)")
    ax.set_xlim(minx - 0.5, maxx + 2.0)
    ax.set_ylim(miny - 0.7, maxy + 1.0)
    return save(fig, path)


def overall_coverage(region: Polygon, xy: np.ndarray, radius: float, edges: int, path, title: str) -> Path:
    """The union of coverage polygons with overlaps merged, clipped to the region (eq. 6). xy [N, 2]."""
    cov = coverage_polygons(xy, radius, edges)
    union = shapely.intersection(shapely.union_all(cov), region)
    minx, miny, maxx, maxy = region.bounds
    fig, ax = plt.subplots(figsize=(6, 6 * (maxy - miny + 2) / (maxx - minx + 2)))
    draw_region(ax, region)
    draw_polygon(ax, union, facecolor="#f4a261", alpha=0.7, edgecolor="#9c4a00", linewidth=1.2)
    for c in cov:
        x, y = c.exterior.xy
        ax.plot(x, y, color="k", linewidth=0.5, alpha=0.6)
    ax.plot(xy[:, 0], xy[:, 1], "k.", ms=4)
    ax.set_title(f"{title}\nmerged coverage ∩ region = {union.area:.2f} m² ({union.area / region.area:.0%})")
    return save(fig, path)


def spread(region: Polygon, patch: Polygon, xy: np.ndarray, radius: float, edges: int, path, title: str,
           trails: np.ndarray | None = None, note: str = "") -> Path:
    """Qualitative performance: region, start patch, final positions with coverage polygons (and trails)."""
    minx, miny, maxx, maxy = region.bounds
    w, h = maxx - minx + 2, maxy - miny + 2
    fig, ax = plt.subplots(figsize=(min(10, 1.2 * w + 2), min(7, 1.2 * h + 2)))
    draw_region(ax, region, patch)
    if trails is not None:
        for k in range(trails.shape[1]):
            ax.plot(trails[:, k, 0], trails[:, k, 1], color=AGENT_COLOURS[k % 10], linewidth=0.8, alpha=0.6)
    for k, c in enumerate(coverage_polygons(xy, radius, edges)):
        draw_polygon(ax, c, facecolor=AGENT_COLOURS[k % 10], alpha=0.35, edgecolor=AGENT_COLOURS[k % 10])
    ax.plot(xy[:, 0], xy[:, 1], "k.", ms=5)
    lo = np.minimum(xy.min(axis=0) - radius, (minx - 0.5, miny - 0.5))
    hi = np.maximum(xy.max(axis=0) + radius, (maxx + 0.5, maxy + 0.5))
    lo, hi = np.maximum(lo, (minx - 6, miny - 6)), np.minimum(hi, (maxx + 6, maxy + 6))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_title(title + (f"\n{note}" if note else ""), fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    return save(fig, path)


def reward_curves(curves: list[dict], method: str, path, title: str, window: int = 200,
                  seed: int | None = None) -> Path:
    """SW: the shared (average agent) reward, mean over seeds with a min-max band; CR: the nine agents' own
    reward curves of one seed, ``seed`` (the first curve; moving average over ``window`` episodes)."""
    fig, ax = plt.subplots(figsize=(8, 3.8))
    if method == "cr":
        title += f", seed {seed}" if seed is not None else ", first seed"
        c = curves[0]
        n = sum(1 for k in c if k.startswith("reward_"))
        for i in range(n):
            ma = moving_average(c[f"reward_{i}"], window)
            ax.plot(np.arange(len(ma)) + window - 1, ma, color=AGENT_COLOURS[i % 10], linewidth=1, label=f"agent {i}")
        ax.legend(ncol=5, fontsize=7)
        ax.set_ylabel("episode reward of each agent")
    else:
        mas = [moving_average(c["team_reward"], window) for c in curves]
        length = min(len(m) for m in mas)
        stack = np.stack([m[:length] for m in mas])
        x = np.arange(length) + window - 1
        ax.plot(x, stack.mean(axis=0), color="C0", label=f"mean of {len(curves)} seed(s)")
        if len(curves) > 1:
            ax.fill_between(x, stack.min(axis=0), stack.max(axis=0), color="C0", alpha=0.25, label="seed range")
        ax.legend(fontsize=8)
        ax.set_ylabel("average agent reward (shared)")
    ax.set_xlabel("episode")
    ax.set_title(title + f" ({window}-episode moving average)", fontsize=10)
    return save(fig, path)


def coverage_vs_episode(curves_by_method: dict[str, list[dict]], baselines: dict[str, float], ceiling: float,
                        path, title: str, window: int = 200) -> Path:
    """Training coverage vs episode for every method (mean over seeds, min-max band), with the baselines'
    evaluation coverage and the ceiling as horizontal lines."""
    fig, ax = plt.subplots(figsize=(8, 4))
    for k, (label, curves) in enumerate(curves_by_method.items()):
        mas = [moving_average(c["coverage"], window) for c in curves]
        length = min(len(m) for m in mas)
        if length == 0:
            continue
        stack = np.stack([m[:length] for m in mas])
        x = np.arange(length) + window - 1
        ax.plot(x, stack.mean(axis=0), color=f"C{k}", label=f"{label} ({len(curves)} seeds)")
        ax.fill_between(x, stack.min(axis=0), stack.max(axis=0), color=f"C{k}", alpha=0.2)
    styles = {"random": ":", "naive": "--", "naive_tuned": "--", "lloyd": "-.", "lloyd_tuned": "-.",
              "lloyd_converged": "-"}
    for name, value in baselines.items():
        ax.axhline(value, color="k" if name.endswith("_tuned") else "grey", linestyle=styles.get(name, ":"),
                   linewidth=1, label=f"{name} {value:.2f}")
    ax.axhline(ceiling, color="k", linewidth=0.8, label=f"ceiling {ceiling:.3f}")
    ax.set_ylim(0, 1)
    ax.set_xlabel("episode")
    ax.set_ylabel("coverage fraction at the last step")
    ax.set_title(title + f" ({window}-episode moving average)", fontsize=10)
    ax.legend(fontsize=7, ncol=2, loc="upper left")
    return save(fig, path)


def evaluation_vs_episode(validation_by_label: dict[str, list[dict]], baselines: dict[str, float], ceiling: float,
                          path, title: str) -> Path:
    """Evaluation coverage against training episode: each run's deterministic policy on its fixed validation
    starts (``validation.csv``), mean over seeds with the interquartile band and the min-max band, beside the
    baselines' evaluation coverage and the ceiling as horizontal lines."""
    fig, ax = plt.subplots(figsize=(8, 4))
    for k, (label, vals) in enumerate(validation_by_label.items()):
        length = min(len(v["coverage"]) for v in vals)
        stack = np.stack([v["coverage"][:length] for v in vals])
        x = vals[0]["episode"][:length]
        ax.plot(x, stack.mean(axis=0), color=f"C{k}", label=f"{label} (mean of {len(vals)} seeds)")
        ax.fill_between(x, *np.percentile(stack, [25, 75], axis=0), color=f"C{k}", alpha=0.3)
        ax.fill_between(x, stack.min(axis=0), stack.max(axis=0), color=f"C{k}", alpha=0.1)
    styles = {"naive": "--", "naive_tuned": "--", "lloyd": "-.", "lloyd_tuned": "-.", "lloyd_converged": "-"}
    for name, value in baselines.items():
        ax.axhline(value, color="k" if name.endswith("_tuned") else "grey", linestyle=styles.get(name, ":"),
                   linewidth=1, label=f"{name} {value:.3f}")
    ax.axhline(ceiling, color="k", linewidth=0.6, alpha=0.5, label=f"ceiling {ceiling:.3f}")
    ax.set_ylim(0, 1)
    ax.set_xlabel("training episode")
    ax.set_ylabel("coverage fraction (validation starts)")
    ax.set_title(title + "\nbands: interquartile range and min-max over seeds", fontsize=10)
    ax.legend(fontsize=7, ncol=2, loc="lower right")
    return save(fig, path)


def ablation(rows: dict[str, dict], baselines: dict[str, float], path, title: str) -> Path:
    """Leave-one-out ablation: evaluation coverage with every change (the base config) and without each one,
    mean over seeds with the 95 % CI as error bars and each seed as a dot; baselines as vertical lines."""
    names = list(rows)
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(names) + 1.5))
    y = np.arange(len(names))
    for k, r in enumerate(rows.values()):
        for offset, key, color in ((-0.18, "with", "C0"), (0.18, "without", "C3")):
            ci = r[key]
            err = [[ci["mean"] - ci["lo"]], [ci["hi"] - ci["mean"]]] if ci["lo"] == ci["lo"] else None
            ax.barh(y[k] + offset, ci["mean"], height=0.34, xerr=err, color=color, alpha=0.7,
                    label=("with the change" if key == "with" else "without it") if k == 0 else None)
            ax.plot(r[f"{key}_per_seed"], [y[k] + offset] * len(r[f"{key}_per_seed"]), "k.", markersize=3)
    for i, (name, value) in enumerate(baselines.items()):
        ax.axvline(value, color="grey", linestyle=("--", "-.", ":")[i % 3], linewidth=1, label=f"{name} {value:.2f}")
    ax.set_yticks(y, names)
    ax.set_xlim(0, 1)
    ax.set_xlabel("evaluation coverage at the last step")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    return save(fig, path)


def diagnostics(curves: list[dict], path, title: str, window: int = 100,
                validation: list[dict | None] | None = None, seeds: list[int] | None = None) -> Path:
    """Learning diagnostics per episode for every seed of a group (one colour per seed, raw values faint,
    ``window``-episode moving average bold): critic loss, mean |Q|, saturated actions, exploration σ, training
    coverage, plus the validation coverage of the checkpoint selection where a run has one."""
    keys = [("critic_loss", "critic loss"), ("q_abs", "mean |Q|"), ("saturated", "fraction |a| > 0.99"),
            ("noise", "exploration σ"), ("coverage", "coverage")]
    fig, axes = plt.subplots(len(keys), 1, figsize=(8, 9), sharex=True)
    for k, curve in enumerate(curves):
        x = np.asarray(curve["episode"])
        for ax, (key, label) in zip(axes, keys):
            y = np.asarray(curve[key], dtype=float)
            ax.plot(x, y, color=f"C{k}", linewidth=0.3, alpha=0.25)
            ok = ~np.isnan(y)
            if ok.sum() >= window:
                ax.plot(x[ok][window - 1:], moving_average(y[ok], window), color=f"C{k}", linewidth=1,
                        label=f"seed {(seeds or range(len(curves)))[k]}" if key == "critic_loss" else None)
            ax.set_ylabel(label, fontsize=8)
            if key == "critic_loss" and np.nanmax(y, initial=0) > 0:
                ax.set_yscale("log")
            else:
                ax.ticklabel_format(axis="y", useOffset=False)
        val = (validation or [None] * len(curves))[k]
        if val is not None:
            axes[-1].plot(val["episode"], val["coverage"], "o-", color=f"C{k}", markersize=2, linewidth=0.6,
                          label="validation (deterministic)" if k == 0 else None)
    axes[0].legend(fontsize=7, loc="upper right")
    if validation and any(v is not None for v in validation):
        axes[-1].legend(fontsize=7, loc="lower right")
    axes[-1].set_xlabel("episode")
    axes[0].set_title(title, fontsize=10)
    return save(fig, path)


def bedok_map(lonlat: Polygon, utm: Polygon, utm_crs: str, source: str, attribution: str, path) -> Path:
    """Bedok Reservoir in lon/lat and in UTM, side by side, with the outline's source and attribution."""
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.5))
    draw_polygon(a, lonlat, facecolor="#9ecae1", edgecolor="#08519c")
    a.set_xlabel("longitude (°E)")
    a.set_ylabel("latitude (°N)")
    a.set_title("lon/lat (EPSG:4326)")
    a.set_aspect(1 / np.cos(np.radians(lonlat.centroid.y)))
    a.ticklabel_format(useOffset=False, style="plain")
    a.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
    draw_polygon(b, utm, facecolor="#9ecae1", edgecolor="#08519c")
    b.set_xlabel("easting (m)")
    b.set_ylabel("northing (m)")
    b.set_title(f"UTM ({utm_crs}), area {utm.area / 1e6:.3f} km²")
    b.set_aspect("equal")
    b.ticklabel_format(useOffset=False, style="plain")
    b.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
    fig.subplots_adjust(wspace=0.35)
    fig.suptitle(f"Bedok Reservoir — outline source: {source}", fontsize=11)
    fig.text(0.5, -0.02, attribution, ha="center", fontsize=7, wrap=True)
    return save(fig, path)


def general_lakes(panels: list[dict], radius: float, edges: int, path, title: str) -> Path:
    """The general policy on several lakes side by side: each panel a dict with ``region`` (Polygon), ``trace``
    [T + 1, N, 2] (one episode) and ``title``; trails, final coverage polygons, final positions."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 5.5))
    for ax, panel in zip(np.atleast_1d(axes), panels, strict=True):
        trace = panel["trace"]
        draw_region(ax, panel["region"])
        for k in range(trace.shape[1]):
            colour = AGENT_COLOURS[k % 10]
            ax.plot(trace[:, k, 0], trace[:, k, 1], color=colour, linewidth=0.7, alpha=0.6)
        for k, c in enumerate(coverage_polygons(trace[-1], radius, edges)):
            draw_polygon(ax, c, facecolor=AGENT_COLOURS[k % 10], alpha=0.35, edgecolor=AGENT_COLOURS[k % 10])
        ax.plot(trace[0, :, 0], trace[0, :, 1], "k+", ms=4, alpha=0.5)
        ax.plot(trace[-1, :, 0], trace[-1, :, 1], "k.", ms=4)
        ax.set_title(panel["title"], fontsize=9)
    fig.suptitle(title, fontsize=11, y=1.08)  # above the panels' three-line titles
    return save(fig, path)
