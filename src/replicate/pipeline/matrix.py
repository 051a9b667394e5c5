"""The training matrix of the pipeline's ``train`` stage: config × method × region × seed, one process per core.

A cell's seeds train together in one process (``train.Trainer`` stacks them; each run is bit for bit the run
trained alone), and the cells start longest first, so that the two cores finish together.

Layout: ``runs/NAME/{curve.csv.gz, actors.pt, run.json}`` with NAME = ``CONFIG-METHOD-REGION-sSEED``, and
``runs/summary.json`` (wall time per run). ``evaluate.evaluate_matrix`` and ``figures.make_figures`` read it.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from replicate.core import artifacts
from replicate.core.executor import map_jobs
from replicate.core.params import ablated_name, load_params, run_config, selection_only
from replicate.learn.process import training_process
from replicate.learn.runs import core_seconds, finished_run, run_identity, timed_by
from replicate.learn.train import train_runs
from replicate.world.regions import make_region


def run_name(config: str, method: str, region: str, seed: int) -> str:
    return f"{config}-{method}-{region}-s{seed}"


def _train_cell(job: dict) -> list[dict]:
    """Train the seeds of one (config, method, region) cell. A run already finished with these exact settings is
    kept (runs/ persists across repro); an interrupted one resumes from its checkpoint; the others train as one
    stack in this process."""
    training_process()  # this worker process trains
    params = load_params(job["params"])
    region = make_region(job["region"], params.regions[job["region"]], params.world.region_area)
    rc = run_config(params, job["config"], job["method"], job["region"])
    episodes, every = job["episodes"], params.train.checkpoint_every
    summaries, fresh = [], []
    for seed, out in zip(job["seeds"], map(Path, job["outs"])):
        done = finished_run(out, run_identity(rc, region, episodes, seed))
        if done is not None:
            summaries.append({**done, "skipped": True})
        elif (out / "checkpoint.pt").exists():
            summaries += train_runs(rc, region, episodes, [seed], [out], every, resume=True, progress=False)
        else:
            fresh.append((seed, out))
    if fresh:
        summaries += train_runs(rc, region, episodes, *map(list, zip(*fresh)), every, progress=False)
    return sorted(summaries, key=lambda s: s["seed"])


def run_cost(rc, episodes: int) -> float:
    """A rough estimate of one run's training seconds on this machine, only to start the longest cells first:
    per run of a stack of seeds (as ``_train_cell`` trains them), ~40 µs of environment per transition and per
    update 0.66 ms + 18.3 µs per minibatch row (``tuned`` at 128 and ``paper`` at 1024 took ~3.0 and ~19 ms per
    run when the pipeline trained each cell's seeds as one stack)."""
    cfg = rc.algo.maddpg
    transitions = episodes * rc.world.episode_length
    updates = max(transitions - cfg.learning_starts, 0) / cfg.update_every
    return 40e-6 * transitions + updates * (0.66e-3 + 18.3e-6 * cfg.batch_size)


def cell_seeds(params, config: str) -> tuple[int, ...]:
    """The training seeds of a cell: its config's reported seeds, or for an ablation config ``ablation.seeds``."""
    if config in params.configs:
        return params.train.seeds_of(config)
    return params.ablation.seeds


def ablation_cells(params) -> list[tuple[str, str, str]]:
    """(config, method, region) of the leave-one-out ablation runs; a selection-only change needs no run of its
    own (its "without" is the base run's last actors)."""
    ab = params.ablation
    return [(ablated_name(ab.base, c), ab.method, r) for c in ab.changes if not selection_only(params, c)
            for r in ab.regions]


def matrix_cells(params, configs, methods, regions, ablation: bool) -> list[tuple[str, str, str]]:
    """(config, method, region) of every run of the ``train`` stage: config × method × region, then with
    ``ablation`` the ablation's runs. Each cell is trained once per seed."""
    cells = [(c, m, r) for c in configs for m in methods for r in regions]
    return cells + (ablation_cells(params) if ablation else [])


def train_matrix(params_path: str, configs, methods, regions, episodes: int, runs_dir: str, workers: int,
                 ablation: bool = False, executor: str = "local"):
    """Train every config × method × region × seed of the config (``train.seeds``), ``workers`` processes at a
    time (one per core; with ``executor="ray"`` one Ray task per cell on the cluster's CPUs), then with
    ``ablation`` the runs of ``params.ablation`` (its seeds, same episodes). Each process trains one cell's seeds
    together (``_train_cell``), the costliest cells first.

    Run again, the matrix skips runs already finished with identical settings and resumes interrupted ones
    from their checkpoints, so adding seeds or a configuration trains only what is new."""
    params = load_params(params_path)
    cells = matrix_cells(params, configs, methods, regions, ablation)
    jobs = [
        {"params": params_path, "config": c, "method": m, "region": r, "seeds": list(cell_seeds(params, c)),
         "episodes": episodes, "outs": [str(Path(runs_dir) / run_name(c, m, r, s)) for s in cell_seeds(params, c)]}
        for c, m, r in cells
    ]
    jobs.sort(key=lambda j: -len(j["seeds"]) * run_cost(run_config(params, j["config"], j["method"], j["region"]),
                                                        episodes))
    t0 = time.perf_counter()
    summaries = [s for cell in map_jobs(_train_cell, jobs, executor, workers) for s in cell]
    wall = time.perf_counter() - t0
    keys = ("config", "method", "region", "seed", "wall_seconds", "final_coverage_last100")
    table = [{**{k: s[k] for k in keys}, "runs_in_process": s.get("runs_in_process", 1),
              "core_seconds": round(core_seconds(s), 2), "timed_by": timed_by(s), "skipped": s.get("skipped", False),
              "arithmetic": s.get("arithmetic")}
             for s in summaries]
    artifacts.write_json(Path(runs_dir) / "summary.json", {"wall_seconds": round(wall, 1), "runs": table})
    return wall, table


def pipeline_workers(requested: int) -> int:
    return max(1, min(requested, os.cpu_count() or 1))
