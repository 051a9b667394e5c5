"""What the pipeline's notebooks call: the training matrix on both cores, the evaluation of every run and
baseline, and every figure of SPEC §9. The notebooks hold parameters and calls, no logic.

Layout: ``runs/NAME/{curve.csv, actors.pt, run.json}`` with NAME = ``CONFIG-METHOD-REGION-sSEED``;
``metrics/runs/NAME.json``, ``metrics/baselines/BASELINE-REGION.json``, ``metrics/summary.json``;
``figures/*.png``.
"""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from . import artifacts, plots
from .config import load_params, run_config
from .evaluate import BASELINES, eval_env, evaluate_baseline, evaluate_run, read_curve
from .metrics import coverage_ceiling, mean_ci
from .regions import make_region


def run_name(config: str, method: str, region: str, seed: int) -> str:
    return f"{config}-{method}-{region}-s{seed}"


def _train_one(job: dict) -> dict:
    import torch

    from .train import train

    torch.set_num_threads(1)
    params = load_params(job["params"])
    region = make_region(job["region"], params.regions[job["region"]], params.world.region_area)
    rc = run_config(params, job["config"], job["method"])
    out = Path(job["out"])
    resume = (out / "checkpoint.pt").exists()
    summary = train(rc, region, job["episodes"], job["seed"], out, params.train.checkpoint_every, resume, False)
    (out / "checkpoint.pt").unlink(missing_ok=True)  # the replay buffer is ~100 MB: not a pipeline output
    return summary


def train_matrix(params_path: str, configs, methods, regions, seeds, episodes: int, runs_dir: str, workers: int):
    """Train every config × method × region × seed, ``workers`` processes at a time (one per core).

    An interrupted matrix resumes each unfinished run from its checkpoint when run again."""
    jobs = [
        {"params": params_path, "config": c, "method": m, "region": r, "seed": s, "episodes": episodes,
         "out": str(Path(runs_dir) / run_name(c, m, r, s))}
        for c in configs for m in methods for r in regions for s in seeds
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers) as pool:
        summaries = list(pool.map(_train_one, jobs))
    wall = time.perf_counter() - t0
    table = [{k: s[k] for k in ("config", "method", "region", "seed", "wall_seconds", "final_coverage_last100")}
             for s in summaries]
    artifacts.write_json(Path(runs_dir) / "summary.json", {"wall_seconds": round(wall, 1), "runs": table})
    return wall, table


def _evaluate_one(job: dict) -> tuple[str, dict]:
    import torch

    torch.set_num_threads(1)
    params = load_params(job["params"])
    region = make_region(job["region"], params.regions[job["region"]], params.world.region_area)
    if "run" in job:
        result = evaluate_run(job["run"], params, region)
    else:
        result = evaluate_baseline(job["baseline"], params, region)
    artifacts.write_json(job["out"], result)
    return job["out"], result


def evaluate_matrix(params_path: str, runs_dir: str, metrics_dir: str, regions, workers: int) -> dict:
    """SPEC §8 metrics of every run in ``runs_dir`` and of every baseline on every region; a summary table."""
    metrics_dir = Path(metrics_dir)
    jobs = []
    for run in sorted(p for p in Path(runs_dir).iterdir() if (p / "actors.pt").exists()):
        ident = json.loads((run / "run.json").read_text())
        curve = read_curve(run / "curve.csv")
        artifacts.write_csv(metrics_dir / "curves" / f"{run.name}.csv", ["episode", "team_reward", "coverage"],
                            zip(curve["episode"].astype(int), curve["team_reward"], curve["coverage"]))
        jobs.append({"params": params_path, "run": str(run), "region": ident["region"],
                     "out": str(metrics_dir / "runs" / f"{run.name}.json")})
    for region in regions:
        for name in BASELINES:
            jobs.append({"params": params_path, "baseline": name, "region": region,
                         "out": str(metrics_dir / "baselines" / f"{name}-{region}.json")})
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = dict(pool.map(_evaluate_one, jobs))
    summary = summarise_metrics(results.values())
    artifacts.write_json(metrics_dir / "summary.json", summary)
    return summary


def summarise_metrics(results) -> dict:
    """Coverage table: per config × method × region the mean over seeds with a 95 % CI, and the baselines."""
    groups: dict[str, list] = {}
    baselines = {}
    for r in results:
        if r["kind"] == "run":
            groups.setdefault(f"{r['config']}/{r['method']}/{r['region']}", []).append(r)
        else:
            baselines[f"{r['baseline']}/{r['region']}"] = {
                "coverage": r["coverage"]["mean"],
                "nearest_neighbour": r["nearest_neighbour"]["mean"],
                "fraction_inside": r["fraction_inside"]["mean"],
                "ceiling": r["ceiling"],
            }
    runs = {}
    for key, rs in sorted(groups.items()):
        conv = [r["convergence_episode"] for r in rs]
        runs[key] = {
            "seeds": sorted(r["seed"] for r in rs),
            "coverage": mean_ci([r["coverage"]["mean"] for r in rs]),
            "coverage_per_seed": [round(r["coverage"]["mean"], 4) for r in rs],
            "nearest_neighbour": mean_ci([r["nearest_neighbour"]["mean"] for r in rs]),
            "fraction_inside": mean_ci([r["fraction_inside"]["mean"] for r in rs]),
            "convergence_episode": conv,
            "wall_seconds": mean_ci([r["wall_seconds"] or np.nan for r in rs]),
        }
    return {"runs": runs, "baselines": baselines}


def make_figures(params_path: str, runs_dir: str, metrics_dir: str, figures_dir: str, outline_path: str) -> list:
    """Every figure of SPEC §9, one PNG per panel, for every configuration; returns the paths written."""
    from .regions import region_from_file

    params = load_params(params_path)
    fig = Path(figures_dir)
    runs_dir, metrics_dir = Path(runs_dir), Path(metrics_dir)
    summary = json.loads((metrics_dir / "summary.json").read_text())
    c = params.coverage
    written = []
    regions = {n: make_region(n, params.regions[n], params.world.region_area) for n in params.regions}
    written.append(plots.three_cases(regions["square"].polygon, c.radius, c.edges, fig / "fig_agent_vs_region.png"))

    runs = sorted(p for p in runs_dir.iterdir() if (p / "curve.csv").exists())
    by_group: dict[tuple, list] = {}
    for run in runs:
        ident = json.loads((run / "run.json").read_text())
        by_group.setdefault((ident["config"], ident["method"], ident["region"]), []).append(run)

    for (config, method, region_name), group in sorted(by_group.items()):
        region = regions[region_name]
        curves = [read_curve(r / "curve.csv") for r in sorted(group)]
        tag = f"{config}_{method}_{region_name}"
        label = f"{'SW' if method == 'sw' else 'CR'}-MARL, {region_name}, {config} config"
        written.append(plots.reward_curves(curves, method, fig / f"fig_{tag}_reward.png", label))
        first = sorted(group)[0]
        metrics = json.loads((metrics_dir / "runs" / f"{first.name}.json").read_text())
        xy = np.array(metrics["example"]["final_positions"])
        trails = np.array(metrics["example"]["trajectory"])
        env = eval_env(region, run_config(params, config, method), 1)
        cov = metrics["coverage"]
        note = f"seed {metrics['seed']}, evaluation coverage {cov['mean']:.2f} (100 episodes)"
        written.append(plots.spread(region.polygon, env.patch, xy, c.radius, c.edges, fig / f"fig_{tag}_spread.png",
                                    f"{label}: final positions of an evaluation episode", trails, note))
        written.append(plots.diagnostics(curves[0], fig / f"fig_{tag}_diagnostics.png", f"{label}, seed 0"))
        if config == "paper" and method == "cr" and region_name == "square":
            written.append(plots.overall_coverage(region.polygon, xy, c.radius, c.edges,
                                                  fig / "fig_overall_coverage.png", label))

    for config in params.configs:
        for region_name, region in regions.items():
            curves_by_method = {
                f"{m.upper()}-MARL": [read_curve(r / "curve.csv") for r in by_group.get((config, m, region_name), [])]
                for m in params.methods
            }
            curves_by_method = {k: v for k, v in curves_by_method.items() if v}
            if not curves_by_method:
                continue
            base = {b: summary["baselines"][f"{b}/{region_name}"]["coverage"] for b in BASELINES
                    if f"{b}/{region_name}" in summary["baselines"]}
            ceiling = coverage_ceiling(region.area, params.world.n_agents, c.radius, c.edges)
            written.append(plots.coverage_vs_episode(curves_by_method, base, ceiling,
                                                     fig / f"fig_{config}_coverage_{region_name}.png",
                                                     f"Coverage during training, {region_name}, {config} config"))

    outline = region_from_file(outline_path, area=None)
    import geopandas as gpd

    lonlat = gpd.read_file(outline_path).to_crs("EPSG:4326").geometry.iloc[0]
    utm = gpd.GeoSeries([lonlat], crs="EPSG:4326").to_crs(outline.utm_crs).iloc[0]
    props = json.loads(Path(outline_path).read_text())["features"][0]["properties"]
    written.append(plots.bedok_map(lonlat, utm, outline.utm_crs, props.get("source", "?"), outline.attribution,
                                   fig / "fig_bedok_map.png"))
    return [str(p) for p in written]


def pipeline_workers(requested: int) -> int:
    return max(1, min(requested, os.cpu_count() or 1))
