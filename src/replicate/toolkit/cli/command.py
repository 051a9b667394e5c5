"""The ``replicate`` command: the parser of every verb (one module each), and how an error or Ctrl-C ends it."""

from __future__ import annotations

import argparse
import errno
import logging
import os
import sys
import warnings
from contextlib import ExitStack
from importlib.metadata import version

import shapely

from replicate.core import progress
from replicate.core.artifacts import CheckpointError
from replicate.core.schema import ConfigError
from replicate.toolkit.cli import (
    act,
    animate,
    compare,
    cover,
    evaluate,
    export,
    init,
    plan,
    train,
    train_general,
    tune,
)
from replicate.world.regions import RegionError

DESCRIPTION = ("The `replicate` command: train, evaluate, train-general, cover, plan, export, act, tune, compare, "
               "init, animate (`replicate COMMAND --help` for the options).")
VERBS = (train, evaluate, train_general, cover, plan, export, act, tune, compare, init, animate)  # the order of --help


def common_options(suppress: bool) -> argparse.ArgumentParser:
    """``--params`` and ``--set``, accepted before the verb and after it (``suppress``: a verb's copy leaves the
    value given before the verb alone unless given again)."""
    p = argparse.ArgumentParser(add_help=False)
    after = "_after_verb" if suppress else ""
    p.add_argument("--params", dest=f"params{after}", metavar="FILE", default=None,
                   help="parameters file (default: the one installed with the package; a params.yaml in the working "
                        "folder is read only when given; `replicate init` writes an editable copy)")
    p.add_argument("--set", dest=f"set{after}", action="append", metavar="KEY=VALUE", default=None,
                   help="override a value of the parameters file, e.g. configs.tuned.n_envs=25 (repeatable)")
    if suppress:
        p.add_argument("--no-progress", action="store_true",
                       help="no progress (also with TQDM_DISABLE set); without a terminal, progress is a log line "
                            "per phase and every 15 s")
    return p


class Help(argparse.HelpFormatter):
    """Help that names a default where there is one worth naming (not None, not a switch that is off)."""

    def _get_help_string(self, action):
        text = action.help or ""
        named = action.default is not None and action.default is not False and action.default != argparse.SUPPRESS
        if named and "%(default)" not in text and action.option_strings and not text.endswith(")"):
            text += " (default: %(default)s)"
        return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="replicate", description=DESCRIPTION, parents=[common_options(False)])
    parser.add_argument("--version", action="version", version=f"%(prog)s {version('buoy-swarm-coverage')}")
    sub = parser.add_subparsers(dest="command", required=True)
    verb = dict(parents=[common_options(True)], formatter_class=Help)
    regions = "square, rectangle, bedok (params.yaml regions), or a vector file in any CRS"
    for module in VERBS:
        module.add(sub, verb, regions)
    return parser


def glued_values(argv: list[str]) -> list[str]:
    """``--obs -1.2,-1.2;...`` → ``--obs=-1.2,-1.2;...``: argparse takes a value that starts with a minus sign for
    an option."""
    out, it = [], iter(argv)
    for arg in it:
        if arg == "--obs":
            value = next(it, None)
            out.append(arg if value is None else f"--obs={value}")
        else:
            out.append(arg)
    return out


def parsed(argv: list[str] | None) -> argparse.Namespace:
    """The command line as the verbs read it: --params and --set before or after the verb, the older --run."""
    args = build_parser().parse_args(glued_values(sys.argv[1:] if argv is None else argv))
    if getattr(args, "run_option", None) is not None:
        args.run = args.run or args.run_option
    args.params = args.params_after_verb or args.params
    args.set = (args.set or []) + (args.set_after_verb or [])
    # bars only on a terminal; a log or a pipe gets progress as log lines, without carriage returns
    quiet = args.no_progress or bool(os.environ.get("TQDM_DISABLE"))
    args.no_progress = quiet or not sys.stderr.isatty()
    progress.log_lines(not quiet and not sys.stderr.isatty())
    return args


def main(argv: list[str] | None = None) -> int:
    try:
        args = parsed(argv)
        warnings.simplefilter("default")
        warnings.formatwarning = lambda message, category, *_, **__: f"replicate: note: {message}\n"  # not a traceback
        logging.basicConfig(level=logging.WARNING, format="replicate: %(message)s", stream=sys.stderr)  # diagnostics:
        logging.getLogger("replicate").setLevel(logging.INFO)  # the package's notes, other libraries' warnings
        if args.command in ("train", "cover", "tune"):
            from replicate.learn.process import training_process

            training_process()
    except KeyboardInterrupt:  # Ctrl-C while the command starts: one line, as later
        return interrupted(None)
    try:
        with ExitStack() as held:  # the outputs this command claims (``core.outputs``), released however it ends
            args.held = held
            return args.func(args)
    except (ConfigError, RegionError, CheckpointError, OSError, ValueError) as exc:
        full = isinstance(exc, OSError) and exc.errno == errno.ENOSPC
        print(f"replicate: error: {exc}" + ("; free some space, or give --out on another disk" if full else ""),
              file=sys.stderr)
        return 2
    except shapely.errors.GEOSException as exc:
        print(f"replicate: error: the region's geometry cannot be used ({exc}); check the outline file, or repair "
              "it (e.g. shapely.make_valid)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return interrupted(args)
    except Exception as exc:
        if not caused_by_ctrl_c(exc):
            raise
        return interrupted(args)


def caused_by_ctrl_c(exc: BaseException) -> bool:
    """Whether ``exc`` wraps a KeyboardInterrupt: numba turns one that lands while it loads a compiled function
    from its cache into an error of its own, raised from the interrupt."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def interrupted(args) -> int:
    hint = getattr(args, "interrupted_hint", None)
    hint = hint() if callable(hint) else hint
    print("replicate: interrupted" + (f"; {hint}" if hint else ""), file=sys.stderr)
    return 130
