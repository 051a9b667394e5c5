"""``write_report``: read the pipeline's results, compute every table's rows (``claims``, ``general``, ``tables``)
and fill the template ``REPORT.md.j2``, which holds the report's words and layout."""

from __future__ import annotations

import json
import math
from dataclasses import astuple
from pathlib import Path

import jinja2

from replicate.core import artifacts
from replicate.core.params import Cell, RegionKey
from replicate.pipeline.report.claims import claims, comparisons, cpu_timed, sensitivity, targets
from replicate.pipeline.report.general import general_section, one_limit, tried_section
from replicate.pipeline.report.goals import goal_section
from replicate.pipeline.report.rules import fmt, fmt_t, span
from replicate.pipeline.report.tables import (
    ablation_rows,
    arithmetic_line,
    budget_confound,
    budgets,
    missing_runs,
    robustness_rows,
    seeds_section,
)

TEMPLATE = "REPORT.md.j2"


def read_json(path: str | None, default=None):
    return json.loads(Path(path).read_text()) if path and Path(path).exists() else default


def training_line(timing: dict) -> str | None:
    """The Time section's sentence on the training runs: their one-core seconds and how the stage ran."""
    if not timing:
        return None
    runs = timing["runs"]
    cores = [r["core_seconds"] for r in runs]
    kept = sum(r["skipped"] for r in runs)
    stage = (f"the last `train` stage took {timing['wall_seconds']:.0f} s wall and kept {kept} runs already "
             "finished with identical settings" if timing.get("wall_seconds") is not None else
             "the runs were trained by separate `train_matrix` calls, not one `train` stage")
    by_wall = sum(r.get("timed_by") != "cpu" for r in runs)
    if by_wall:
        stage += f"; {by_wall} runs recorded only their wall time, which work beside them on the machine inflates"
    return (f"Training: {len(runs)} runs, {sum(cores):.0f} s of one core's time in all ({span(cores)} s per run; a "
            "cell's seeds train together in one process, and a run counts its share of that process's CPU time, "
            f"or of its wall time where it recorded only that); {stage}.")


def robustness_context(params, summary: dict, regions: list[str]) -> dict:
    scenarios = list(params.evaluate.robustness)
    said = "; ".join(f"`{n}` = {s.start} start, {s.horizon:g} T" + (f", {s.lose} lost at half time" if s.lose else "")
                     for n, s in params.evaluate.robustness.items())
    return {"robustness": robustness_rows(summary, regions, scenarios), "scenarios_said": said,
            "robustness_header": "| region | policy | " + " | ".join(f"`{s}`" for s in scenarios) + " |",
            "robustness_rule": "|---|---|" + "---|" * len(scenarios)}


def seed_cpu(runs: dict) -> dict[int, float]:
    """{seed: one core's seconds} of the reported general seeds (``policies/summary.json``); empty without it."""
    return {r["seed"]: r["cpu_seconds"] for r in runs.get("runs", []) if r.get("cpu_seconds")}


def write_report(params, summary_path: str, timing_path: str, tuning_paths: dict[str, str], figures: list[str],
                 out: str, stage_times: dict, general_path: str | None = None,
                 comparisons_dir: str | None = None, general_runs_path: str | None = None) -> str:
    """Write ``REPORT.md`` to ``out`` from the pipeline's results → its text; with ``comparisons_dir`` the
    ``replicate compare`` records there (those with a verdict) are listed under the general policy, with
    ``general_runs_path`` (``policies/summary.json``) the reported seeds' training time beside its goal."""
    summary, timing = read_json(summary_path), read_json(timing_path, {})
    general = read_json(general_path)
    records = {p.stem: read_json(str(p)) for p in sorted(Path(comparisons_dir).glob("*.json"))} \
        if comparisons_dir else {}
    tuning = {k: read_json(p) for k, p in tuning_paths.items() if Path(p).exists()}
    rules = params.report
    cells = [Cell.parse(k) for k in summary["runs"]]
    regions = [r for r in params.regions if r in {c.region for c in cells} |
               {RegionKey.parse(k).region for k in summary["baselines"]}]
    context = {
        "episodes": params.evaluate.episodes, "level": f"{rules.level:.0%}", "margin": f"{rules.margin:.3f}",
        "t_below": rules.t_below,
        "sensitivity": " and × ".join(map(str, rules.sensitivity)), "target_seconds": f"{rules.target_seconds:.0f}",
        "missing": missing_runs(params, summary), "seeds": seeds_section(params),
        "claims": {config: list(zip(claims(summary, config, regions, rules),
                                    sensitivity(summary, config, regions, rules), strict=True))
                   for config in sorted({c.config for c in cells})},
        "comparisons": comparisons(summary, regions, rules), "targets": targets(summary, timing, rules),
        "wall_timed": bool(timing) and not cpu_timed(timing.get("runs", [])),
        "budgets": budgets(params, tuning), "budget_confound": budget_confound(params, tuning),
        **robustness_context(params, summary, regions),
        "general": [*general_section(params, general, summary),
                    *goal_section(params, one_limit(general["cells"]), seed_cpu(read_json(general_runs_path, {}))),
                    *tried_section({k: r for k, r in records.items() if "verdict" in r})]
        if general is not None else [],
        "ablation": ablation_rows(summary, rules.margin), "ablation_seeds": ", ".join(map(str, params.ablation.seeds)),
        "runs": [(Cell.parse(key), r) for key, r in summary["runs"].items()],
        "baselines": [(*astuple(RegionKey.parse(key)), b) for key, b in sorted(summary["baselines"].items())],
        "training": training_line(timing), "stage_times": stage_times,
        "arithmetic": arithmetic_line(timing["runs"]) if timing else None,
        "figures": [(Path(p).stem, Path(p).as_posix()) for p in figures], "nan": math.nan,
    }
    env = jinja2.Environment(loader=jinja2.PackageLoader("replicate.pipeline.report", "."), trim_blocks=True,
                             lstrip_blocks=True, keep_trailing_newline=True, undefined=jinja2.StrictUndefined,
                             autoescape=False)
    env.filters["fmt"] = fmt
    env.filters["fmt_t"] = fmt_t
    text = env.get_template(TEMPLATE).render(**context)
    artifacts.atomic_write_text(out, text)
    return text
