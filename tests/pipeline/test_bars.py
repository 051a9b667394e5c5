"""The general policy's bars (``report.general``) can fail: random actions, put in the policy's place on a real lake
with arms under the suite's physics, starts and events, meet none of them."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from replicate.compare import baselines
from replicate.compare.best_layout import best_coverage
from replicate.compare.evaluate import rollout
from replicate.compare.rivals import general_baselines
from replicate.compare.suite import SuiteCell, drift_heading, suite_cells, suite_event, suite_lake
from replicate.core.studies import StartsConfig
from replicate.pipeline.report.general import general_checks
from replicate.world.coverage import coverage_fraction
from replicate.world.regions import at_density
from replicate.world.scenario import general_evaluation_env, horizon

from ..conftest import ROOT


@pytest.mark.slow
def test_random_actions_fail_every_bar(params):
    """Mae Kuang (arms: lloyd_tuned falls short of the best layout, so the narrow-lake bar applies) with 9 buoys
    from the corner: still water, a loss at T/2 and the suite's drift and vortex, 8 episodes each."""
    gains = json.loads((ROOT / "metrics/tuning/general_baselines.json").read_text())
    rivals, _ = general_baselines(params, gains, geodesic=False, decentralised=False)
    su, n = params.general.suite, 9
    region = at_density(*suite_lake(params, "mae_kuang_reservoir"), n)
    steps = horizon(params.general, region, params.world.region_area)
    cells = []
    for event in su.events:
        cell = SuiteCell("mae_kuang_reservoir", n, "corner", event, "real")
        lose, current = suite_event(su, event, n, drift_heading(params.evaluate.seed, cell), region.polygon)

        def covered(policy, lose=lose, current=current) -> float:
            env, _ = general_evaluation_env(params, region, n, 8, None, current)
            live = rollout(env, policy, steps, params.evaluate.seed, StartsConfig("corner", lose=lose))["live"]
            return float(coverage_fraction(region.polygon, live, params.coverage.radius, params.coverage.edges).mean())

        found = {name: covered(policy) for name, policy in rivals.items()}
        found["best_layout"] = best_coverage(region.polygon, n - lose, params.coverage.radius, params.coverage.edges)
        mine = covered(baselines.random_policy(np.random.default_rng(0)))
        cells.append({**dataclasses.asdict(cell), "coverage": {"mean": mine}, "max_outside_m": 0.0,
                      "baselines": {k: {"coverage": {"mean": v}} for k, v in found.items()}})
    checks = general_checks(cells, params.report.general)
    assert len(checks) == 7
    for bar, which, ok in checks:
        assert which and not all(ok), f"random actions meet the bar {bar!r}"


def test_no_committed_cell_beats_the_upper_bound(params):
    """The bound min(1, N·A(Cov)/A(Reg)) of the buoys in service holds over every cell of the committed suite
    (`metrics/general.json`): every seed, every controller, the planner and the best layout."""
    cells = json.loads((ROOT / "metrics/general.json").read_text())["cells"]
    over = []
    for c in cells:
        bound = c["baselines"]["upper_bound"]["coverage"]["mean"]
        found = {name: b["coverage"]["mean"] for name, b in c["baselines"].items() if name != "upper_bound"}
        found |= {seed: s["coverage"]["mean"] for seed, s in c["seeds"].items()}
        over += [(c["region"], c["n_agents"], c["start"], c["event"], k) for k, v in found.items() if v > bound + 1e-9]
    assert len(cells) == len(suite_cells(params)) and not over
