"""Ctrl-C anywhere ends a command with one line and exit 130: while it starts, and inside an Optuna study (whose
own log of the stopped trial, with its traceback, is left out)."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from replicate.compare.tuning import QuietInterrupt
from replicate.toolkit.cli import command


def test_ctrl_c_while_the_command_starts_is_one_line(monkeypatch, capsys):
    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.setattr(command, "parsed", interrupted)
    assert command.main(["train"]) == 130
    assert capsys.readouterr().err == "replicate: interrupted\n"


def test_a_trial_stopped_by_ctrl_c_is_not_logged_as_a_failure():
    def record(exc: BaseException, message: str) -> logging.LogRecord:
        try:
            raise exc
        except BaseException:
            info = sys.exc_info()
        return logging.LogRecord("optuna", logging.WARNING, __file__, 1, message, None, info)

    quiet = QuietInterrupt()
    assert not quiet.filter(record(KeyboardInterrupt(), "Trial 3 failed with value None."))
    assert quiet.filter(record(ValueError("a real failure"), "Trial 4 failed with value None."))


def test_cover_interrupted_after_its_training_keeps_the_trained_run(monkeypatch, capsys, tmp_path):
    """Ctrl-C in `cover --method cr` once training has finished (while Lloyd is evaluated): the finished run
    stays, and the message names the command that measures it; interrupted before any training, nothing stays."""
    import json

    from replicate.toolkit.cli import cover

    def trained_then_interrupted(args, params, out, tempfile):
        (out / "run").mkdir(parents=True)
        (out / "run" / "run.json").write_text(json.dumps({"status": "finished"}))
        raise KeyboardInterrupt

    monkeypatch.setattr(cover, "cover_into", trained_then_interrupted)
    lake = str(Path(__file__).resolve().parents[2] / "data" / "bedok_outline.geojson")
    out = tmp_path / "c"
    assert command.main(["cover", "--method", "cr", "--region", lake, "--out", str(out)]) == 130
    assert (out / "run" / "run.json").exists()
    assert f"`replicate evaluate {out / 'run'}` measures it" in capsys.readouterr().err

    def interrupted(args, params, out, tempfile):
        (out / "run").mkdir(parents=True)
        raise KeyboardInterrupt

    monkeypatch.setattr(cover, "cover_into", interrupted)
    assert command.main(["cover", "--method", "cr", "--region", lake, "--out", str(tmp_path / "d")]) == 130
    assert not (tmp_path / "d").exists()


def test_cover_force_interrupted_puts_the_old_result_back_and_says_so(monkeypatch, capsys, tmp_path):
    """Ctrl-C in `cover --force` over a finished result: the old result is put back, and the message says that
    rather than pointing at a run that is no longer there."""
    import json

    from replicate.toolkit.cli import cover

    out = tmp_path / "c"
    (out / "run").mkdir(parents=True)
    (out / "run" / "run.json").write_text(json.dumps({"status": "finished", "seed": "old"}))

    def trained_then_interrupted(args, params, out, tempfile):
        (out / "run").mkdir(parents=True)
        (out / "run" / "run.json").write_text(json.dumps({"status": "finished", "seed": "new"}))
        raise KeyboardInterrupt

    monkeypatch.setattr(cover, "cover_into", trained_then_interrupted)
    lake = str(Path(__file__).resolve().parents[2] / "data" / "bedok_outline.geojson")
    assert command.main(["cover", "--method", "cr", "--region", lake, "--out", str(out), "--force"]) == 130
    assert json.loads((out / "run" / "run.json").read_text())["seed"] == "old"
    assert f"what {out} held before is back in place" in capsys.readouterr().err
