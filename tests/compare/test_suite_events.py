"""The suite's events: each sized as ``general.suite`` says, the moving water a ``Current`` of the lake."""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import box

from replicate.compare.suite import suite_event
from replicate.core.sections import EVENTS


def test_every_event_is_sized_as_the_suite_says(params):
    """Still water and the loss carry no current; the drift flows at the suite's speed toward its heading; the
    vortex turns about the middle of the lake's box, at the suite's speed one core (a third of the lake) from it,
    counter-clockwise for a heading in the upper half of the circle and clockwise in the lower."""
    su, lake = params.general.suite, box(0, 0, 6, 3)
    assert set(EVENTS) >= {"none", "lose", "current", "vortex"}
    assert suite_event(su, "none", 9) == (0, None)
    assert suite_event(su, "lose", 9)[0] == 3 and suite_event(su, "lose", 9)[1] is None
    _, drift = suite_event(su, "current", 9, heading=math.pi / 2)
    np.testing.assert_allclose(drift.flow[0], [0.0, su.current], atol=1e-12)
    for heading, turn in ((1.0, 1.0), (4.0, -1.0)):
        lose, vortex = suite_event(su, "vortex", 9, heading, water=lake)
        assert lose == 0 and vortex.describe()["vortex"] == {"center": [3.0, 1.5], "peak": turn * su.current,
                                                              "core": 2.0}
        east_of_middle = vortex.tiled(2).at(np.array([[[5.0, 1.5]], [[3.0, 1.5]]]))
        np.testing.assert_allclose(east_of_middle[0, 0], [0.0, turn * su.current])  # one core east: peak, turning
        np.testing.assert_allclose(east_of_middle[1, 0], [0.0, 0.0])  # the middle is still
    with pytest.raises(ValueError, match="water"):
        suite_event(su, "vortex", 9)


def test_the_suite_reads_four_kinds_of_lakes_from_four_streams(params):
    """The trained-on regions, the yardstick's design lakes, the test stream and the real lakes: disjoint, every
    generated lake named by its recipe and built alone."""
    from replicate.compare.suite import lake_kinds, suite_lake
    from replicate.world.lakes import lake_name, test_stream, training, yardstick

    kinds = lake_kinds(params)
    by_kind = {k: {name for name, kind in kinds.items() if kind == k} for k in ("trained", "design", "test", "real")}
    assert by_kind["trained"] == set(params.general.regions)
    assert by_kind["design"] == {lake_name(s) for s in yardstick(params.yardstick.lakes)}
    assert by_kind["test"] == {lake_name(s) for s in test_stream(params.general.suite.test_lakes)}
    assert len(by_kind["design"]) == params.yardstick.lakes and not by_kind["design"] & by_kind["test"]
    trained_lakes = {lake_name(s) for s in training(params.general.lakes, n_range=params.general.lake_fleet,
                                                   ratio_range=params.general.lake_ratio)}
    assert not trained_lakes & (by_kind["design"] | by_kind["test"])
    name = sorted(by_kind["design"])[0]
    region, drawn_for = suite_lake(params, name)
    assert region.name == name and region.polygon.area > 0 and drawn_for > 0
