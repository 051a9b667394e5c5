"""The map a buoy reads around itself (``replicate.world.local_map``): the lake's water read exactly off its grid,
and the cells that other buoys heard cover."""

import numpy as np
import pytest
import shapely
from shapely.geometry import box

from replicate.world import local_map


@pytest.mark.parametrize("name", ["bedok", "island"])
def test_the_water_mask_reads_points_as_the_outline_does(name, regions):
    """``WaterMask.at`` agrees with shapely on points spread over the lake's box and on points within 1 cm of its
    shore, where the grid alone would misread."""
    water = regions["bedok"].polygon if name == "bedok" else box(0, 0, 3, 3).difference(box(1.2, 1.2, 1.8, 1.8))
    mask = local_map.WaterMask.for_raster(water, 9, 2.0)
    rng = np.random.default_rng(0)
    minx, miny, maxx, maxy = water.bounds
    spread = rng.uniform((minx - 0.5, miny - 0.5), (maxx + 0.5, maxy + 0.5), (20_000, 2))
    shore = shapely.line_interpolate_point(water.exterior, rng.uniform(0, water.exterior.length, 5_000))
    near = shapely.get_coordinates(shore) + rng.uniform(-0.01, 0.01, (5_000, 2))
    for xy in (spread, near):
        np.testing.assert_array_equal(mask.at(xy.reshape(50, -1, 2)).ravel(), shapely.contains_xy(water, *xy.T))
    assert 0.3 < mask.at(near).mean() < 0.7, "half the points near the shore are water"


def test_the_local_raster_maps_water_and_what_others_cover():
    """On a 4 × 4 m square, a buoy 0.5 m from the west shore sees dry cells west of the shore and water east; the
    cells another buoy it hears covers (R = 0.5 m), and none that a buoy beyond the communication range covers."""
    water = box(0, 0, 4, 4)
    offsets = local_map.raster_offsets(9, 2.0)  # cells 4/9 m apart
    pos = np.array([[[0.5, 2.0], [1.5, 2.0], [0.5, 3.9]]])  # buoy 1 heard by buoy 0, buoy 2 not (1.9 > 1.5 m)
    out = local_map.local_raster(pos, local_map.WaterMask.for_raster(water, 9, 2.0), offsets, 0.5, 1.5)
    wet, covered = out[0, 0, :81].reshape(9, 9), out[0, 0, 81:].reshape(9, 9)  # rows south to north
    np.testing.assert_array_equal(wet, np.broadcast_to(pos[0, 0, 0] + offsets[:9, 0] > 0, (9, 9)))
    expected = np.linalg.norm(pos[0, 0] + offsets - pos[0, 1], axis=-1) <= 0.5
    np.testing.assert_array_equal(covered.ravel(), expected)
    assert expected.sum() >= 3 and covered[4, 4] == 0  # buoy 1's disc, not the buoy's own


def test_a_raster_with_no_centre_cell_is_refused():
    from replicate.core.params import load_params
    from replicate.core.schema import ConfigError

    from ..conftest import ROOT

    with pytest.raises(ConfigError, match="odd number of cells"):
        load_params(ROOT / "params.yaml", {"general.sensors.raster": 8})
