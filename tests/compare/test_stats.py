"""Bootstrap intervals over seeds, differences and the probability of improvement (``replicate.compare.stats``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from replicate.compare import stats

BOOT = stats.Bootstrap(0.95, 2000, 0)


def test_interval_of_a_fraction_stays_in_the_unit_interval():
    rng = np.random.default_rng(0)
    for _ in range(20):
        v = np.clip(rng.normal(0.98, 0.05, size=5), 0, 1)
        ci = stats.mean_interval(v, BOOT)
        assert 0.0 <= ci["lo"] <= ci["mean"] <= ci["hi"] <= 1.0


def test_interval_is_seeded_and_iqm_drops_an_outlier():
    v = [0.70, 0.72, 0.71, 0.73, 0.20]
    assert stats.mean_interval(v, BOOT) == stats.mean_interval(v, BOOT)
    assert stats.mean_interval(v, BOOT)["iqm"] == pytest.approx(np.mean([0.70, 0.71, 0.72]))


def test_one_value_has_no_interval():
    ci = stats.mean_interval([0.5], BOOT)
    assert ci["mean"] == 0.5 and math.isnan(ci["lo"]) and ci["n"] == 1


def test_difference_of_means_and_its_interval():
    a, b = [0.72, 0.74, 0.70, 0.73, 0.75], [0.60, 0.61, 0.59]
    d = stats.difference([a], [b], BOOT)
    assert d["delta"] == pytest.approx(np.mean(a) - np.mean(b))
    assert 0 < d["lo"] < d["delta"] < d["hi"]
    constant = stats.difference([a], [0.71], BOOT)  # a baseline: one number, not resampled
    assert constant["delta"] == pytest.approx(np.mean(a) - 0.71) and constant["lo"] < constant["delta"]


def test_probability_of_improvement_counts_pairs_and_ties():
    assert stats.probability_of_improvement([[0.8, 0.9]], [[0.1, 0.2]], BOOT)["p"] == 1.0
    assert stats.probability_of_improvement([[0.1, 0.2]], [[0.8, 0.9]], BOOT)["p"] == 0.0
    assert stats.probability_of_improvement([[0.5, 0.5]], [[0.5, 0.5]], BOOT)["p"] == 0.5
    p = stats.probability_of_improvement([[0.1, 0.3, 0.5]], [[0.2, 0.4]], BOOT)  # 3 of 6 pairs
    assert p["p"] == pytest.approx(0.5) and 0.0 <= p["lo"] <= p["hi"] <= 1.0


def test_stratified_comparison_averages_the_regions():
    a = [[0.7, 0.8], [0.5, 0.6, 0.55]]
    b = [[0.6, 0.65], 0.5]
    d = stats.difference(a, b, BOOT)
    assert d["delta"] == pytest.approx(((0.75 - 0.625) + (0.55 - 0.5)) / 2)
    p = stats.probability_of_improvement(a, b, BOOT)
    assert p["p"] == pytest.approx((1.0 + 2.5 / 3) / 2)  # every pair; two seeds above the constant, one tie
