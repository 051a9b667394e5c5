"""The ``evaluate`` stage: SPEC §8 metrics of every run of the matrix and of every baseline on every region, in
parallel processes, into ``metrics/`` and the summary table ``metrics/summary.json`` (means over seeds with
bootstrap intervals, the robustness scenarios, the ablation's rows)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from replicate.compare import stats
from replicate.compare.evaluate import BASELINES, evaluate_baseline, evaluate_run
from replicate.core import artifacts
from replicate.core.artifacts import read_curve
from replicate.core.executor import map_jobs
from replicate.core.params import Cell, Params, RegionKey, ablated_name, load_params, run_config, selection_only
from replicate.learn.runs import finished_run, run_identity
from replicate.learn.train import CURVE
from replicate.pipeline.matrix import cell_seeds
from replicate.world.regions import make_region

log = logging.getLogger(__name__)


def _evaluate_one(job: dict) -> tuple[str, dict]:
    import torch

    torch.set_num_threads(1)
    params = load_params(job["params"])
    region = make_region(job["region"], params.regions[job["region"]], params.world.region_area)
    if "run" in job:
        result = evaluate_run(job["run"], params, region, job.get("actors", "actors.pt"), job.get("as_config"))
    else:
        result = evaluate_baseline(job["baseline"], params, region, tuned=job.get("tuned"))
    artifacts.write_json(job["out"], result)
    return job["out"], result


def selection_ablation_jobs(params_path: str, params: Params, run: Path, ident: dict, metrics_dir: Path) -> list:
    """Evaluation jobs for the selection-only ablation changes: the base run's last actors, filed under the
    ablation config's name (its training is the base run's, step for step)."""
    ab = params.ablation
    if not (ident["config"] == ab.base and ident["method"] == ab.method and ident["region"] in ab.regions
            and ident["seed"] in ab.seeds and (run / "actors_last.pt").exists()):
        return []
    jobs = []
    for change in (c for c in ab.changes if selection_only(params, c)):
        name = ablated_name(ab.base, change)
        out = metrics_dir / "runs" / f"{run.name.replace(ab.base, name, 1)}.json"
        jobs.append({"params": params_path, "run": str(run), "region": ident["region"], "actors": "actors_last.pt",
                     "as_config": name, "out": str(out)})
    return jobs


def evaluate_matrix(params_path: str, runs_dir: str, metrics_dir: str, regions, workers: int,
                    tuned_baselines: str | Path, executor: str = "local") -> dict:
    """SPEC §8 metrics of every run in ``runs_dir`` and of every baseline on every region (the tuned ones with the
    gains in ``tuned_baselines``), in ``workers`` processes or as Ray tasks (``executor``); a summary table."""
    metrics_dir = Path(metrics_dir)
    params = load_params(params_path)
    tuned = json.loads(Path(tuned_baselines).read_text())
    jobs = []
    built = {name: make_region(name, spec, params.world.region_area) for name, spec in params.regions.items()}
    for run in sorted(p for p in Path(runs_dir).iterdir() if (p / "actors.pt").exists()):
        ident = json.loads((run / "run.json").read_text())
        why = not_in_matrix(params, ident, run, built)
        if why:  # a run of older code or settings, of a seed that chose values, of an ablation since removed
            log.warning("skipped %s: %s", run.name, why)
            continue
        curve = read_curve(run / CURVE)
        artifacts.write_csv(metrics_dir / "curves" / f"{run.name}.csv", ["episode", "team_reward", "coverage"],
                            zip(curve["episode"].astype(int), curve["team_reward"], curve["coverage"]))
        jobs.append({"params": params_path, "run": str(run), "region": ident["region"],
                     "out": str(metrics_dir / "runs" / f"{run.name}.json")})
        jobs += selection_ablation_jobs(params_path, params, run, ident, metrics_dir)
    # the baselines first: the converged Lloyd layouts (500 steps of 100 episodes) are the longest jobs, and
    # started last they kept one process busy while the other idled
    jobs = [{"params": params_path, "baseline": name, "region": region,
             "tuned": tuned.get(RegionKey(name.removesuffix("_tuned"), region).key)
             if name.endswith("_tuned") else None,
             "out": str(metrics_dir / "baselines" / f"{name}-{region}.json")}
            for name in BASELINES for region in regions] + jobs
    results = dict(map_jobs(_evaluate_one, jobs, executor, workers))
    summary = summarise_metrics(results.values(), stats.Bootstrap.of(params.report))
    summary = split_ablation(summary, params)
    artifacts.write_json(metrics_dir / "summary.json", summary)
    return summary


def not_in_matrix(params: Params, ident: dict, run: Path, regions: dict) -> str | None:
    """Why the finished run ``run`` (its ``run.json`` is ``ident``) is not one the pipeline reports, or None: its
    config and seed must be in the matrix (``train.seeds``, ``ablation.seeds``), and its identity (code version,
    settings, region, episodes) the one params.yaml gives now. ``regions``: name → Region, built once."""

    config = ident.get("config")
    if config not in params.all_configs():
        return f"its config {config!r} is not in params.yaml"
    if config in params.configs and config not in params.train.seeds:
        return f"params.yaml train.seeds has no seeds for {config!r}"
    if ident.get("seed") not in cell_seeds(params, config):
        return f"seed {ident.get('seed')} is not among {config}'s reported seeds"
    region = regions.get(ident.get("region"))
    if region is None:
        return f"its region {ident.get('region')!r} is not in params.yaml"
    rc = run_config(params, config, ident["method"], ident["region"])
    if finished_run(run, run_identity(rc, region, params.train.episodes, ident["seed"])) is None:
        return "it was trained with other code or settings than params.yaml gives now"
    return None


def split_ablation(summary: dict, params: Params) -> dict:
    """Move the ablation groups out of ``runs`` into ``ablation``: one row per change with the base config's
    coverage (with the change) and the derived config's (without it), each over the ablation's seeds, and the
    bootstrap interval of Δ = with − without."""
    ab, r = params.ablation, params.report
    boot = stats.Bootstrap.of(r)
    runs = dict(summary["runs"])
    rows = {}
    for change, keys in ab.changes.items():
        for region in ab.regions:
            derived = runs.pop(Cell(ablated_name(ab.base, change), ab.method, region).key, None)
            base = summary["runs"].get(Cell(ab.base, ab.method, region).key)
            if derived is None or base is None:
                continue
            with_ = [c for s, c in zip(base["seeds"], base["coverage_per_seed"]) if s in ab.seeds]
            without = derived["coverage_per_seed"]
            rows[RegionKey(change, region).key] = {
                "keys": list(keys),
                "with": stats.mean_interval(with_, boot),
                "without": stats.mean_interval(without, boot),
                "with_per_seed": with_,
                "without_per_seed": without,
                "delta": stats.difference([with_], [without], boot),
            }
    return {**summary, "runs": runs, "ablation": rows}


def summarise_metrics(results, boot: stats.Bootstrap = stats.DEFAULT) -> dict:
    """Coverage table: per config × method × region the mean over seeds with its bootstrap interval, each
    robustness scenario likewise, and the baselines (deterministic: one value per region)."""
    groups: dict[str, list] = {}
    baselines = {}
    for r in results:
        if r["kind"] == "run":
            groups.setdefault(Cell(r["config"], r["method"], r["region"]).key, []).append(r)
        else:
            baselines[RegionKey(r['baseline'], r['region']).key] = {
                "coverage": r["coverage"]["mean"],
                "nearest_neighbour": r["nearest_neighbour"]["mean"],
                "fraction_inside": r["fraction_inside"]["mean"],
                "ceiling": r["ceiling"],
                "steps": r["steps"],
                **({"gains": r["gains"]} if "gains" in r else {}),
                **({"robustness": {k: v["coverage"] for k, v in r["robustness"].items()}}
                   if "robustness" in r else {}),
            }
    runs = {}
    for key, rs in sorted(groups.items()):
        rs = sorted(rs, key=lambda r: r["seed"])
        scenarios = rs[0].get("robustness", {})
        runs[key] = {
            "seeds": [r["seed"] for r in rs],
            "coverage": stats.mean_interval([r["coverage"]["mean"] for r in rs], boot),
            "coverage_per_seed": [round(r["coverage"]["mean"], 4) for r in rs],
            "nearest_neighbour": stats.mean_interval([r["nearest_neighbour"]["mean"] for r in rs], boot),
            "nearest_neighbour_per_seed": [round(r["nearest_neighbour"]["mean"], 4) for r in rs],
            "nearest_neighbour_inside": stats.mean_interval([r["nearest_neighbour_inside"]["mean"] for r in rs],
                                                            boot),
            "nearest_neighbour_inside_per_seed": [None if r["nearest_neighbour_inside"]["n"] == 0 else
                                                  round(r["nearest_neighbour_inside"]["mean"], 4) for r in rs],
            "nearest_neighbour_inside_episodes": [r["nearest_neighbour_inside"]["n"] for r in rs],  # measured
            "fraction_inside": stats.mean_interval([r["fraction_inside"]["mean"] for r in rs], boot),
            "convergence_episode": [r["convergence_episode"] for r in rs],
            "convergence_by_tolerance": {band: {f: [r["convergence_by_tolerance"][band][f] for r in rs] for f in by}
                                         for band, by in rs[0].get("convergence_by_tolerance", {}).items()},
            "core_seconds": stats.mean_interval([r["core_seconds"] for r in rs], boot),
            "robustness": {name: {"coverage": stats.mean_interval([r["robustness"][name]["coverage"] for r in rs],
                                                                  boot),
                                  "per_seed": [round(r["robustness"][name]["coverage"], 4) for r in rs]}
                           for name in scenarios},
        }
    return {"runs": runs, "baselines": baselines}
