"""The figures stage: every figure of SPEC §9 from the pipeline's runs and metrics, one PNG per panel, for
every configuration (drawing primitives are in ``plots``)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from replicate.compare.evaluate import BASELINES, general_episode
from replicate.compare.rivals import lloyd_name
from replicate.compare.suite import (
    SuiteCell,
    drift_heading,
    lake_kinds,
    suite_event,
    suite_lake,
    suite_lose,
)
from replicate.core.artifacts import read_curve
from replicate.core.params import RegionKey, load_params
from replicate.learn.runs import KEPT_POLICY
from replicate.learn.train import CURVE
from replicate.pipeline.evaluation import not_in_matrix
from replicate.toolkit import plots
from replicate.toolkit.animate import animate_run, animate_trace
from replicate.toolkit.plan import Mission, plan_on
from replicate.toolkit.plan_map import plan_map
from replicate.world.coverage import coverage_ceiling
from replicate.world.env import start_patch
from replicate.world.geometry import coverage_fraction_exact
from replicate.world.osm import describe_source
from replicate.world.regions import at_density, make_region, region_from_file
from replicate.world.units import BOB_SPEED


@dataclass
class Figures:
    """What every figure of a pipeline run reads: the parameters, where PNGs go, the regions, the evaluation
    summary, and the reported runs grouped by cell (config, method, region) with their curves."""

    params: object
    fig: Path
    regions: dict
    summary: dict
    metrics_dir: Path
    by_group: dict[tuple, list] = field(default_factory=dict)
    curves_of: dict[tuple, list] = field(default_factory=dict)

    def baseline_coverage(self, region_name: str, names) -> dict:
        base = self.summary["baselines"]
        keys = {b: RegionKey(b, region_name).key for b in names}
        return {b: base[k]["coverage"] for b, k in keys.items() if k in base}

    def ceiling(self, region) -> float:
        c = self.params.coverage
        return coverage_ceiling(region.area, self.params.world.n_agents, c.radius, c.edges)


def group_runs(f: Figures, runs_dir: Path) -> None:
    """The reported runs of ``runs_dir`` by cell, with their curves (ablation runs and runs outside the matrix
    are not reported: see ``evaluation.not_in_matrix``)."""
    for run in sorted(p for p in runs_dir.iterdir() if (p / CURVE).exists()):
        ident = json.loads((run / "run.json").read_text())
        if ident["config"] not in f.params.configs or not_in_matrix(f.params, ident, run, f.regions):
            continue
        f.by_group.setdefault((ident["config"], ident["method"], ident["region"]), []).append(run)
    f.curves_of.update({key: [read_curve(r / CURVE) for r in sorted(group)] for key, group in f.by_group.items()})


def cell_figures(f: Figures) -> list:
    """Per cell: the reward curves, an evaluation episode's spread, the training diagnostics (and the paper's
    overall-coverage panel for paper CR-MARL on the square)."""
    c, written = f.params.coverage, []
    for (config, method, region_name), group in sorted(f.by_group.items()):
        region, curves = f.regions[region_name], f.curves_of[(config, method, region_name)]
        tag = f"{config}_{method}_{region_name}"
        label = f"{'SW' if method == 'sw' else 'CR'}-MARL, {region_name}, {config} config"
        first = sorted(group)[0]
        written.append(plots.reward_curves(curves, method, f.fig / f"fig_{tag}_reward.png", label,
                                           seed=json.loads((first / "run.json").read_text())["seed"]))
        metrics = json.loads((f.metrics_dir / "runs" / f"{first.name}.json").read_text())
        xy = np.array(metrics["example"]["final_positions"])
        trails = np.array(metrics["example"]["trajectory"])
        patch = start_patch(region.polygon, f.params.world.start_patch)
        cov = metrics["coverage"]
        note = f"seed {metrics['seed']}, evaluation coverage {cov['mean']:.2f} ({cov['n']} episodes)"
        written.append(plots.spread(region.polygon, patch, xy, c.radius, c.edges, f.fig / f"fig_{tag}_spread.png",
                                    f"{label}: final positions of an evaluation episode", trails, note))
        validation = [read_curve(r / "validation.csv") if (r / "validation.csv").exists() else None
                      for r in sorted(group)]
        seeds = [json.loads((r / "run.json").read_text())["seed"] for r in sorted(group)]
        written.append(plots.diagnostics(curves, f.fig / f"fig_{tag}_diagnostics.png", f"{label}, every seed",
                                         validation=validation, seeds=seeds))
        if config == "paper" and method == "cr" and region_name == "square":
            written.append(plots.overall_coverage(region.polygon, xy, c.radius, c.edges,
                                                  f.fig / "fig_overall_coverage.png", label))
    return written


def coverage_figures(f: Figures) -> list:
    """Per config and region: coverage during training by method, beside the baselines and the ceiling."""
    written = []
    for config in f.params.configs:
        for region_name, region in f.regions.items():
            curves_by_method = {f"{m.upper()}-MARL": f.curves_of.get((config, m, region_name), [])
                                for m in f.params.methods}
            curves_by_method = {k: v for k, v in curves_by_method.items() if v}
            if curves_by_method:
                written.append(plots.coverage_vs_episode(
                    curves_by_method, f.baseline_coverage(region_name, BASELINES), f.ceiling(region),
                    f.fig / f"fig_{config}_coverage_{region_name}.png",
                    f"Coverage during training, {region_name}, {config} config"))
    return written


def validation_figures(f: Figures) -> list:
    """Per config that selects its actors, and region: its deterministic validation curve during training."""
    written = []
    for config in f.params.configs:
        for region_name, region in f.regions.items():
            validation = {f"{m.upper()}-MARL": [read_curve(r / "validation.csv") for r in sorted(group)]
                          for (cf, m, rn), group in sorted(f.by_group.items()) if (cf, rn) == (config, region_name)
                          and all((r / "validation.csv").exists() for r in group)}
            if validation:
                written.append(plots.evaluation_vs_episode(
                    validation, f.baseline_coverage(region_name, ("naive_tuned", "lloyd_tuned")), f.ceiling(region),
                    f.fig / f"fig_{config}_evaluation_{region_name}.png",
                    f"Evaluation coverage during training, {region_name}, {config} config"))
    return written


def ablation_figures(f: Figures) -> list:
    ab, written = f.params.ablation, []
    for region_name in ab.regions:
        rows = {RegionKey.parse(k).what: v for k, v in f.summary.get("ablation", {}).items()
                if RegionKey.parse(k).region == region_name}
        if rows:
            written.append(plots.ablation(rows, f.baseline_coverage(region_name, ("naive_tuned", "lloyd_tuned")),
                                          f.fig / f"fig_ablation_{region_name}.png",
                                          f"{ab.method.upper()}-MARL `{ab.base}` on {region_name}: each change "
                                          "removed in turn"))
    return written


def bedok_map_figure(f: Figures, outline_path: str) -> Path:
    """The Bedok outline in lon/lat and in its UTM zone, with its source and licence."""
    import geopandas as gpd


    outline = region_from_file(outline_path, area=None)
    lonlat = gpd.read_file(outline_path).to_crs("EPSG:4326").geometry.iloc[0]
    utm = gpd.GeoSeries([lonlat], crs="EPSG:4326").to_crs(outline.utm_crs).iloc[0]
    return plots.bedok_map(lonlat, utm, outline.utm_crs, describe_source(outline_path), outline.attribution,
                           f.fig / "fig_bedok_map.png")


def make_figures(params_path: str, runs_dir: str, metrics_dir: str, figures_dir: str, outline_path: str,
                 policies_dir: str | None = None) -> list:
    """Every figure of SPEC §9, one PNG per panel, for every configuration, and with ``policies_dir`` (the
    ``train_general`` folder; its suite in ``metrics_dir/general.json``) the general policy's; returns the
    paths written."""

    params = load_params(params_path)
    metrics_dir = Path(metrics_dir)
    regions = {n: make_region(n, params.regions[n], params.world.region_area) for n in params.regions}
    f = Figures(params, Path(figures_dir), regions, json.loads((metrics_dir / "summary.json").read_text()),
                metrics_dir)
    c = params.coverage
    written = [plots.three_cases(regions["square"].polygon, c.radius, c.edges, f.fig / "fig_agent_vs_region.png")]
    group_runs(f, Path(runs_dir))
    written += cell_figures(f) + coverage_figures(f) + validation_figures(f) + ablation_figures(f)
    for (config, method, region_name), group in sorted(f.by_group.items()):
        if method == "cr":  # one animated evaluation episode per region and configuration
            written.append(animate_run(sorted(group)[0], params, regions[region_name],
                                       f.fig / f"anim_{config}_cr_{region_name}.gif"))
    if policies_dir is not None:
        written += general_figures(params, Path(policies_dir) / KEPT_POLICY, metrics_dir / "general.json", f.fig)
    written.append(bedok_map_figure(f, outline_path))
    return [str(p) for p in written]


def general_figures(params, policy: Path, suite_path: Path, fig: Path) -> list[Path]:
    """The general policy, one evaluation episode each: on the real lakes of ``general.suite.real_lakes`` (three
    test lakes where there are none) from the suite's last start (scattered by default; ``fig_general_lakes.png``),
    and as GIFs through a loss of a share of the fleet at T/2 (``anim_general_lose.gif``) and through the suite's
    drift of that cell (``anim_general_current.gif``), on Bedok with the paper's fleet."""

    su, c = params.general.suite, params.coverage
    suite = {(x["region"], x["n_agents"], x["start"], x["event"]): x
             for x in json.loads(suite_path.read_text())["cells"]}
    n, start = max(su.lake_fleets), su.starts[-1]
    kinds = lake_kinds(params)
    shown = [name for name, kind in kinds.items() if kind == "real" and name not in params.regions]
    shown = shown or [name for name, kind in kinds.items() if kind == "test"][:3]  # no lake files: test lakes
    panels = []
    for name in shown:
        region = at_density(*suite_lake(params, name), n)
        trace, _ = general_episode(policy, region, params, n, start)
        cell = suite[(name, n, start, "none")]
        cover = coverage_fraction_exact(region.polygon, trace[-1][None], c.radius, c.edges)[0]
        lloyd = lloyd_name(cell["baselines"])
        rival = {k: cell["baselines"][k]["coverage"]["mean"] for k in (lloyd, "best_layout")}
        panels.append({"region": region.polygon, "trace": trace, "title": (
            f"{name}\nN = {n}: coverage {cover:.2f} in this episode\nmean of {cell['coverage']['n']}: "
            f"{cell['coverage']['mean']:.3f}; {lloyd} {rival[lloyd]:.3f}, best layout {rival['best_layout']:.3f}")})
    written = [plots.general_lakes(panels, c.radius, c.edges, fig / "fig_general_lakes.png",
                                   f"The general policy on lakes it never trained on ({start} starts; "
                                   "crosses: where the buoys started)")]
    written += [plan_figure(params, policy, name, fig) for name in shown]
    bedok, buoys = make_region("bedok", params.regions["bedok"], params.world.region_area), params.world.n_agents
    lose = suite_lose(su, buoys)
    trace, alive = general_episode(policy, bedok, params, buoys, "corner", lose=lose)
    written.append(animate_trace(bedok.polygon, trace, alive, c.radius, c.edges,
                                 f"general policy, Bedok, {lose} of {buoys} lost at T/2",
                                 fig / "anim_general_lose.gif"))
    _, drift = suite_event(su, "current", buoys, drift_heading(params.evaluate.seed,
                                                           SuiteCell("bedok", buoys, "random", "current", "real")))
    flow = tuple(drift.flow[0])
    trace, alive = general_episode(policy, bedok, params, buoys, "random", current=flow)
    written.append(animate_trace(bedok.polygon, trace, alive, c.radius, c.edges, "general policy, Bedok, drift",
                                 fig / "anim_general_current.gif", flow=np.asarray(flow)))
    return written


def plan_figure(params, policy: Path, lake: str, fig: Path) -> Path:
    """``replicate plan`` on a suite lake with the paper's fleet at the suite's density, from the corner patch,
    buoys of the 1 m/s top speed: the policy against tuned and decentralised Lloyd and the clairvoyant planner,
    coverage against minutes (``fig_general_plan_LAKE.png``)."""
    n = params.world.n_agents
    region = at_density(*suite_lake(params, lake), n)
    mission = Mission(n, params.coverage.radius * region.scale, BOB_SPEED)
    return plan_map(plan_on(region, params, mission, policy), fig / f"fig_general_plan_{lake}.png")


def gallery(paths, notebook_dir: str) -> str:
    """Markdown that shows every figure from its file, linked relative to the executed notebook in
    ``notebook_dir`` (embedding them made the executed notebook 12 MB, rewritten on every run)."""
    return "\n\n".join(f"**{Path(p).name}**\n\n![{Path(p).stem}]({os.path.relpath(p, notebook_dir)})" for p in paths)
