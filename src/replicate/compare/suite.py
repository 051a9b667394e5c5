"""The general policy's evaluation suite: every lake × fleet × start × event it is read on.

Its lakes are of four kinds, never pooled in one number (``LakeKind``):

* **trained**: the named regions the policy trains on (``general.regions``: the square and the rectangle);
* **design**: the yardstick's lakes (``lakes.yardstick``, ``yardstick.lakes`` of them), on which the training's
  values were chosen (``replicate compare``): never trained on, but read by every choice, so not a test;
* **test**: ``general.suite.test_lakes`` generated lakes of the test stream (``lakes.test_stream``), a seed stream
  that no choice of the training, the baselines or the report has read;
* **real**: the other named regions (Bedok) and the lake files of ``general.suite.real_lakes`` (OpenStreetMap
  reservoirs), each drawn for the paper's 9 buoys.

The named regions run the fleets of ``named_fleets``, the others those of ``lake_fleets``; a cell scales its lake to
the fleet's density (``regions.at_density``). The yardstick (``yardstick``) sizes its events as the suite does.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from shapely.geometry import Polygon

from replicate.world.currents import Current, lake_vortex
from replicate.world.lakes import lake_name, test_stream, yardstick
from replicate.world.regions import Region, make_region, region_from_file
from replicate.world.scenario import named_lakes

LakeKind = Literal["trained", "design", "test", "real"]
KINDS: tuple[LakeKind, ...] = ("trained", "design", "test", "real")


@dataclass(frozen=True)
class SuiteCell:
    """One cell of the generalisation table: a lake of a kind (``LakeKind``), a fleet, a start, an event
    (``core.sections.EVENTS``: still water, a share of the fleet lost at T/2, a drift)."""

    region: str
    n_agents: int
    start: str
    event: str
    kind: LakeKind = "test"


def lake_kinds(params) -> dict[str, LakeKind]:
    """{lake name: its kind} of the suite, in the suite's order: named regions, real lake files, design lakes, test
    lakes."""
    named = {name: "trained" if name in params.general.regions else "real" for name in params.regions}
    files = {Path(path).stem: "real" for path in params.general.suite.real_lakes}
    design = {lake_name(spec): "design" for spec in yardstick(params.yardstick.lakes)}
    tests = {lake_name(spec): "test" for spec in test_stream(params.general.suite.test_lakes)}
    return named | files | design | tests


def suite_lake(params, name: str) -> tuple[Region, int]:
    """One lake of the suite → (region, the fleet it is drawn for)."""
    if name in params.regions:
        return make_region(name, params.regions[name], params.world.region_area), params.world.n_agents
    for path in params.general.suite.real_lakes:
        if Path(path).stem == name:
            return region_from_file(path, name, params.world.region_area), params.world.n_agents
    generated = [*yardstick(params.yardstick.lakes), *test_stream(params.general.suite.test_lakes)]
    spec = {lake_name(s): s for s in generated}[name]
    return named_lakes(params, [spec])[name]  # this lake's geometry alone


def suite_lakes(params) -> dict[str, tuple[Region, int]]:
    """Every lake of the suite → (region, the fleet it is drawn for)."""
    return {name: suite_lake(params, name) for name in lake_kinds(params)}


def suite_cells(params) -> list[SuiteCell]:
    su = params.general.suite
    cells = []
    for name, kind in lake_kinds(params).items():
        fleets = su.named_fleets if name in params.regions else su.lake_fleets
        cells += [SuiteCell(name, n, start, event, kind) for n in fleets for start in su.starts
                  for event in su.events]
    return cells


def suite_lose(suite, n_agents: int) -> int:
    """Buoys lost at T/2 in the suite's "lose" event: ``lose_fraction`` of the fleet, at least one."""
    return max(1, int(n_agents * suite.lose_fraction))


def suite_event(suite, event: str, n_agents: int, heading: float = 0.0,
                water: Polygon | None = None) -> tuple[int, Current | None]:
    """An event of ``EVENTS`` as (buoys lost at T/2, the water's current or None), sized as ``suite`` sizes it: the
    uniform drift flows toward ``heading`` (radians from +x); the vortex over ``water`` (``lake_vortex``) turns
    counter-clockwise for a heading in the upper half of the circle, clockwise in the lower."""
    lose = suite_lose(suite, n_agents) if event == "lose" else 0
    if event == "current":
        return lose, Current.uniform((suite.current * math.cos(heading), suite.current * math.sin(heading)))
    if event == "vortex":
        if water is None:
            raise ValueError("the vortex event needs the lake's water")
        return lose, lake_vortex(water, suite.current if heading < math.pi else -suite.current)
    return lose, None


def drift_heading(seed: int, cell: SuiteCell) -> float:
    """The direction of a cell's drift (and the turn of its vortex), uniform on the circle, drawn from the
    evaluation seed and the cell (its lake, fleet and start): the drift is not always along +x, where it would carry
    buoys released in the lower-left corner along a long lake."""
    key = zlib.crc32(f"{cell.region}/{cell.n_agents}/{cell.start}".encode())
    return float(np.random.default_rng([seed, key]).uniform(0.0, 2.0 * math.pi))
