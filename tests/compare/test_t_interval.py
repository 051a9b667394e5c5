"""The Student-t interval beside the percentile bootstrap at few seeds: how often each keeps a null difference."""

from __future__ import annotations

import numpy as np

from replicate.compare import stats


def test_at_five_seeds_the_t_interval_misses_the_mean_about_as_often_as_it_says():
    """400 draws of five normal seeds: the percentile bootstrap's 95 % interval misses the true mean far more often
    than 5 % (it is too narrow at n = 5), the t interval close to 5 %; at ten seeds only the bootstrap is given."""
    rng, boot = np.random.default_rng(3), stats.Bootstrap(0.95, 1000, 0, t_below=10)
    miss = {"percentile": 0, "t": 0}
    for _ in range(400):
        ci = stats.mean_interval(rng.normal(0.0, 1.0, 5), boot)
        miss["percentile"] += not ci["lo"] <= 0.0 <= ci["hi"]
        miss["t"] += not ci["t_lo"] <= 0.0 <= ci["t_hi"]
    assert miss["percentile"] / 400 > 0.10 and 0.02 < miss["t"] / 400 < 0.09
    assert "t_lo" not in stats.mean_interval(rng.normal(size=10), boot)
