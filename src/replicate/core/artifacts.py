"""Run artifacts on disk: atomic writes, the per-episode curve, checkpoints and exported actors.

Every file is written to a temporary sibling and renamed into place, so a crash or Ctrl-C never leaves a
half-written file behind: a reader sees the old version or the new one.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import os
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

CHECKPOINT_FORMAT = 1


class CheckpointError(RuntimeError):
    """A checkpoint or actor file is missing, corrupt, or does not match the run asked for."""


@contextmanager
def atomic_file(path: str | Path) -> Iterator[BinaryIO]:
    """A binary file handle whose contents replace ``path`` when the block ends without an error (written to a
    temporary sibling, synced, renamed); on an error the temporary file is removed and ``path`` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o644)  # mkstemp's 0600 would survive the rename
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        if exc.filename is not None:
            raise
        raise OSError(exc.errno, f"{exc.strerror} (writing {path})") from exc  # a full disk names no file
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary sibling path (same suffix) for a library that writes a file by name (a GeoPackage); renamed
    onto ``path`` with mode 0644 when the block ends without an error, removed otherwise."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(fd)
    Path(tmp).unlink()  # the library creates it: an existing empty file is not a GeoPackage
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_file(path) as fh:
        fh.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def write_json(path: str | Path, obj: Any) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def write_csv(path: str | Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
    """A CSV file; gzip-compressed when ``path`` ends in ``.gz`` (with a fixed header time, so the same rows
    give the same bytes)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in row])
    data = buf.getvalue().encode()
    atomic_write_bytes(path, gzip.compress(data, mtime=0) if str(path).endswith(".gz") else data)


def read_text(path: str | Path) -> str:
    """The text of a file written by ``write_csv`` or ``atomic_write_text``, gzip-compressed or not."""
    data = Path(path).read_bytes()
    return (gzip.decompress(data) if str(path).endswith(".gz") else data).decode()


def torch_save(path: str | Path, obj: Any) -> None:
    """``torch.save`` streamed into the file (a checkpoint's replay buffer is up to 250 MB: no copy in memory)."""
    import torch  # here, not at the top: `replicate --help` and the verbs' input checks start without torch

    with atomic_file(path) as fh:
        torch.save(obj, fh)


def torch_load(path: str | Path, what: str = "checkpoint") -> dict:
    """Load a file written by ``torch_save`` (tensors, numbers, strings, lists, dicts only)."""
    import torch  # as in ``torch_save``

    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: no {what} here")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure means a corrupt file
        raise CheckpointError(f"{path}: corrupt {what} ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a {what} of this project (format {CHECKPOINT_FORMAT})")
    return state


def read_curve(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a curve file (``curve.csv.gz`` of a run, ``validation.csv``, a reference curve)."""
    rows = list(csv.DictReader(io.StringIO(read_text(path))))
    if not rows:
        raise ValueError(f"{path}: empty curve")
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}
