"""The training matrix of the pipeline's ``train`` stage: config × method × region × seed, one process per core.

Layout: ``runs/NAME/{curve.csv.gz, actors.pt, run.json}`` with NAME = ``CONFIG-METHOD-REGION-sSEED``, and
``runs/summary.json`` (wall time per run). ``evaluate.evaluate_matrix`` and ``figures.make_figures`` read it.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from . import artifacts
from .config import load_params, run_config, selection_only
from .regions import make_region


def run_name(config: str, method: str, region: str, seed: int) -> str:
    return f"{config}-{method}-{region}-s{seed}"


def _train_one(job: dict) -> dict:
    import torch

    from .train import finished_run, run_identity, train

    torch.set_num_threads(1)
    params = load_params(job["params"])
    region = make_region(job["region"], params.regions[job["region"]], params.world.region_area)
    rc = run_config(params, job["config"], job["method"], job["region"])
    out = Path(job["out"])
    done = finished_run(out, run_identity(rc, region, job["episodes"], job["seed"]))
    if done is not None:  # already trained with these exact settings (runs/ persists across repro)
        return {**done, "skipped": True}
    resume = (out / "checkpoint.pt").exists()
    summary = train(rc, region, job["episodes"], job["seed"], out, params.train.checkpoint_every, resume, False)
    (out / "checkpoint.pt").unlink(missing_ok=True)  # the replay buffer is ~100 MB: not a pipeline output
    return summary


def ablation_cells(params) -> list[tuple[str, str, str]]:
    """(config, method, region) of the leave-one-out ablation runs; a selection-only change needs no run of its
    own (its "without" is the base run's last actors)."""
    ab = params.ablation
    return [(f"{ab.base}-without-{c}", ab.method, r) for c in ab.changes if not selection_only(params, c)
            for r in ab.regions]


def matrix_cells(params, configs, methods, regions, ablation: bool) -> list[tuple[str, str, str]]:
    """(config, method, region) of every run of the ``train`` stage: config × method × region, then with
    ``ablation`` the ablation's runs. Each cell is trained once per seed."""
    cells = [(c, m, r) for c in configs for m in methods for r in regions]
    return cells + (ablation_cells(params) if ablation else [])


def train_matrix(params_path: str, configs, methods, regions, seeds, episodes: int, runs_dir: str, workers: int,
                 ablation: bool = False):
    """Train every config × method × region × seed, ``workers`` processes at a time (one per core), then with
    ``ablation`` the runs of ``params.ablation`` (same seeds and episodes).

    Run again, the matrix skips runs already finished with identical settings and resumes interrupted ones
    from their checkpoints, so adding seeds or a configuration trains only what is new."""
    cells = matrix_cells(load_params(params_path), configs, methods, regions, ablation)
    jobs = [
        {"params": params_path, "config": c, "method": m, "region": r, "seed": s, "episodes": episodes,
         "out": str(Path(runs_dir) / run_name(c, m, r, s))}
        for c, m, r in cells for s in seeds
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers) as pool:
        summaries = list(pool.map(_train_one, jobs))
    wall = time.perf_counter() - t0
    keys = ("config", "method", "region", "seed", "wall_seconds", "final_coverage_last100")
    table = [{**{k: s[k] for k in keys}, "skipped": s.get("skipped", False)} for s in summaries]
    artifacts.write_json(Path(runs_dir) / "summary.json", {"wall_seconds": round(wall, 1), "runs": table})
    return wall, table


def pipeline_workers(requested: int) -> int:
    return max(1, min(requested, os.cpu_count() or 1))
