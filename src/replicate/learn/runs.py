"""A training run's record: what makes two runs the same run (their identity: the version of the training's
arithmetic and every value they train with), whether a folder holds a finished run of that identity, where a
stage keeps a general seed, and one core's time for a run. The pipeline keeps a finished run of the same identity
instead of training it again."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from replicate.core.params import RunConfig
from replicate.core.schema import to_dict
from replicate.world.geometry import region_key
from replicate.world.regions import Region

# Part of every run's identity: raise it with any change that alters the numbers a run produces (the update's
# arithmetic, the environment, the rewards), so that runs trained by older code are retrained, not reused.
# 1: autograd update; 2: hand-written gradients in their fastest matmul forms (maddpg_by_hand.py);
# 3: a forward pass's narrow outputs (64 → 1, 64 → 2) by plain bmm, no longer transposed; 4: the autograd update
# again (the written-out gradients were 1.13-1.18x faster at the paper's batch, under the 1.3x that kept them), and
# eq. (5)'s exact contacts read with closed sets under the geofence too.
TRAINING_VERSION = 4


def run_identity(rc: RunConfig, region: Region, episodes: int, seed: int) -> dict:
    """What makes two runs the same run: checked on resume, and by the pipeline to skip finished runs."""
    return {
        "training_version": TRAINING_VERSION,
        "config": rc.config_name,
        "method": rc.method_name,
        "region": region.name,
        "region_key": region_key(region.polygon),
        "seed": seed,
        "episodes": episodes,
        "params": to_dict(rc, drop_defaults=True),
    }


def core_seconds(summary: dict) -> float:
    """One core's time for a run: its process's CPU time (``cpu_seconds``; one thread, so other work on the machine
    does not inflate it) shared among the runs trained in it, or for a run that recorded only its wall time, that
    (runs trained one per process do not record ``runs_in_process``)."""
    return summary.get("cpu_seconds", summary["wall_seconds"]) / summary.get("runs_in_process", 1)


def timed_by(summary: dict) -> str:
    """``cpu`` when ``core_seconds`` is the run's CPU time, ``wall`` when only its wall time was recorded (then
    a second process on the core inflates it)."""
    return "cpu" if "cpu_seconds" in summary else "wall"


def finished_run(out: str | Path, identity: dict) -> dict | None:
    """The summary of a finished run in ``out`` with this identity, else None."""

    path = Path(out) / "run.json"
    if not (path.exists() and (Path(out) / "actors.pt").exists()):
        return None
    summary = json.loads(path.read_text())
    same = all(summary.get(k) == v for k, v in identity.items())
    return summary if same and summary.get("status") == "finished" else None


# ---- a general run: one policy for any lake ------------------------------------------------------------------
GENERAL_VERSION = 4  # raised when the general training's arithmetic changes: older runs are trained again
# 2: the update runs on the buoys in service only and applies φ's last layer to the pooled mean (float rounding)
# 3: a velocity over the ground is the buoy's displacement over the last step / dt (the shore's stop included)
# 4: the exploration σ of the per-region training's rounding (``schedules.noise_sigma``)
KEPT_POLICY = "general.pt"  # the best-validated seed's policy, the one a user deploys
SEED_POLICY = "policy.pt"  # each seed's exported policy, in its run folder


def identity_of(section) -> dict:
    """A section as a run's identity records it: ``to_dict``, less every value its section lists as ``OPTIONAL``
    that holds its default (a value added after runs were trained leaves them valid until it is used)."""
    out = {}
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        if f.name in getattr(section, "OPTIONAL", ()) and value == f.default:
            continue
        out[f.name] = identity_of(value) if dataclasses.is_dataclass(value) else to_dict(value)
    return out


def general_identity(params, seed: int, teacher: dict | None = None) -> dict:
    """What makes two general runs the same run: the version, the seed and every value they train with, and where
    it imitates a teacher (``general.learner.imitation``), what makes the teacher that one (``teacher``: the
    planner's ``compare.planner.teacher_identity``)."""
    trained = {k: v for k, v in identity_of(params.general).items()
               if k not in ("seeds", "suite")}  # what it trained with, not how it is evaluated
    taught = {} if params.general.learner.imitation == "none" else {"teacher": teacher}
    return {"general_version": GENERAL_VERSION, "seed": seed, "general": trained,
            "world": identity_of(params.world), "coverage": identity_of(params.coverage),
            "cr_reward": identity_of(params.cr_reward), "regions": to_dict(params.regions), **taught}


def finished_general(out: Path, identity: dict) -> dict | None:
    """The summary of a finished general run in ``out`` with this identity, else None."""
    path = out / "run.json"
    if not (path.exists() and (out / "actor.pt").exists()):
        return None
    summary = json.loads(path.read_text())
    same = summary.get("identity") == json.loads(json.dumps(identity))
    return summary if same and summary.get("status") == "finished" else None


def seed_folder(out: Path, seed: int) -> Path:
    """A seed's run folder in a stage's output ``out``."""
    return out / "runs" / f"general-s{seed}"
