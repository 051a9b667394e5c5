"""Progress where no terminal draws a bar: log lines, each phase at once and a count now and then."""

from __future__ import annotations

import logging
import re

from replicate.core import progress


def test_a_bar_not_drawn_is_logged_by_phase_and_now_and_then(caplog, monkeypatch):
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.0)  # every count
    progress.log_lines(True)
    with caplog.at_level(logging.INFO, logger="replicate.progress"):
        with progress.bar(False, total=3, unit="phase", leave=False) as bar:
            bar.set_description("lake: the policy")
            bar.update()
            bar.set_description("lake: Lloyd")
            bar.update(2)
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "lake: the policy: 0/3 phases, 0 s"
    assert "lake: Lloyd: 1/3 phases, 0 s" in lines
    assert lines[-1] == "lake: Lloyd: 3/3 phases (done), 0 s" and lines.count(lines[-1]) == 1


def test_no_lines_unless_asked_and_a_bar_where_asked(caplog):
    with caplog.at_level(logging.INFO, logger="replicate.progress"):
        with progress.bar(False, total=2, desc="quiet") as bar:
            bar.update(2)
    assert not caplog.records
    assert not progress.bar(True, total=1).disable and progress.bar(False, total=1).disable


def test_a_command_without_a_terminal_logs_its_steps(replicate, caplog, tmp_path):
    with caplog.at_level(logging.INFO, logger="replicate.progress"):
        code, err = replicate("--set", "evaluate.episodes=2", "evaluate", "--baseline", "lloyd", "--region",
                              "square", "--out", str(tmp_path / "lloyd.json"))
    assert code == 0, err
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0].startswith("evaluating lloyd: 0/") and re.fullmatch(r".* steps \(done\), \d+ s", lines[-1])
    caplog.clear()
    code, err = replicate("--set", "evaluate.episodes=2", "evaluate", "--no-progress", "--baseline", "lloyd",
                          "--region", "square", "--out", str(tmp_path / "quiet.json"))
    assert code == 0 and not caplog.records  # asked for none


def worker_lines(_job) -> bool:
    return progress._lines


def test_worker_processes_leave_the_log_to_the_count_of_jobs(caplog):
    """`compare` and the pipeline's stages run lakes in worker processes: their phases would flood a log (thousands
    of lines); only the jobs' count is logged."""
    from replicate.core.executor import map_jobs

    progress.log_lines(True)
    with caplog.at_level(logging.INFO, logger="replicate.progress"):
        assert map_jobs(worker_lines, range(3), workers=2) == [False] * 3
    assert [r.getMessage() for r in caplog.records][-1] == "jobs: 3/3 jobs (done), 0 s"
