"""Nothing lost: an output is claimed for the length of the command that writes it. A second writer is refused by
name, a killed writer's lock is taken over, and ``--force`` keeps the old result until the new one is complete."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from replicate.core.outputs import lock_path

from ..command import cli


def test_a_second_writer_is_refused_and_the_first_result_is_intact(tmp_path, replicate):
    """While one command writes ``same.json`` (its lock held by a live process), another is refused by name and
    changes nothing; once the first is done, the path is free again."""
    out = tmp_path / "same.json"
    out.write_text('{"first": true}\n')
    first = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock_path(out).write_text(f"{first.pid}\n")
        code, err = replicate("evaluate", "--baseline", "naive", "--region", "square", "--out", str(out), "--force")
        assert code == 2 and f"another replicate command (process {first.pid}) is writing it" in err
        assert out.read_text() == '{"first": true}\n' and lock_path(out).read_text() == f"{first.pid}\n"
    finally:
        first.kill()
        first.wait()
    # its process is gone (a command killed with kill -9): the lock is taken over, and released at the end
    code, err = replicate("--set", "evaluate.episodes=2", "evaluate", "--baseline", "naive", "--region", "square",
                          "--out", str(out), "--force")
    assert code == 0, err
    assert json.loads(out.read_text())["coverage"]["n"] == 2 and not lock_path(out).exists()


@pytest.mark.slow
def test_two_commands_racing_for_one_output(tmp_path):
    """Two ``evaluate`` commands at once to the same --out: the one that claims it first writes it, the other is
    refused by name and exits 2."""
    out = tmp_path / "same.json"
    args = ["--set", "evaluate.episodes=40", "evaluate", "--baseline", "lloyd", "--region", "bedok", "--out", str(out)]
    first = cli(*args, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not lock_path(out).exists() and first.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    second = cli(*args, stderr=subprocess.PIPE, text=True)
    assert second.wait(timeout=300) == 2 and "is writing it" in second.stderr.read()
    assert first.wait(timeout=600) == 0
    assert json.loads(out.read_text())["coverage"]["n"] == 40 and not lock_path(out).exists()


def finished_folder(path, marker: str) -> None:
    path.mkdir(parents=True)
    (path / "run.json").write_text(json.dumps({"status": "finished", "config": "tuned", "method": "cr",
                                               "region": "square", "seed": 0, "episodes": 10, "marker": marker}))


def test_force_then_ctrl_c_puts_the_old_result_back(tmp_path, replicate, monkeypatch):
    """``--force`` over a finished run, then Ctrl-C in the middle of the new one: the old run is back in place,
    nothing of the new one is left, and the command says so (exit 130)."""
    from replicate.learn import train as training

    out = tmp_path / "run"
    finished_folder(out, "the old run")

    def interrupted(rc, region, episodes, seed, run_dir, **kw):
        (run_dir / "curve.csv.gz").write_bytes(b"half a curve")
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "train", interrupted)
    code, err = replicate("train", "--episodes", "50", "--out", str(out), "--force", "--no-progress")
    assert code == 130 and "holds the run it held before" in err
    assert json.loads((out / "run.json").read_text())["marker"] == "the old run"
    assert sorted(p.name for p in out.iterdir()) == ["run.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"], "no lock, nothing moved aside, left behind"


def test_force_replaces_the_old_result_once_the_new_one_is_complete(tmp_path, replicate, monkeypatch):
    from replicate.learn import train as training

    out = tmp_path / "run"
    finished_folder(out, "the old run")

    def finished(rc, region, episodes, seed, run_dir, **kw):
        assert not (run_dir / "run.json").exists(), "the new run starts in an empty folder"
        summary = {"config": "tuned", "method": "cr", "region": "square", "wall_seconds": 1.0,
                   "final_coverage_last100": 0.5}
        (run_dir / "run.json").write_text(json.dumps({**summary, "marker": "the new run"}))
        return summary

    monkeypatch.setattr(training, "train", finished)
    code, err = replicate("train", "--episodes", "50", "--out", str(out), "--force", "--no-progress")
    assert code == 0, err
    assert json.loads((out / "run.json").read_text())["marker"] == "the new run"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_run_interrupted_before_its_first_checkpoint_is_not_told_to_resume(tmp_path, replicate, monkeypatch):
    from replicate.learn import train as training

    def interrupted(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "train", interrupted)
    code, err = replicate("train", "--episodes", "50", "--out", str(tmp_path / "new"), "--no-progress")
    assert code == 130 and "--resume" not in err and "no checkpoint was written yet" in err
    assert os.listdir(tmp_path) == ["new"]


def test_cover_force_then_ctrl_c_keeps_the_old_result(tmp_path, replicate, monkeypatch):
    """The case a user met: ``cover --force`` over a finished result, then Ctrl-C: the old result survives."""
    from replicate.toolkit.cli import cover

    out = tmp_path / "lake"
    out.mkdir()
    (out / "summary.json").write_text('{"coverage": "the old result"}\n')

    def interrupted(args, params, folder, tempfile):
        (folder / "outline.geojson").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(cover, "cover_into", interrupted)
    code, _ = replicate("cover", "--region", "data/bedok_outline.geojson", "--out", str(out), "--force")
    assert code == 130
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]
    assert (out / "summary.json").read_text() == '{"coverage": "the old result"}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lake"]


def test_an_interrupted_cover_training_can_be_resumed(tmp_path, replicate, monkeypatch):
    """``cover --method cr`` records its lake in the run folder before it trains, so a training interrupted after a
    checkpoint continues with ``train --resume`` (it once answered "unknown region"), as the command says."""
    from replicate.toolkit import cover
    from replicate.world.regions import read_run_region

    def interrupted(rc, region, episodes, seed, run_dir, *args, **kw):
        assert read_run_region(run_dir).name == "bedok_outline", "the lake is recorded before training"
        (run_dir / "checkpoint.pt").write_bytes(b"a checkpoint")
        raise KeyboardInterrupt

    monkeypatch.setattr(cover, "train", interrupted)
    code, err = replicate("cover", "--method", "cr", "--region", "data/bedok_outline.geojson", "--episodes", "50",
                          "--out", str(tmp_path / "lake"), "--no-progress")
    assert code == 130 and f"`replicate train --resume {tmp_path / 'lake' / 'run'}` continues the training" in err
    assert (tmp_path / "lake" / "run" / "checkpoint.pt").exists()
