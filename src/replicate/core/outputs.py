"""Outputs a command writes, claimed for the length of the command so that nothing is lost.

* A **lock** beside the output (``.NAME.lock``, created exclusively, holding the writer's process id): a second
  command that would write the same output is refused by name while the first runs; a lock whose process is gone
  (a command killed with ``kill -9``) is taken over.
* **Moved aside, not deleted**: ``--force`` over a finished result moves the old one to ``.NAME.replaced`` and
  deletes it only once the new result is complete; a command that fails or is interrupted puts it back, and the
  next command to claim the output puts back what a killed one (``kill -9``) left aside.

A command holds its claims in a ``contextlib.ExitStack`` (``replicate.toolkit.cli.command``), released when it
ends whatever the outcome.
"""

from __future__ import annotations

import os
import shutil
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from replicate.core.schema import ConfigError


def lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie or another user's process counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def holder(lock: Path) -> int | None:
    """The process id a lock names, or None when it names none that runs."""
    try:
        pid = int(lock.read_text().strip() or 0)
    except (OSError, ValueError):
        return None
    return pid if pid > 0 and alive(pid) else None


@contextmanager
def locked(out: Path, option: str = "--out") -> Iterator[Path]:
    """Hold the lock of output ``out`` for the block; refused by name while another process holds it."""
    out = Path(out)
    lock = lock_path(out)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file where a folder should be, a read-only disk
        raise unwritable(out, option, exc) from None
    for _ in range(2):  # a second try after taking over a stale lock
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            pid = holder(lock)
            if pid is not None and pid != os.getpid():
                raise ConfigError(f"{option} {out}: another replicate command (process {pid}) is writing it; "
                                  "wait for it to finish, or choose another path") from None
            if pid == os.getpid():
                raise ConfigError(f"{option} {out}: this command already writes it; give each output its own path") \
                    from None
            lock.unlink(missing_ok=True)  # its process is gone: a killed command's lock
            continue
        except OSError as exc:  # a read-only or full disk, a folder without write permission
            raise unwritable(out, option, exc) from None
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{os.getpid()}\n")
        break
    else:  # pragma: no cover - another process took the stale lock in between
        raise ConfigError(f"{option} {out}: another replicate command is writing it; choose another path")
    try:
        put_back(out)
        yield out
    finally:
        if holder(lock) == os.getpid():
            lock.unlink(missing_ok=True)


def unwritable(out: Path, option: str, exc: OSError) -> ConfigError:
    """The error of an output whose lock cannot be written, with the system's reason."""
    return ConfigError(f"{option} {out}: cannot be written there ({exc.strerror}); choose a writable folder")


def put_back(out: Path) -> None:
    """Put back a result that a command killed while replacing it (``kill -9``: no ``finally`` ran) had moved
    aside, in place of whatever that command left; called with the lock held, so no command is writing it."""
    aside = out.parent / f".{out.name}.replaced"
    if aside.exists():
        if out.exists():
            remove(out)
        aside.rename(out)
        warnings.warn(f"{out}: put back the result that a killed command had moved aside to replace it", stacklevel=3)


@contextmanager
def replacing(out: Path) -> Iterator[Path]:
    """Move the existing ``out`` (a file or a folder) aside for the block: deleted when the block completes, put
    back in place of whatever the block left when it fails or is interrupted."""
    out = Path(out)
    aside = out.parent / f".{out.name}.replaced"
    put_back(out)  # a replacement that was itself killed: the old result is the one to keep
    out.rename(aside)
    try:
        yield out
    except BaseException:
        if out.exists():
            remove(out)
        aside.rename(out)
        raise
    remove(aside)


def remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
