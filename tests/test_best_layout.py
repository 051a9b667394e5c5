"""The best layout (``replicate.best_layout``): the offline limit every method is read against."""

import json

import numpy as np
import pytest

from replicate.best_layout import best_layout, covered_area

from .conftest import ROOT


def test_the_square_reaches_its_ceiling(params, regions):
    """Nine polygons fit in the 3 × 3 m square without overlap: the best layout covers N·A(Cov)/A(Reg)."""
    xy, coverage = best_layout(regions["square"].polygon, 9, params.coverage.radius, params.coverage.edges)
    assert coverage == pytest.approx(0.7797, abs=2e-4)
    assert coverage == pytest.approx(covered_area(regions["square"].polygon, xy, 0.5, 30) / 9.0)


def test_bedok_beats_every_committed_lloyd_layout(params, regions):
    """On Bedok the best layout lies above Lloyd's, converged (500 steps) or at T, with any gains."""
    xy, coverage = best_layout(regions["bedok"].polygon, 9, params.coverage.radius, params.coverage.edges)
    baselines = json.loads((ROOT / "metrics" / "summary.json").read_text())["baselines"]
    lloyd = max(v["coverage"] for k, v in baselines.items() if k.startswith("lloyd") and k.endswith("/bedok"))
    assert coverage > lloyd and coverage > 0.76
    assert xy.shape == (9, 2) and np.isfinite(xy).all()
