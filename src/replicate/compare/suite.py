"""The general policy's evaluation suite: every lake × fleet × start × event it is read on.

The lakes are the named regions (the square, the rectangle and Bedok) for the paper's 9 buoys, and the held-out
generated lakes of ``lakes.held_out`` for their own N; a cell scales its lake to the fleet's density
(``at_density``). The yardstick (``yardstick``) sizes its events as the suite does.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from shapely import affinity

from replicate.world.lakes import held_out
from replicate.world.regions import Region, make_region
from replicate.world.scenario import named_lakes


@dataclass(frozen=True)
class SuiteCell:
    """One cell of the generalisation table: a lake (a named region or a held-out lake), a fleet, a start, an
    event (``core.sections.EVENTS``: still water, a share of the fleet lost at T/2, a uniform drift)."""

    region: str
    n_agents: int
    start: str
    event: str


def suite_lakes(params) -> dict[str, tuple[Region, int]]:
    """The suite's lakes → (region, the fleet it is drawn for): every region of ``regions`` (the square, the
    rectangle and Bedok) for the paper's 9 buoys, then ``general.suite.held_out`` lakes of ``lakes.held_out`` for
    their own N."""

    named = {name: (make_region(name, params.regions[name], params.world.region_area), params.world.n_agents)
             for name in params.regions}
    return named | named_lakes(params, held_out(params.general.suite.held_out))


def at_density(region: Region, drawn_for: int, n_agents: int) -> Region:
    """``region`` scaled for ``n_agents`` buoys at the density it was drawn for (the same N·A(Cov)/A(Reg))."""
    s = (n_agents / drawn_for) ** 0.5
    return dataclasses.replace(region, polygon=affinity.scale(region.polygon, s, s, origin=(0, 0)),
                               scale=region.scale / s)


def suite_cells(params) -> list[SuiteCell]:
    su = params.general.suite
    cells = []
    for name in suite_lakes(params):
        fleets = su.named_fleets if name in params.regions else su.lake_fleets
        cells += [SuiteCell(name, n, start, event) for n in fleets for start in su.starts for event in su.events]
    return cells


def suite_lose(suite, n_agents: int) -> int:
    """Buoys lost at T/2 in the suite's "lose" event: ``lose_fraction`` of the fleet, at least one."""
    return max(1, int(n_agents * suite.lose_fraction))


def suite_event(suite, event: str, n_agents: int) -> tuple[int, tuple[float, float] | None]:
    """An event of ``EVENTS`` as (buoys lost at T/2, uniform current m/s or None), sized as ``suite`` sizes it."""
    lose = suite_lose(suite, n_agents) if event == "lose" else 0
    return lose, (suite.current, 0.0) if event == "current" else None
