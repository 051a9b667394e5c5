"""What a verb reads from the user before any work: a region by name or file, ``--set`` overrides, and the
output it will write, claimed (checked writable and not a finished result unless ``--force``)."""

from __future__ import annotations

import json
import math
import os
import re
import sys
from contextlib import ExitStack
from pathlib import Path

from replicate.core.artifacts import CheckpointError
from replicate.core.outputs import locked, remove, replacing
from replicate.core.params import Params
from replicate.core.schema import ConfigError
from replicate.world.regions import (
    Region,
    RegionError,
    make_region,
    read_run_region,
    region_from_file,
)


def resolve_region(name_or_path: str, params: Params) -> Region:
    """A region named in params.yaml (``square``, ``rectangle``, ``bedok``) or any vector file."""
    if name_or_path in params.regions:
        return make_region(name_or_path, params.regions[name_or_path], params.world.region_area)
    path = Path(name_or_path)
    if path.suffix or path.exists():
        return region_from_file(path, area=params.world.region_area)
    raise RegionError(f"unknown region {name_or_path!r}: not one of {sorted(params.regions)} and not a file")


def overrides(pairs: list[str] | None) -> dict:
    """``--set key.path=value`` pairs (values parsed as YAML) → a mapping for ``load_params``. A number YAML 1.1
    reads as a string (``1e-9``: no dot before the exponent) is read as the number it is."""
    import yaml

    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {pair!r}")
        parsed = yaml.safe_load(value)
        if isinstance(parsed, str) and re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+", parsed.strip()):
            parsed = float(parsed)
        out[key.strip()] = parsed
    return out


MAX_EPISODES = 1_000_000  # 100 times the paper's 10,000: days of one core; beyond, a typo (1e12)


def check_episodes(episodes: int | None, option: str = "--episodes") -> None:
    """Refuse a number of training episodes no run could finish, by name."""
    if episodes is not None and episodes > MAX_EPISODES:
        raise ConfigError(f"{option} {episodes}: more than {MAX_EPISODES:,} episodes (100 times the paper's 10,000, "
                          "days of one core at the paper's size); give fewer")


def number_pair(text: str | None, option: str, what: str) -> tuple[float, float] | None:
    """``"a,b"`` → (a, b), refused by ``option`` when not two finite numbers."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 2 or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{option} expects two numbers {what}, got {text!r}")
    return values


def resume_command(run: Path) -> str:
    import shlex

    return f"replicate train --resume {shlex.quote(str(run))}"


def claim_out_file(out: Path, force: bool, option: str = "--out", held: ExitStack | None = None) -> Path:
    """Check an output file before any work: not a folder, in a folder that exists (or can be made) and can be
    written, and not a finished result unless ``force`` (then the old file stays until the new one replaces it,
    written whole). With ``held`` (the command's claims) it is locked for the command: a second writer is refused."""
    out = Path(out)
    if out.is_dir():
        raise ConfigError(f"{option} {out}: is a folder; give the path of a file")
    if out.exists() and not out.is_file():  # a device or a pipe (/dev/null) would be replaced by a file
        raise ConfigError(f"{option} {out}: not a regular file (a device or a pipe); give the path of a file")
    if out.exists() and not force:
        raise ConfigError(f"{option} {out}: exists; pass --force to replace it, or choose another path")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{option} {out}: cannot create its folder ({exc.strerror}); choose a writable folder") \
            from None
    if not os.access(out.parent, os.W_OK):
        raise ConfigError(f"{option} {out}: its folder is not writable; choose a writable folder")
    if held is not None:
        held.enter_context(locked(out, option))
    return out


def claim_run_folder(out: Path, force: bool, held: ExitStack | None = None) -> bool:
    """Make ``out`` ready for a new run: refuse a folder that holds a run (finished or interrupted) or anything
    else, unless ``force``, which moves it aside until the new run is complete (put back if the command fails or
    is interrupted). With ``held`` (the command's claims) the folder is locked for the command. → whether the
    folder was created here (so that a run that fails before writing anything can leave no empty folder behind)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file, not a folder; choose a folder")
    if held is not None:
        held.enter_context(locked(out))
    if out.is_dir() and any(out.iterdir()):
        if not force:
            run = out / "run.json"
            if (out / "checkpoint.pt").exists():
                raise ConfigError(f"--out {out}: holds an interrupted run; continue it with `{resume_command(out)}`, "
                                  "or pass --force to start over")
            d = read_record(run)
            if d.get("status") == "finished":
                raise ConfigError(f"--out {out}: holds a finished run ({d.get('config')}/{d.get('method')} on "
                                  f"{d.get('region')}, seed {d.get('seed')}, {d.get('episodes')} episodes); pass "
                                  "--force to replace it, or choose another --out")
            raise ConfigError(f"--out {out}: is not empty; pass --force to clear it, or choose another --out")
        if held is None:
            remove(out)
        else:
            held.enter_context(replacing(out))
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create the folder ({exc.strerror}); choose a writable folder") from exc
    if not os.access(out, os.W_OK):
        raise ConfigError(f"--out {out}: the folder is not writable; choose a writable folder")
    return created


def read_record(path: Path) -> dict:
    """A run's ``run.json`` as a mapping, refused by name when it is there but unreadable; {} when absent."""
    if not path.exists():
        return {}
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: not a readable run record ({exc}); the run folder is damaged: pass --force "
                              "to replace it") from None
    return record if isinstance(record, dict) else {}


def run_record(run: Path) -> dict:
    """A run folder's ``run.json``, refused by name when it is missing, unreadable or not a run's record."""
    import json

    path = Path(run) / "run.json"
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{run}: not a run folder (no run.json); give a folder that `replicate train` "
                              "wrote") from None
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: not a readable run record ({exc}); the run folder is damaged") from None
    if isinstance(record, dict) and "general" in record:
        raise CheckpointError(f"{run}: a general run (one policy for any lake); `replicate export {run}`, then "
                              "`replicate evaluate --policy FILE --region R`")
    if not isinstance(record, dict) or "region" not in record:
        raise CheckpointError(f"{path}: not a run's record (no region); the run folder is damaged")
    return record


def run_region(run_dir: str, params: Params, region: str | None) -> Region:
    """The region to evaluate a run on: ``region`` if given, else the run's own (recorded in the run folder by
    ``write_run_region``, or named in its run.json)."""
    own_name = run_record(Path(run_dir))["region"]
    own = read_run_region(Path(run_dir))
    if region is None:
        return own if own is not None else resolve_region(own_name, params)
    chosen = resolve_region(region, params)
    if chosen.name != own_name:
        print(f"note: {run_dir} was trained on {own_name!r}; evaluating it on {chosen.name!r} (its actors observe "
              "absolute positions, so they know only the region they were trained on)", file=sys.stderr)
    return chosen
