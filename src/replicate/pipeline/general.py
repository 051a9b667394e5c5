"""The general policy's stages: every seed of ``general.seeds`` trained in a process of its own, the
best-validated one exported as the policy every lake gets; then that policy, zero-shot, on the evaluation suite.

Layout: ``OUT/runs/general-sSEED/{actor.pt, curve.csv.gz, run.json}`` (``general_train``) and ``policy.pt`` (the
seed's exported policy, carrying the baselines' gains of ``tuning.general_baselines``), ``OUT/general.pt`` (the
policy of the seed with the best validation coverage, the one a user deploys) and ``OUT/summary.json`` (each
seed's validation, time and policy, the one kept). A seed already finished with identical settings is kept, so
adding seeds trains only the new ones. The same training on the tuning seeds of ``yardstick.seeds`` is the
yardstick's standing baseline (``train_yardstick``, the same layout without ``general.pt``).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

from replicate.compare.evaluate import evaluate_policy
from replicate.compare.planner import planner_teacher, teacher_identity
from replicate.compare.suite import SuiteCell, drift_heading, suite_cells, suite_event, suite_lake
from replicate.core import artifacts
from replicate.core.executor import map_jobs
from replicate.core.params import load_params
from replicate.learn.general_train import train_recorded
from replicate.learn.process import training_process
from replicate.learn.runs import KEPT_POLICY, SEED_POLICY, finished_general, general_identity, seed_folder
from replicate.toolkit.export import export_general
from replicate.world.regions import at_density


def _train_seed(job: dict) -> dict:
    """Train one seed (a job of ``train_general``), or keep it when finished with identical settings."""
    training_process()
    params = load_params(job["params"])
    out = Path(job["out"])
    gains = json.loads(Path(job["gains"]).read_text()) if job.get("gains") else None
    done = finished_general(out, general_identity(params, job["seed"], teacher_identity(params, gains)))
    if done is not None:
        return {**done, "skipped": True}
    return train_recorded(params, job["seed"], out, teacher=planner_teacher(params, gains),
                          taught_by=teacher_identity(params, gains))


def train_seeds(params_path: str, out: Path, seeds, gains_path: str | None, workers: int,
                executor: str) -> tuple[list[dict], float]:
    """Train every seed of ``seeds`` into ``OUT/runs/general-sSEED`` (``workers`` processes, or Ray tasks; a seed
    finished with identical settings is kept) and export each one's actor to ``policy.pt`` there with the
    baselines' gains of ``gains_path``. → (each seed's summary, flagged ``skipped`` when kept; the wall time)."""
    params = load_params(params_path)
    jobs = [{"params": params_path, "seed": s, "out": str(seed_folder(out, s)), "gains": gains_path} for s in seeds]
    t0 = time.perf_counter()
    runs = map_jobs(_train_seed, jobs, executor, workers)
    wall = time.perf_counter() - t0
    gains = json.loads(Path(gains_path).read_text()) if gains_path else None
    for run in runs:
        run_dir = seed_folder(out, run["seed"])
        export_general(run_dir / "actor.pt", run_dir / SEED_POLICY, params.world.sensitivity, gains)
    return runs, wall


def seed_rows(runs: list[dict]) -> list[dict]:
    """The summary's row of every seed: its validation, its time and its policy file (relative to OUT)."""
    return [{k: r.get(k) for k in ("seed", "selected_episode", "selected_validation_coverage", "cpu_seconds",
                                   "wall_seconds")} | {"policy": str(seed_folder(Path(), r["seed"]) / SEED_POLICY)}
            for r in runs]


def with_stage_times(summary: dict, runs: list[dict], wall: float) -> dict:
    """``summary`` as a stage reports it: with its wall time and which seeds were kept from an earlier run."""
    return summary | {"wall_seconds": round(wall, 1), "runs": [
        row | {"skipped": r.get("skipped", False)} for row, r in zip(summary["runs"], runs, strict=True)]}


def train_general(params_path: str, out_dir: str, gains_path: str | None, workers: int,
                  executor: str = "local") -> dict:
    """Train and export every seed of ``general.seeds`` (``train_seeds``), copy the best-validated seed's policy
    to ``OUT/general.pt``, write ``OUT/summary.json`` (the same bytes when nothing was trained again, so the suite
    downstream does not rerun). → the summary, with the stage's wall time and which seeds were kept."""
    params = load_params(params_path)
    out = Path(out_dir)
    runs, wall = train_seeds(params_path, out, params.general.seeds, gains_path, workers, executor)
    best = max(runs, key=lambda r: r["selected_validation_coverage"])
    kept = seed_folder(out, best["seed"]) / SEED_POLICY
    artifacts.atomic_write_bytes(out / KEPT_POLICY, kept.read_bytes())
    summary = {"kept_seed": best["seed"], "runs": seed_rows(runs)}
    artifacts.write_json(out / "summary.json", summary)
    return with_stage_times(summary, runs, wall)


def train_yardstick(params_path: str, out_dir: str, gains_path: str | None, workers: int,
                 executor: str = "local") -> dict:
    """The yardstick's standing baseline: the general training's current values on the tuning seeds of
    ``yardstick.seeds`` (never reported), trained and exported as ``train_general`` does, into ``OUT/runs`` and
    ``OUT/summary.json``; ``replicate compare`` reads it when no ``--baseline`` is given, so a candidate trains
    only its own seeds. → the summary, with the stage's wall time and which seeds were kept."""
    params = load_params(params_path)
    out = Path(out_dir)
    runs, wall = train_seeds(params_path, out, params.yardstick.seeds, gains_path, workers, executor)
    summary = {"runs": seed_rows(runs)}
    artifacts.write_json(out / "summary.json", summary)
    return with_stage_times(summary, runs, wall)


def _suite_lake(job: dict) -> list[dict]:
    """Every cell of one lake and fleet (a job of ``evaluate_general``): every seed's policy and the baselines
    (``evaluate.evaluate_policy``), the best layout computed once per fleet left in service."""

    training_process()
    params = load_params(job["params"])
    su = params.general.suite
    params = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, episodes=su.episodes))
    region, drawn_for = suite_lake(params, job["region"])
    region = at_density(region, drawn_for, job["n_agents"])
    kept, *others = job["policies"].items()  # the kept seed's, then the others'
    out = []
    for cell in map(lambda c: SuiteCell(**c), job["cells"]):
        lose, current = suite_event(su, cell.event, cell.n_agents, drift_heading(params.evaluate.seed, cell),
                                    region.polygon)
        result = evaluate_policy(kept[1], region, params, cell.n_agents, cell.start, lose, current,
                                 seeds=dict(others), decentralised=True, planner=True)
        seeds = {kept[0]: {k: result[k] for k in ("coverage", "max_outside_m")}, **result.get("seeds", {})}
        out.append({**dataclasses.asdict(cell), "lose": lose, "current": result["current"],
                    "coverage": result["coverage"], "seeds": seeds,
                    "baselines": result["baselines"], "max_outside_m": result["max_outside_m"],
                    "steps": result["steps"]})
    return out


def seed_policies(policies_dir: str | Path) -> dict[str, str]:
    """{"sSEED": policy file} of a ``train_general`` folder, the kept seed first (``OUT/summary.json``)."""
    root = Path(policies_dir)
    summary = json.loads((root / "summary.json").read_text())
    runs = sorted(summary["runs"], key=lambda r: r["seed"] != summary["kept_seed"])
    return {f"s{r['seed']}": str(root / r["policy"]) for r in runs}


def evaluate_general(params_path: str, policies_dir: str, out: str, workers: int, executor: str = "local") -> dict:
    """Every seed's policy of ``policies_dir`` (``train_general``) on every cell of the suite (``suite_cells``),
    one job per lake and fleet → ``out`` (JSON: the cells, with the kept policy's, each seed's and every
    baseline's coverage)."""
    params = load_params(params_path)
    policies = seed_policies(policies_dir)
    groups: dict[tuple[str, int], list[dict]] = {}
    for cell in suite_cells(params):
        groups.setdefault((cell.region, cell.n_agents), []).append(dataclasses.asdict(cell))
    jobs = [{"params": params_path, "policies": policies, "region": r, "n_agents": n, "cells": cells}
            for (r, n), cells in sorted(groups.items(), key=lambda kv: -kv[0][1])]  # the largest fleets first
    t0 = time.perf_counter()
    cells = [c for group in map_jobs(_suite_lake, jobs, executor, workers) for c in group]
    result = {"policy": str(Path(policies_dir) / KEPT_POLICY), "seeds": list(policies),
              "wall_seconds": round(time.perf_counter() - t0, 1), "cells": cells}
    artifacts.write_json(out, result)
    return result
