"""``replicate init``: An editable params.yaml with every default value."""

from __future__ import annotations

import argparse
from pathlib import Path

from replicate.core import artifacts
from replicate.core.schema import ConfigError
from replicate.toolkit.cli.inputs import (
    claim_out_file,
)


def add(sub, verb: dict, regions: str) -> None:
    """The ``init`` verb's options."""
    i = sub.add_parser("init", help="write an editable params.yaml with every default value into a folder", **verb)
    i.add_argument("dir", nargs="?", default=".", help="folder")
    i.add_argument("--force", action="store_true", help="replace a params.yaml already there")
    i.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    from replicate.core.params import packaged

    if Path(args.dir).exists() and not Path(args.dir).is_dir():
        raise ConfigError(f"{args.dir}: is a file; choose a folder")
    target = claim_out_file(Path(args.dir) / "params.yaml", args.force, "init", held=args.held)
    artifacts.atomic_write_bytes(target, packaged("params.yaml").read_bytes())
    print(f"wrote {target}: every value of the toolkit, commented; edit it and pass --params {target} (a "
          "params.yaml in the working folder is read only when given)")
    return 0
