"""Progress as a user sees it: a bar on a terminal, a log line now and then where the output is a log or a pipe
(no carriage returns), nothing when asked (``--no-progress``, ``TQDM_DISABLE``).

``bar(enabled, **tqdm_options)`` is the one way the package opens a progress bar: ``enabled`` True draws the bar,
None draws it only on a terminal, False draws none; a bar not drawn is written as log lines (``replicate.progress``,
INFO) once the command line has asked for them with ``log_lines(True)``: every phase a bar names, and its count
every ``LOG_EVERY_S`` seconds.
"""

from __future__ import annotations

import io
import logging
import sys
import time

from tqdm.auto import tqdm

LOG_EVERY_S = 15.0  # a log line at most this often while a count advances (each named phase is logged at once)
log = logging.getLogger("replicate.progress")
_lines = False  # the command line's choice: log lines where no bar is drawn


def log_lines(enabled: bool) -> None:
    """Write the progress of bars not drawn as log lines (the command line, when its output is not a terminal)."""
    global _lines
    _lines = enabled


class LoggedBar(tqdm):
    """A tqdm whose display is a log line: its phase whenever the description changes, and its count at most
    every ``LOG_EVERY_S`` seconds and when it completes."""

    def __init__(self, *args, **kwargs):
        self._logged_at, self._logged = -float("inf"), (None, False)
        super().__init__(*args, file=io.StringIO(), **kwargs)

    def display(self, msg=None, pos=None) -> bool:
        now, done = time.monotonic(), self.total is not None and self.n >= self.total
        what = self.desc.removesuffix(": ")
        if not what and not self.n:  # a bar about to be named: its first line is its phase's
            return True
        if done and self._logged == (what, True):  # said already (a bar's close displays it once more)
            return True
        if what != self._logged[0] or now - self._logged_at >= LOG_EVERY_S or (done and self.n):
            count = f"{self.n:,}" + (f"/{self.total:,}" if self.total is not None else "")
            units = self.unit if self.total == 1 else f"{self.unit}es" if self.unit.endswith("ch") else f"{self.unit}s"
            log.info(f"{what or 'working'}: {count} {units}{' (done)' if done else ''}, "
                     f"{self.format_dict['elapsed']:.0f} s")
            self._logged_at, self._logged = now, (what, done)
        return True


def bar(enabled: bool | None = True, **options) -> tqdm:
    """A progress bar (module docstring): drawn when ``enabled`` (None: on a terminal), else log lines when the
    command line asked for them, else nothing."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if enabled:
        return tqdm(**options)
    if _lines:
        return LoggedBar(**options)
    return tqdm(disable=True, **options)
