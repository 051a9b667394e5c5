"""The ``train`` verb as a user meets it: killed and resumed, refused before anything is written, and every
bad input named."""

from __future__ import annotations

import json
import re
import shlex
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from replicate.core import artifacts
from replicate.core.artifacts import read_text
from replicate.learn.train import CURVE, load_actors

from ..command import SMALL, cli, wait_for_checkpoint


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_curve(tmp_path):
    """Kill a run after its first checkpoints; `--resume RUN` finishes it with the curve of an uninterrupted run."""
    common = [*SMALL, "--set", "configs.tuned.select_every=20",
              "train", "--config", "tuned", "--method", "cr", "--region", "square", "--episodes", "80",
              "--seed", "4", "--checkpoint-every", "10", "--no-progress"]
    assert cli(*common, "--out", str(tmp_path / "whole")).wait(timeout=600) == 0

    proc = cli(*common, "--out", str(tmp_path / "cut"))
    wait_for_checkpoint(tmp_path / "cut")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    cut_rows = len(read_text(tmp_path / "cut" / CURVE).splitlines()) - 1
    assert 0 < cut_rows < 80, "the run must be cut before its end"
    refused = cli(*common, "--out", str(tmp_path / "cut"), stderr=subprocess.PIPE, text=True)
    assert refused.wait(timeout=300) == 2 and f"replicate train --resume {tmp_path / 'cut'}" in refused.stderr.read()
    assert cli("train", "--resume", str(tmp_path / "cut"), "--no-progress").wait(timeout=600) == 0  # nothing else
    whole = artifacts.read_curve(tmp_path / "whole" / CURVE)
    resumed = artifacts.read_curve(tmp_path / "cut" / CURVE)
    for column in ("team_reward", "coverage", "critic_loss"):
        np.testing.assert_array_equal(resumed[column], whole[column])
    assert (tmp_path / "cut" / "validation.csv").read_text() == (tmp_path / "whole" / "validation.csv").read_text()
    for a, b in zip(load_actors(tmp_path / "cut" / "actors.pt")[0].parameters(),
                    load_actors(tmp_path / "whole" / "actors.pt")[0].parameters()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    again = cli("train", "--resume", str(tmp_path / "cut"), stderr=subprocess.PIPE, text=True)
    assert again.wait(timeout=300) == 2 and "already finished" in again.stderr.read()


@pytest.mark.slow
def test_interrupted_run_resumes_with_the_command_it_prints(tmp_path):
    """Ctrl-C prints the command that continues the run; that command, exactly, finishes it."""
    out, log = tmp_path / "my run", tmp_path / "stderr.txt"
    with open(log, "w") as stderr:
        proc = cli(*SMALL, "train", "--config", "tuned", "--method", "cr", "--region", "square", "--episodes", "400",
                   "--checkpoint-every", "10", "--no-progress", "--out", str(out), stderr=stderr, text=True)
        wait_for_checkpoint(out)
        # 400 episodes outlast the first checkpoints by far. A Ctrl-C that lands while numba compiles a kernel the
        # run meets for the first time (a fresh clone has no numba cache) can be lost inside the compiler and the
        # run goes on: as a user would, press it again after a pause, until the run says it was interrupted.
        for _ in range(20):
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=5)
                break
            except subprocess.TimeoutExpired:
                if "replicate: interrupted" in log.read_text():
                    break
        code = proc.wait(timeout=300)
    err = log.read_text()
    assert code == 130, err
    hint = re.search(r"`(replicate train --resume .+?)`", err)
    assert hint, "the interruption names the command that continues the run"
    argv = shlex.split(hint.group(1))
    assert argv[:3] == ["replicate", "train", "--resume"] and Path(argv[3]) == out
    assert cli(*argv[1:], "--no-progress").wait(timeout=600) == 0
    assert json.loads((out / "run.json").read_text())["status"] == "finished"
    assert not list(out.glob(".*.tmp")), "no partial files are left behind"


@pytest.mark.slow
def test_training_into_a_finished_run_leaves_it_unchanged(tmp_path):
    out = tmp_path / "done"
    args = [*SMALL, "train", "--config", "tuned", "--method", "sw", "--region", "square", "--episodes", "20",
            "--no-progress", "--out", str(out)]
    assert cli(*args).wait(timeout=600) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    refused = cli(*args, "--seed", "3", stderr=subprocess.PIPE, text=True)
    assert refused.wait(timeout=300) == 2 and "holds a finished run" in refused.stderr.read()
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    (out / "notes.txt").write_text("mine")
    assert cli(*args, "--seed", "3", "--force").wait(timeout=600) == 0
    assert not (out / "notes.txt").exists(), "--force clears the folder first"
    assert json.loads((out / "run.json").read_text())["seed"] == 3
    assert {oct(p.stat().st_mode & 0o777) for p in out.iterdir()} == {"0o644"}


def test_a_refused_schedule_leaves_no_folder(tmp_path, replicate):
    out = tmp_path / "never"
    code, err = replicate("--set", "train.checkpoint_every=0", "train", "--out", str(out))
    assert code == 2 and "checkpoint_every must be at least 1" in err
    code, err = replicate("--set", "configs.paper.n_envs=0", "train", "--out", str(out))
    assert code == 2 and "n_envs must be at least 1" in err
    assert not out.exists()


@pytest.mark.slow
def test_cli_train_and_evaluate_with_baseline(tmp_path):
    out = tmp_path / "run"
    proc = cli(*SMALL, "train", "--config", "tuned", "--method", "sw", "--region", "rectangle", "--episodes", "20",
               "--out", str(out), "--no-progress", stdout=subprocess.PIPE, text=True)
    assert proc.wait(timeout=600) == 0
    assert "in " in proc.stdout.read() and (out / "actors.pt").exists()
    assert cli("evaluate", "--run", str(out)).wait(timeout=600) == 0
    assert (out / "metrics.json").exists()
    target = tmp_path / "naive.json"
    assert cli("evaluate", "--baseline", "naive", "--region", "rectangle", "--out", str(target)).wait(600) == 0
    assert target.exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["train", "--region", "atlantis"], "unknown region 'atlantis'"),
        (["train", "--config", "best"], "unknown config 'best'"),
        (["--set", "train.epsiodes=3", "train"], "unknown key 'epsiodes'"),
        (["train", "--episodes", "15"], "must be a multiple of n_envs"),
        (["evaluate", "--baseline", "oracle", "--region", "square"], "unknown baseline 'oracle'"),
        (["train", "--resume", "/nonexistent/run"], "no such run folder"),
        (["train", "--seed", str(2**70), "--out", "/tmp/never-written"], "--seed must be a whole number"),
        (["train", "--seed", "-1"], "--seed must be a whole number from 0"),
        (["--set", "coverage.radius=-0.5", "train"], "coverage.radius must be above 0, got -0.5"),
        (["--set", "world.n_agents=1000", "train"], "world.n_agents must be in [1, 200], got 1000"),
        (["cover", "--region", "data/bedok_outline.geojson", "--radius-m", "nan", "--out", "/tmp/never-written"],
         "--radius-m must be a positive number"),
        (["cover", "--method", "cr", "--region", "data/bedok_outline.geojson", "--episodes", "0", "--out",
          "/tmp/never-written"],
         "--episodes must be at least 1"),
        (["cover", "--region", "data/bedok_outline.geojson", "--n-agents", "1000"], "--n-agents must be between"),
        (["act", "--policy", "p.pt", "--obs", "1,2;3"], "every row as long"),
        (["act", "--policy", "p.pt", "--obs", "nan,2;3,4"], "finite numbers"),
        (["evaluate", "--baseline", "naive", "--region", "square", "--out", "tests"], "is a folder"),
        (["train", "--out", "README.md"], "is a file, not a folder"),
    ],
)
def test_cli_errors_are_clear(args, message, replicate):
    code, err = replicate(*args)
    assert code == 2 and message in err
    assert not Path("/tmp/never-written").exists()


def test_invalid_yaml_names_the_file_and_line(tmp_path, replicate):
    bad = tmp_path / "params.yaml"
    bad.write_text("world: [unclosed\n")
    code, err = replicate("--params", str(bad), "train")
    assert code == 2 and f"{bad}: not valid YAML at line 2" in err


def test_a_number_in_set_is_a_number_and_the_version_is_printed(capsys):
    """``--set`` reads ``1e-9`` (a string to YAML 1.1) as the number it is; ``--version`` names the installed
    package's version."""
    from importlib.metadata import version

    from replicate.toolkit.cli import main
    from replicate.toolkit.cli.inputs import overrides

    assert overrides(["a=1e-9", "b=2", "c=abc", "d=-3E+2"]) == {"a": 1e-9, "b": 2, "c": "abc", "d": -300.0}
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"replicate {version('buoy-swarm-coverage')}"


def test_a_full_disk_names_the_file_and_the_run_says_it_stopped(replicate, tmp_path, monkeypatch):
    """ENOSPC while a checkpoint is written: the message names the file and the fix (exit 2), no temporary file is
    left, and run.json says the run stopped (not "running"), so `--resume` is what to do once there is room."""
    import errno

    import torch

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", full)
    out = tmp_path / "run"
    code, err = replicate(*SMALL, "train", "--config", "tuned", "--method", "cr", "--region", "square",
                          "--episodes", "50", "--checkpoint-every", "10", "--out", str(out))
    assert code == 2 and "No space left on device (writing" in err and "checkpoint" in err, err
    assert "free some space" in err
    record = json.loads((out / "run.json").read_text())
    assert record["status"] == "stopped" and "No space left" in record["stopped_by"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no half-written temporary file
