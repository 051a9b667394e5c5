"""Ctrl-C anywhere ends a command with one line and exit 130: while it starts, and inside an Optuna study (whose
own log of the stopped trial, with its traceback, is left out)."""

from __future__ import annotations

import logging
import sys

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
