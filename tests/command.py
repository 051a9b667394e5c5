"""The ``replicate`` command as a user runs it, in a process of its own (for Ctrl-C, kill and resume), and
the small trainings the tests share."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from replicate.core.params import run_config
from replicate.learn.train import CURVE, Trainer

from .conftest import ROOT


def default_sigint() -> None:
    """In the child: Ctrl-C as a terminal delivers it. A suite started in the background by a shell without job
    control (``nohup make test &``) runs with SIGINT ignored, which children inherit; Python then never raises
    KeyboardInterrupt, and a test of Ctrl-C would see the run finish."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def cli(*args, **kw):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    kw.setdefault("cwd", ROOT)
    return subprocess.Popen([sys.executable, "-m", "replicate", *args], env=env, preexec_fn=default_sigint, **kw)


SMALL = ["--set", "configs.tuned.n_envs=10", "--set", "configs.tuned.maddpg.learning_starts=500",
         "--set", "configs.tuned.maddpg.batch_size=32"]


def small_trainer(params, region, out, seed=0, episodes=20, config="tuned", method="cr", **algo_changes):
    """A short run (or, with lists of seeds and folders, a stack of runs) that learns from its 500th transition."""
    rc = run_config(params, config, method)
    maddpg = algo_changes.pop("maddpg", dataclasses.replace(rc.algo.maddpg, learning_starts=500, batch_size=32))
    algo = dataclasses.replace(rc.algo, n_envs=10, maddpg=maddpg, **algo_changes)
    return Trainer(dataclasses.replace(rc, algo=algo), region, episodes, seed, out, 10, progress=False)


def wait_for_checkpoint(run: Path, timeout: float = 300) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline and not ((run / "checkpoint.pt").exists() and (run / CURVE).exists()
                                          and (run / CURVE).stat().st_size > 500):
        time.sleep(0.05)
