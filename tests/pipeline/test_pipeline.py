"""The DVC pipeline end to end, on a copy of the repository with a tiny episode count, and its completeness."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from replicate.core.params import run_config
from replicate.pipeline.matrix import run_cost

from ..conftest import ROOT

# SPEC §9, per configuration: one PNG per panel, named after the paper's figure.
PER_CONFIG = [
    "fig_{c}_sw_square_reward", "fig_{c}_sw_square_spread",
    "fig_{c}_sw_rectangle_reward", "fig_{c}_sw_rectangle_spread",
    "fig_{c}_cr_square_reward", "fig_{c}_cr_square_spread",
    "fig_{c}_cr_rectangle_reward", "fig_{c}_cr_rectangle_spread",
    "fig_{c}_cr_bedok_reward", "fig_{c}_cr_bedok_spread",
    "fig_{c}_coverage_square", "fig_{c}_coverage_rectangle", "fig_{c}_coverage_bedok",
]
SELECTING = ["fig_{c}_evaluation_square", "fig_{c}_evaluation_rectangle", "fig_{c}_evaluation_bedok"]
ONCE = ["fig_agent_vs_region", "fig_overall_coverage", "fig_bedok_map"]
OUTPUT_DIRS = ("runs", "metrics", "figures", "notebooks/executed", "policies", "yardstick")


def expected_figures(configs, selecting=("tuned",)) -> set[str]:
    """Every panel; the configs that select their actors also plot their validation coverage."""
    return ({f"{name}.png" for name in ONCE} | {f"{n.format(c=c)}.png" for c in configs for n in PER_CONFIG}
            | {f"{n.format(c=c)}.png" for c in configs if c in selecting for n in SELECTING})


def copy_repo(dst: Path) -> None:
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    for rel in files:
        if rel.split("/")[0] in OUTPUT_DIRS or rel in ("dvc.lock", "REPORT.md"):
            continue  # start from nothing: the stages must produce every output
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        if (ROOT / rel).is_file():
            shutil.copy2(ROOT / rel, target)


def test_every_spec_figure_has_a_stage_output():
    """Completeness: the figures stage owns figures/, and every SPEC §9 panel is named by the figure code."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    outs = [next(iter(o)) if isinstance(o, dict) else o for o in stages["figures"]["outs"]]
    assert "figures" in outs
    source = (ROOT / "src" / "replicate" / "pipeline" / "figures.py").read_text()
    for name in ONCE + ["fig_{tag}_reward", "fig_{tag}_spread", "fig_{config}_coverage_{region_name}"]:
        assert name in source, f"no figure code writes {name}"
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert set(params["pipeline"]["regions"]) >= {"square", "rectangle", "bedok"}
    assert set(params["pipeline"]["methods"]) == {"sw", "cr"}


def test_train_general_depends_on_every_training_value_but_not_the_suite():
    """`train_general` lists the general.* keys one by one so that a change of the evaluation suite does not
    retrain the policy: a key added to `general` must be added there too, and the suite's must stay out."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    listed = {p for p in stages["train_general"]["params"] if isinstance(p, str)}
    assert {f"general.{key}" for key in params["general"] if key != "suite"} <= listed
    assert not any(p == "general" or p.startswith("general.suite") for p in listed)
    assert "general.suite" in stages["evaluate_general"]["params"]


def test_the_standing_baseline_trains_as_the_general_policy_trains_on_its_own_seeds():
    """`train_yardstick` (the yardstick's standing baseline) depends on what `train_general` depends on, with
    its own notebook and yardstick.seeds for general.seeds: a value that retrains the policy retrains the baseline."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    general, design = stages["train_general"], stages["train_yardstick"]
    assert [p if p != "general.seeds" else "yardstick.seeds" for p in general["params"]] == design["params"]
    assert [d.replace("train_general", "train_yardstick") for d in general["deps"]] == design["deps"]


def test_source_notebooks_are_stripped_and_short():
    for nb in (ROOT / "notebooks").glob("*.ipynb"):
        doc = json.loads(nb.read_text())
        code = [c for c in doc["cells"] if c["cell_type"] == "code"]
        assert all(not c.get("outputs") and c.get("execution_count") is None for c in code), nb.name
        assert "parameters" in code[0]["metadata"].get("tags", []), f"{nb.name}: first code cell is not tagged"
        lines = sum(len("".join(c["source"]).splitlines()) for c in code[1:])
        assert lines <= 25, f"{nb.name}: {lines} lines of code; logic belongs in src/replicate"


def test_cost_estimate_orders_the_cells_like_the_committed_runs(params):
    """The estimate that starts the costliest cells first is within a factor of 2 of one core's time for every
    committed 10,000-episode run trained in a stack of seeds, as the pipeline trains them, so the longest cells do
    start first."""
    timing = json.loads((ROOT / "runs" / "summary.json").read_text())
    # a run's time is one core's when it is its CPU time (`timed_by: cpu`); of the runs that recorded only their wall
    # time, only the stacks of three seeds were trained by a `train` stage two processes to two cores, the others
    # beside other work
    runs = [r for r in timing["runs"] if r["runs_in_process"] > 1
            and (r.get("timed_by") == "cpu" or r["runs_in_process"] == 3)]
    assert len(runs) > 10
    for r in runs:
        estimate = run_cost(run_config(params, r["config"], r["method"], r["region"]), params.train.episodes)
        assert 0.5 < estimate / r["core_seconds"] < 2.0, r


@pytest.mark.slow
def test_dvc_repro_end_to_end(tmp_path):
    repo = tmp_path / "repo"
    copy_repo(repo)
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["train"].update(episodes=50, seeds={"paper": [0, 1], "tuned": [0, 1]}, checkpoint_every=50)
    params["ablation"]["seeds"] = [0, 1]
    params["tuning"].update(starts=4)
    params["tuning"]["baselines"]["naive"]["trials"] = 3
    params["tuning"]["baselines"]["lloyd"]["trials"] = 3
    params["tuning"]["general_baselines"].update(starts=2, naive_trials=2, lloyd_trials=2, decentralised_trials=2,
                                                    geodesic_trials=2)
    params["general"].update(regions=["square"], fleet=[6], lakes=1, lake_fleet=[5, 5], lake_ratio=[1.0, 1.0],
                             n_envs=4, episodes=8, episode_length=10, learning_starts=50, batch_size=16,
                             buffer_size=1000, update_every=8, seeds=[0, 1])
    params["general"]["suite"].update(test_lakes=3, real_lakes=["data/lakes/lake_karaguz.geojson"], named_fleets=[5],
                                      lake_fleets=[6], starts=["random"], episodes=2)
    params["yardstick"].update(seeds=[2, 3], min_seeds=2)
    params["pipeline"]["configs"] = ["paper", "tuned"]
    params["pipeline"]["ablation"] = True  # the experiment `dvc exp run -S pipeline.ablation=true`, here in one go
    params["configs"]["tuned"]["select_every"] = 25  # so the checkpoint_selection ablation has last actors
    params["evaluate"].update(episodes=4)
    params["evaluate"]["lloyd"]["converged_steps"] = 60
    params["fetch_outline"]["nominatim_url"] = "http://127.0.0.1:9/"  # nothing listens: OSM is unreachable
    params["fetch_outline"]["timeout"] = 2
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    subprocess.run(["git", "init", "-q"], cwd=repo, check=True)
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"
    env = {**os.environ, "DVC_NO_ANALYTICS": "1", "PATH": path}
    proc = subprocess.run(["dvc", "repro"], cwd=repo, env=env, capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    lock = yaml.safe_load((repo / "dvc.lock").read_text())["stages"]
    declared = yaml.safe_load((repo / "dvc.yaml").read_text())["stages"]
    assert set(lock) == set(declared)
    for name, stage in lock.items():
        for out in stage.get("outs", []):
            assert (repo / out["path"]).exists(), f"{name}: declared output {out['path']} was not written"
    for nb in (repo / "notebooks" / "executed").glob("*.ipynb"):
        doc = json.loads(nb.read_text())
        errors = [o for c in doc["cells"] for o in c.get("outputs", []) if o.get("output_type") == "error"]
        assert not errors, f"{nb.name} raised {errors[0].get('ename')}"
    assert len(list((repo / "notebooks" / "executed").glob("*.ipynb"))) == len(declared)

    figures = {p.name for p in (repo / "figures").glob("*.png")}
    executed = repo / "notebooks" / "executed"
    shown = re.findall(r"!\[[^]]*\]\(([^)]+)\)", (executed / "figures.ipynb").read_text())
    assert {Path(s).name for s in shown} >= figures, "the figures notebook does not show every figure"
    assert all((executed / s).resolve().is_file() for s in shown), "a figure link of the notebook leads nowhere"
    missing = expected_figures(params["pipeline"]["configs"]) - figures
    assert not missing, f"figures not produced: {sorted(missing)}"
    gifs = {p.name for p in (repo / "figures").glob("*.gif")}
    regions = ("square", "rectangle", "bedok")
    assert gifs == {f"anim_{c}_cr_{r}.gif" for c in params["pipeline"]["configs"] for r in regions} | {
        "anim_general_lose.gif", "anim_general_current.gif"}
    assert "fig_general_lakes.png" in figures
    suite = json.loads((repo / "metrics" / "general.json").read_text())
    assert suite["seeds"][0] == f"s{json.loads((repo / 'policies' / 'summary.json').read_text())['kept_seed']}"
    assert all(set(c["seeds"]) == {"s0", "s1"} for c in suite["cells"])
    standing = json.loads((repo / "yardstick" / "summary.json").read_text())["runs"]
    assert [r["seed"] for r in standing] == [2, 3]
    assert all((repo / "yardstick" / r["policy"]).is_file() for r in standing)
    general = json.loads((repo / "metrics" / "tuning" / "general_baselines.json").read_text())
    assert {k: v["trials"] for k, v in general.items()} == {"naive_tuned": 2, "lloyd_tuned": 2,
                                                           "decentralised_tuned": 2, "geodesic_tuned": 2}
    outline = json.loads((repo / "data" / "bedok_outline.geojson").read_text())
    assert outline["features"][0]["properties"]["source"] == "fallback"
    assert "bundled" in (repo / "notebooks" / "executed" / "fetch_outline.ipynb").read_text()
    report = (repo / "REPORT.md").read_text()
    assert "## One policy for every lake" in report and "| 3 test lakes (mean) | 6 | random | none |" in report
    assert "| lake_karaguz | 6 | random | none |" in report  # a real lake, every cell
    assert "The paper's claims" in report and "| baseline | region | steps | coverage" in report
    assert report.count("![") == len(figures)
    assert "## Targets of `tuned` CR-MARL" in report and "| rule | verdict | sensitivity |" in report
    assert "## Robustness" in report and "## Search budgets" in report and "| naive_tuned | square |" in report
    assert "| lloyd_tuned gains for every lake |" in report
    ablation = report.split("## Ablation")[1].split("\n## ")[0]
    for change in params["ablation"]["changes"]:
        assert f"| `{change}` |" in ablation, f"no ablation row for {change}"
    assert "fig_ablation_square.png" in figures
    runs = json.loads((repo / "runs" / "summary.json").read_text())["runs"]
    trained_changes = len(params["ablation"]["changes"]) - 1  # checkpoint_selection reuses the tuned runs
    assert len(runs) == 2 * 2 * 3 * 2 + trained_changes * 2
    assert {r["runs_in_process"] for r in runs} == {2}, "each cell's two seeds train as one stack"
    status = subprocess.run(["dvc", "status"], cwd=repo, env=env, capture_output=True, text=True)
    assert "up to date" in status.stdout, status.stdout
