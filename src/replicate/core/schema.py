"""How a section of ``params.yaml`` is declared and checked: pydantic dataclasses, frozen, extra keys forbidden,
each value's range beside its field.

A section is ``@section class WorldConfig: n_agents: Annotated[Int, In(1, MAX_AGENTS)] ...``. Numbers are strict
(``1`` is read as ``1.0`` where a float is expected; ``true`` is never a number and ``"5"`` never an integer),
lists are read as tuples. ``build`` makes a section from a mapping and turns pydantic's errors into one
``ConfigError`` line that names the key path, the value and what it must be
(``configs.tuned.maddpg.gamma must be in (0, 1], got 2``). Sections are real dataclasses: ``dataclasses.replace``
validates again, and ``to_dict`` gives the plain data a run's identity is made of.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import Annotated, Any

import pydantic
from pydantic import AfterValidator, ConfigDict, Strict
from pydantic.dataclasses import dataclass

MAX_AGENTS = 200  # buoys per region: the pairwise terms grow as N², and 1,000 buoys took 5.6 GB
MAX_SEED = 2**32 - 1  # the largest seed every generator takes (torch's manual_seed among them)


class ConfigError(ValueError):
    """A configuration value is unknown, missing, of the wrong type or out of its range."""


class RegionError(ValueError):
    """The input cannot be turned into a region; the message names the problem."""


def section(cls: type) -> type:
    """A frozen pydantic dataclass that refuses unknown keys and non-finite numbers; made from values in code (a
    policy's metadata, ``dataclasses.replace``), a bad value is a ``ConfigError`` naming the field."""
    made = dataclass(frozen=True, config=ConfigDict(extra="forbid", allow_inf_nan=False))(cls)
    validate = made.__init__

    def __init__(self, *args, **kwargs):
        try:
            validate(self, *args, **kwargs)
        except pydantic.ValidationError as exc:
            raise ConfigError(message(exc.errors()[0], made, made.__name__)) from None

    made.__init__ = __init__
    made.validate_from = validate  # ``build``: the same check, with the errors named after where the values came from
    return made


Num = Annotated[float, Strict()]  # a number; an integer is read as its float
Int = Annotated[int, Strict()]
Flag = Annotated[bool, Strict()]
Text = Annotated[str, Strict()]


def span(lo: float, hi: float = math.inf, open_lo: bool = False, open_hi: bool = False) -> str:
    """The words for a range: ``in (0, 1]``, ``at least 1``, ``above 0``."""
    if math.isfinite(hi):
        return f"in {'(' if open_lo else '['}{lo:g}, {hi:g}{')' if open_hi else ']'}"
    return f"above {lo:g}" if open_lo else f"at least {lo:g}"


def inside(value: float, lo: float, hi: float = math.inf, open_lo: bool = False, open_hi: bool = False) -> bool:
    return (value > lo if open_lo else value >= lo) and (value < hi if open_hi else value <= hi)


def In(lo: float, hi: float = math.inf, open_lo: bool = False, open_hi: bool = False) -> AfterValidator:  # noqa: N802
    """A value's range, written beside its field: [lo, hi], or open at either end."""

    def check(value):
        if not inside(value, lo, hi, open_lo, open_hi):
            raise ValueError(f"must be {span(lo, hi, open_lo, open_hi)}")
        return value

    return AfterValidator(check)


Count = Annotated[Int, In(1)]  # a whole number ≥ 1
Whole = Annotated[Int, In(0)]  # a whole number ≥ 0
Positive = Annotated[Num, In(0, open_lo=True)]
NonNegative = Annotated[Num, In(0)]
Share = Annotated[Num, In(0, 1)]  # a fraction in [0, 1]
Seed = Annotated[Int, In(0, MAX_SEED)]
Fleet = Annotated[Int, In(2, MAX_AGENTS)]  # a fleet a general policy is trained or read on


def joined(*parts) -> str:
    return ".".join(str(p) for p in parts if p != "")


TYPE_WORDS = {"int_type": "an integer", "float_type": "a number", "bool_type": "true/false", "string_type": "a string",
              "dict_type": "a mapping", "tuple_type": "a list", "dataclass_type": "a mapping",
              "dataclass_args_type": "a mapping"}


def message(error: dict, cls: type, where: str) -> str:
    """One line for one of pydantic's errors on section ``cls`` read from ``where``: the key path, the value, and
    what it must be."""
    kind, loc, value = error["type"], tuple(error["loc"]), error.get("input")
    path = joined(where, *loc)
    if kind in TYPE_WORDS:
        return f"{path}: expected {TYPE_WORDS[kind]}, got {value!r}"
    if kind == "missing" and isinstance(loc[-1], int):  # a list shorter than its fixed length
        holder, name = section_at(cls, loc[:-2]), loc[-2]
        size = len(typing.get_args(typing.get_type_hints(holder)[name])) if holder else "more"
        return f"{joined(where, *loc[:-1])}: expected {size} items, got {loc[-1]}"
    if kind == "missing":
        return f"{joined(where, *loc[:-1])}: missing key {loc[-1]!r}"
    if kind in ("unexpected_keyword_argument", "extra_forbidden"):
        holder = section_at(cls, loc[:-1])
        known = sorted(f.name for f in dataclasses.fields(holder)) if holder else []
        return f"{joined(where, *loc[:-1])}: unknown key(s) [{loc[-1]!r}]; known: {known}"
    if kind == "literal_error":
        return f"{path}: {value!r} is not one of [{error['ctx']['expected'].replace(' or ', ', ')}]"
    if kind in ("too_long", "too_short"):
        ctx = error["ctx"]
        return f"{path}: expected {ctx.get('max_length', ctx.get('min_length'))} items, got {ctx['actual_length']}"
    if kind == "finite_number":
        return f"{path} must be a finite number, got {value!r}"
    if kind == "value_error":
        cause = error["ctx"]["error"]
        return str(cause) if isinstance(cause, ConfigError) else f"{path} {cause}, got {value!r}"
    return f"{path}: {error['msg']}, got {value!r}"


def build(cls: type, data: Any, where: str = "") -> Any:
    """Section ``cls`` from mapping ``data`` (read from ``where``: a file or a key path); any unknown, missing,
    mistyped or out-of-range value is a ``ConfigError`` naming the key path."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    obj = cls.__new__(cls)
    try:
        cls.validate_from(obj, **data)
    except pydantic.ValidationError as exc:
        raise ConfigError(message(exc.errors()[0], cls, where)) from None
    return obj


def section_at(cls: type, loc: tuple) -> type | None:
    """The section class at key path ``loc`` inside section ``cls`` (through nested sections and mappings)."""
    node: Any = cls
    for part in loc:
        if not dataclasses.is_dataclass(node):
            return None
        hints = typing.get_type_hints(node, include_extras=True)
        if part in hints:  # else a key of a mapping of sections: the section stays
            node = hints[part]
        while True:  # through Optional[...] and dict[str, ...] to the section inside
            args = [a for a in typing.get_args(node) if a is not type(None)]
            if typing.get_origin(node) is dict or (args and type(None) in typing.get_args(node)):
                node = args[-1]
            elif typing.get_origin(node) is Annotated:
                node = args[0]
            else:
                break
    return node if dataclasses.is_dataclass(node) else None


def within(value: float, where: str, lo: float, hi: float = math.inf, open_lo: bool = False) -> float:
    """``value`` if it is a finite number in the range, else a ConfigError naming ``where`` (an option of a verb,
    where no section holds the value)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not (ok and inside(value, lo, hi, open_lo)):
        raise ConfigError(f"{where} must be {span(lo, hi, open_lo)}, got {value!r}")
    return value


def positive(value: float, where: str) -> float:
    """``value`` if it is a finite number above 0, else a ConfigError naming ``where``."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{where} must be a positive number, got {value!r}")
    return value


def check_seed(seed: int, where: str = "--seed") -> int:
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{where} must be a whole number from 0 to {MAX_SEED}, got {seed!r}")
    return seed


def dotted_parent(tree: dict, dotted: str, where: str) -> tuple[dict, str]:
    """The mapping that holds the existing key ``a.b.c`` of a nested mapping, and its last part ``c``."""
    *sections, key = dotted.split(".")
    node = tree
    for k in sections:
        if not isinstance(node.get(k), dict):
            raise ConfigError(f"{where}: no section {k!r} in {dotted!r}")
        node = node[k]
    if key not in node:
        raise ConfigError(f"{where}: unknown key {key!r} in {dotted!r}")
    return node, key


def to_dict(obj: Any, drop_defaults: bool = False) -> Any:
    """A section as plain JSON/YAML-friendly data (tuples become lists). ``drop_defaults`` leaves out fields
    that have a default and hold it: the form used for run identities."""
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if drop_defaults and f.default is not dataclasses.MISSING and value == f.default:
                continue
            out[f.name] = to_dict(value, drop_defaults)
        return out
    if isinstance(obj, dict):
        return {k: to_dict(v, drop_defaults) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v, drop_defaults) for v in obj]
    return obj
