"""The general policy's training: every seed of ``general.seeds`` in a process of its own, the best-validated one
exported as the policy every lake gets.

Layout: ``OUT/runs/general-sSEED/{actor.pt, curve.csv.gz, run.json}`` (``general_train``), ``OUT/general.pt`` (the
exported policy of the seed with the best validation coverage, carrying the baselines' gains of
``tuning.general_baselines``) and ``OUT/summary.json`` (each seed's validation and time, the one kept). A seed
already finished with identical settings is kept, so adding seeds trains only the new ones.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from .. import artifacts
from ..config import load_params, to_dict
from ..executor import map_jobs
from ..export import export_general
from ..general_train import GeneralTrainer
from ..train import training_process

GENERAL_VERSION = 1  # raised when the general training's arithmetic changes: older runs are trained again


def general_identity(params, seed: int) -> dict:
    """What makes two general runs the same run: the version, the seed and every value they train with."""
    return {"general_version": GENERAL_VERSION, "seed": seed, "general": to_dict(params.general),
            "world": to_dict(params.world), "coverage": to_dict(params.coverage),
            "cr_reward": to_dict(params.cr_reward), "regions": to_dict(params.regions)}


def finished_general(out: Path, identity: dict) -> dict | None:
    """The summary of a finished general run in ``out`` with this identity, else None."""
    path = out / "run.json"
    if not (path.exists() and (out / "actor.pt").exists()):
        return None
    summary = json.loads(path.read_text())
    same = summary.get("identity") == json.loads(json.dumps(identity))
    return summary if same and summary.get("status") == "finished" else None


def _train_seed(job: dict) -> dict:
    """Train one seed (a job of ``train_general``), or keep it when finished with identical settings."""
    training_process()
    params = load_params(job["params"])
    out, identity = Path(job["out"]), general_identity(params, job["seed"])
    done = finished_general(out, identity)
    if done is not None:
        return {**done, "skipped": True}
    summary = GeneralTrainer(params, job["seed"], out, progress=False).run()
    summary["identity"] = identity
    artifacts.write_json(out / "run.json", summary)
    return summary


def train_general(params_path: str, out_dir: str, gains_path: str | None, workers: int,
                  executor: str = "local") -> dict:
    """Train every seed of ``general.seeds`` (``workers`` processes, or Ray tasks), export the best-validated
    seed's actor to ``OUT/general.pt`` with the baselines' gains of ``gains_path``, write ``OUT/summary.json``."""
    params = load_params(params_path)
    out = Path(out_dir)
    jobs = [{"params": params_path, "seed": s, "out": str(out / "runs" / f"general-s{s}")}
            for s in params.general.seeds]
    t0 = time.perf_counter()
    runs = map_jobs(_train_seed, jobs, executor, workers)
    wall = time.perf_counter() - t0
    best = max(runs, key=lambda r: r["selected_validation_coverage"])
    gains = json.loads(Path(gains_path).read_text()) if gains_path else None
    export_general(out / "runs" / f"general-s{best['seed']}" / "actor.pt", out / "general.pt",
                   params.world.sensitivity, gains)
    summary = {"kept_seed": best["seed"], "wall_seconds": round(wall, 1), "runs": [
        {k: r.get(k) for k in ("seed", "selected_episode", "selected_validation_coverage", "cpu_seconds",
                               "wall_seconds")} | {"skipped": r.get("skipped", False)} for r in runs]}
    artifacts.write_json(out / "summary.json", summary)
    return summary
