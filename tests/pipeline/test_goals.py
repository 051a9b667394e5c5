"""``report.goals``: each goal of the learned policy read from the suite's cells, with how far it falls short."""

from __future__ import annotations

from replicate.pipeline.report.goals import Goal, goal_section, kind_goals


def cell(region, policy, lloyd, *, kind="test", n=9, start="corner", event="none", best=0.8, planner=None):
    """A suite cell whose two seeds cover ``policy`` (each seed's coverage) against ``lloyd``."""
    rivals = {"lloyd_tuned": lloyd, "decentralised_lloyd": lloyd - 0.1, "naive_tuned": lloyd - 0.05,
              "planner": planner or lloyd, "best_layout": best}
    return {"region": region, "kind": kind, "n_agents": n, "start": start, "event": event,
            "seeds": {f"s{i}": {"coverage": {"mean": v}} for i, v in enumerate(policy)},
            "baselines": {k: {"coverage": {"mean": v}} for k, v in rivals.items()}}


def test_each_goal_is_read_from_every_seed_and_says_how_far_it_falls_short(params):
    cells = [cell("lake-a", (0.72, 0.74), 0.70), cell("lake-b", (0.60, 0.70), 0.60, planner=0.70),
             cell("lake-b", (0.1, 0.1), 0.70, event="lose")]  # only still water is read
    goals = {g.goal: g for g in kind_goals(params, cells, "test")}
    mean = goals["still water: mean coverage ≥ 1.02 × lloyd_tuned's"]
    # the mean coverage against Lloyd's mean, (0.73 + 0.65) / (0.70 + 0.60), not the mean of the cells' shares
    assert abs(mean.value - 0.69 / 0.65) < 1e-12 and mean.met
    assert mean.row().endswith(f"| — | {0.8 / 0.65:.3f} | met |")  # the best layout 0.8 in both cells
    decentralised = goals["still water: mean coverage ≥ 1.15 × decentralised_lloyd's"]
    assert abs(decentralised.value - 0.69 / 0.55) < 1e-12 and decentralised.met
    every = goals["still water: every cell, every seed ≥ 98% of lloyd_tuned"]
    assert every.said == f"worst {0.70 / 0.70:.3f}; 2 of 2 cells" and every.met  # seed 0.60 of lake-b against 0.60
    naive = goals["still water: every cell, every seed above naive_tuned"]
    assert naive.said == f"worst {0.60 / 0.55:.3f}; 2 of 2 cells" and naive.met
    planner = goals["still water: every cell, every seed ≥ 95% of the planner"]
    assert planner.said == f"worst {0.60 / 0.70:.3f}; 1 of 2 cells" and not planner.met  # one seed of lake-b short
    assert f"| {0.95 - 0.60 / 0.70:.3f} | {0.8 / 0.70:.3f} | **not met** |" in planner.row()  # worst cell's layout
    assert kind_goals(params, cells, "real") == []  # no real lake among the cells


def test_above_naive_swarming_is_strict(params):
    """A seed level with naive swarming is not above it, as in the bar of ``report.general``."""
    level = cell("lake-a", (0.65, 0.66), 0.70)
    level["baselines"]["naive_tuned"]["coverage"]["mean"] = 0.65
    goals = {g.goal: g for g in kind_goals(params, [level], "test")}
    naive = goals["still water: every cell, every seed above naive_tuned"]
    assert naive.value == 1.0 and not naive.met and naive.said.endswith("0 of 1 cells")


def test_a_goal_above_the_best_layout_says_so():
    """A goal that asks more than the best layout gives is marked: no controller is known to reach it."""
    assert "| 1.010 (below the goal) | **not met** |" in Goal("g", "l", 1.0, 1.02, "1.000 ×", limit=1.01).row()
    assert "| 1.030 | **not met** |" in Goal("g", "l", 1.0, 1.02, "1.000 ×", limit=1.03).row()


def test_the_lake_files_the_channel_and_a_seeds_time_have_their_own_rows(params):
    g = params.report.goals
    lake = params.general.suite.real_lakes[0].rsplit("/", 1)[-1].removesuffix(".geojson")
    cells = [cell(lake, (0.70, 0.72), 0.60, kind="real", n=g.lake_fleet, best=0.75),
             cell(lake, (0.50, 0.52), 0.50, kind="real", n=g.lake_fleet + 1, best=0.75),  # another fleet: not a goal
             cell(g.channel, (0.64, 0.66), 0.75, kind="trained", n=g.channel_fleet)]
    text = "\n".join(goal_section(params, cells, {10: 400.0, 11: 2000.0}))
    assert f"| {lake}, N = {g.lake_fleet}, corner start | {0.71 / 0.75:.3f} | — | — | met |" in text
    assert f"N = {g.lake_fleet + 1}" not in text
    assert f"| 0.650 against 0.750 ({0.65 / 0.75:.3f} ×) | {1 - 0.65 / 0.75:.3f} | {0.8 / 0.75:.3f} | **not met** |" \
        in text
    assert f"| 2 seeds | 400-2000 s | {2000 - g.seed_cpu_s:.0f} s | — | **not met** |" in text
    assert "a reported seed" not in "\n".join(goal_section(params, cells))  # no run record: no row
