"""The map a buoy reads around itself (``replicate.world.local_map``): the lake's water read exactly off its grid,
the cells that other buoys heard cover, and the centroid of the water nearer to the buoy than to them."""

import numpy as np
import pytest
import shapely
from shapely.geometry import box

from replicate.world import local_map, sensors

from .test_sensors import points_inside


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


def exact_centroid(water, p, heard, reach):
    """The offset from ``p`` to the centroid of (disc of ``reach`` ∩ water ∩ the half-planes nearer to p than to
    each of ``heard``), by shapely: the cell the sensor samples."""
    cell = shapely.Point(p).buffer(reach, quad_segs=64).intersection(water)
    for q in heard:  # the half-plane of the points nearer to p than to q: a large box cut at the bisector
        mid, normal = (p + q) / 2, (p - q) / np.linalg.norm(p - q)
        side = np.array([-normal[1], normal[0]]) * 100
        cell = cell.intersection(shapely.Polygon([mid + side, mid + side + normal * 100, mid - side + normal * 100,
                                                  mid - side]))
    return np.array(cell.centroid.coords[0]) - p


@pytest.mark.parametrize("name", ["bedok", "island"])
def test_the_local_centroid_is_the_centroid_of_the_buoys_sensed_cell(name, regions):
    """``LocalCentroid`` agrees with shapely's centroid of the cell (disc of the reach, water, nearer than every
    buoy heard) to within half its points' spacing, and to a fifth of it in the median (it samples the cell on a
    lattice); lost buoys read 0 and are not heard."""
    water = regions["bedok"].polygon if name == "bedok" else box(0, 0, 3, 3).difference(box(1.2, 1.2, 1.8, 1.8))
    rng = np.random.default_rng(5)
    pos = points_inside(water, 2 * 12, rng).reshape(2, 12, 2)
    alive = np.ones((2, 12), bool)
    alive[1, :3] = False
    rel, heard = sensors.neighbours(pos, 4, 1.5, alive)
    sensor = local_map.LocalCentroid(water, 2.0)
    out = sensor(pos, rel, heard, alive)
    spacing = 2.0 / local_map.CENTROID_STEPS
    errors = []
    for e in range(2):
        for i in range(12):
            if not alive[e, i]:
                np.testing.assert_array_equal(out[e, i], 0.0)
                continue
            expected = exact_centroid(water, pos[e, i], pos[e, i] + rel[e, i][heard[e, i] > 0], 2.0)
            errors.append(np.abs(out[e, i] - expected).max())
    assert max(errors) < spacing / 2 and np.median(errors) < spacing / 5
    assert np.abs(out[alive]).max() > 0.3, "some buoys' cells lie well off them"


def test_the_front_buoy_of_a_channel_sees_the_water_ahead():
    """In a 9 m channel, the east-most of a row of buoys 0.4 m apart along its axis steers east (its cell reaches 2 m
    ahead and 0.2 m behind), a buoy in the middle of the row barely moves, and the west-most steers west. (The channel
    is 1.05 m wide, so that no point the sensor reads lies on its shore, which it knows to within a fine cell.)"""
    water = box(0, 0, 9, 1.05)
    pos = np.array([[[1.0 + 0.4 * k, 0.525] for k in range(5)]])
    rel, heard = sensors.neighbours(pos, 4, 2.0)
    out = local_map.LocalCentroid(water, 2.0)(pos, rel, heard)[0]
    assert out[-1, 0] > 0.8 and out[0, 0] < -0.3 and abs(out[2, 0]) < 0.05
    np.testing.assert_allclose(out[:, 1], 0.0, atol=1e-9)  # the channel is symmetric across its axis
