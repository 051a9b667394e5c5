"""SPEC §8's metrics of spread and convergence, on hand-made examples."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import box

from replicate.compare.metrics import convergence_episode, mean_nearest_neighbour, nearest_neighbour_inside


def test_the_spread_inside_counts_only_the_agents_in_the_region():
    """Two agents inside 1 m apart and one far outside: over every agent the outsider lengthens the mean; inside,
    it is 1 m. Fewer than two inside measure no spread over the region: NaN, not the 0 of agents bunched."""
    region = box(0, 0, 3, 3)
    xy = np.array([[[1.0, 1.0], [2.0, 1.0], [10.0, 10.0]], [[1.0, 1.0], [9.0, 9.0], [10.0, 10.0]]])
    spread = nearest_neighbour_inside(region, xy)
    assert spread[0] == 1.0 and np.isnan(spread[1])
    assert mean_nearest_neighbour(xy)[0] == pytest.approx((1 + 1 + np.hypot(8, 9)) / 3)


def test_the_band_of_the_curves_range_reads_a_return_that_ends_near_zero():
    """A return that climbs from −1,000 to −10 by episode 3,000 and stays there: a band of 5 % of its final value
    (±0.5) is about as narrow as its moving average's noise, so by that reading it converges only after episode
    9,000 ("not converged" for claim 1); 5 % of its range (±50) finds the climb's end. The same return held up by a
    constant (+2,000) converges by the final value's band too."""
    rng = np.random.default_rng(0)
    episodes = np.arange(10_000)
    climb = np.minimum(episodes / 3000, 1.0)
    curve = -1000 + 990 * climb + rng.normal(0, 5, len(episodes))
    assert convergence_episode(curve, band="final") > 9000
    found = convergence_episode(curve, band="range")
    assert found is not None and 2700 <= found <= 3300
    lifted = curve + 2000
    assert 2700 <= convergence_episode(lifted, band="final") <= 3300
    with pytest.raises(ValueError, match="band"):
        convergence_episode(curve, band="median")
