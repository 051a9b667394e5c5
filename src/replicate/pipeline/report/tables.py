"""The report's other tables as Markdown rows: search budgets, robustness, the ablation, the seeds, the cells
still missing, and the arithmetic the runs were trained by."""

from __future__ import annotations

from collections import Counter
from dataclasses import astuple

from replicate.core.params import Cell, RegionKey
from replicate.pipeline.report.rules import fmt, fmt_delta


def budgets(rules_params, tuning: dict) -> list[str]:
    """Markdown rows of every search: what it chose, trials or runs, one core's seconds."""
    hs = rules_params.tuning.hand_search
    rows = [f"| `{hs.config}` {hs.method.upper()}-MARL training values | by hand (`docs/TUNING.md`) | "
            f"{hs.configurations} configurations, {hs.runs} runs | {hs.cpu_seconds:,.0f} | {hs.note} |"]
    method = tuning.get("method")
    if method:
        ms = rules_params.tuning.method
        failed = f" (+ {method['failed_trials']} failed)" if method.get("failed_trials") else ""
        incumbent = (f"; the config's own values (a trial) {method['incumbent_coverage']:.3f}"
                     if method.get("incumbent_coverage") is not None else "")
        rows.append(f"| `{ms.config}` {ms.method.upper()}-MARL training values | Optuna TPE `{method['study']}` | "
                    f"{method['trials']} trials{failed} × {len(ms.seeds)} seeds × {ms.episodes:,} episodes on "
                    f"{', '.join(ms.regions)} | {method['cpu_seconds']:,.0f} | best tuning coverage "
                    f"{method['tuning_coverage']:.3f}{incumbent} |")
    for key, b in sorted(tuning.get("baselines", {}).items()):
        gains = ", ".join(f"{k} {v:.3g}" for k, v in b["gains"].items())
        rows.append(f"| {key} gains | Optuna TPE `{b['study']}` | {b['trials']} trials | {b['cpu_seconds']:,.0f} | "
                    f"{gains}; tuning coverage {b['tuning_coverage']:.3f} |")
    for key, b in sorted(tuning.get("general_baselines", {}).items()):
        gains = ", ".join(f"{k} {v:.3g}" for k, v in b["gains"].items())
        rows.append(f"| {key} gains for every lake | Optuna TPE `{b['study']}` on the general policy's training "
                    f"worlds | {b['trials']} trials | {b['cpu_seconds']:,.0f} | {gains}; tuning coverage "
                    f"{b['tuning_coverage']:.3f} |")
    return rows


def budget_confound(rules_params, tuning: dict) -> str:
    """The reading of CR against SW under ``tuned``: what each method's values cost to find (the hand search for
    one, the ``tuning.method`` study for the other), so that the difference is not read as the method's alone."""
    hs, method = rules_params.tuning.hand_search, tuning.get("method")
    if not method:
        return ""
    ms = rules_params.tuning.method
    return (f"`{hs.config}` {hs.method.upper()}-MARL against {ms.method.upper()}-MARL compares two searches as well as "
            f"two methods: {hs.method.upper()}'s values came from a hand search of {hs.cpu_seconds:,.0f} CPU-s "
            f"({hs.configurations} configurations), {ms.method.upper()}'s from an Optuna study of "
            f"{method['cpu_seconds']:,.0f} CPU-s on {', '.join(ms.regions)}; under `paper` both train with the same "
            "values and no search.")


def robustness_rows(summary: dict, regions: list[str], scenarios: list[str]) -> list[str]:
    """Markdown rows of the robustness table, one column per scenario: runs as mean [CI] over seeds, baselines
    as one value each (deterministic, same starts)."""
    rows = []
    for region in regions:
        for key, r in summary["runs"].items():
            cell = Cell.parse(key)
            if cell.region == region and r.get("robustness"):
                rows.append(f"| {region} | {cell.config} {cell.method.upper()}-MARL | "
                            + " | ".join(fmt(r["robustness"][s]["coverage"]) for s in scenarios) + " |")
        for name in ("naive", "naive_tuned", "lloyd", "lloyd_tuned"):
            b = summary["baselines"].get(RegionKey(name, region).key, {}).get("robustness")
            if b and set(scenarios) <= set(b):
                rows.append(f"| {region} | {name} | " + " | ".join(f"{b[s]:.3f}" for s in scenarios) + " |")
    return rows


def ablation_effect(delta: dict, margin: float) -> str:
    """The reading of an ablation row's Δ (with − without), by the rule of every comparison (``report.margin``): an
    interval above +margin helps, one below −margin hurts; any other (or none) shows no effect beyond the
    margin."""
    lo, hi = delta["lo"], delta["hi"]
    return "helps" if lo > margin else "hurts" if hi < -margin else "no effect beyond the margin"


def ablation_rows(summary: dict, margin: float) -> list[str]:
    lines = []
    for key, r in summary.get("ablation", {}).items():
        change, region = astuple(RegionKey.parse(key))
        keys = ", ".join(f"`{k}`" for k in r["keys"])
        d = r["delta"]
        effect = ablation_effect(d, margin)
        lines.append(f"| `{change}` | {keys} | {region} | {fmt(r['with'])} | {fmt(r['without'])} | "
                     f"{fmt_delta(d)} | {effect} | {r['with_per_seed']} | {r['without_per_seed']} |")
    return lines


def seeds_section(params) -> list[str]:
    t, ev, tc = params.train, params.evaluate, params.tuning
    lines = ["## Seeds", "", "Reported numbers use seeds and starts that chose nothing; searches use others.", "",
             "| what | seeds |", "|---|---|"]
    for config, seeds in t.seeds.items():
        lines.append(f"| `{config}` reported runs, training seeds | {', '.join(map(str, seeds))} |")
    lines += [f"| every reported evaluation (SPEC §8 and robustness) | starts from seed {ev.seed} |",
              f"| `{tc.method.config}` {tc.method.method.upper()}-MARL search, training seeds | "
              f"{', '.join(map(str, tc.method.seeds))} |",
              f"| every search's evaluation starts | seed {tc.starts_seed} |",
              f"| the hand search of `{tc.hand_search.config}` | {tc.hand_search.note} |",
              f"| the ablation | {', '.join(map(str, params.ablation.seeds))} (the first `tuned` seeds) |", ""]
    return lines


def missing_runs(params, summary: dict) -> list[str]:
    """Cells of the matrix (``pipeline`` × ``train.seeds``) with fewer evaluated seeds than params.yaml asks for,
    as "CELL: n of N seeds"."""
    matrix = params.stages.get("pipeline", {})
    out = []
    for config in matrix.get("configs", []):
        for method in matrix.get("methods", []):
            for region in matrix.get("regions", []):
                cell = Cell(config, method, region)
                want = params.train.seeds_of(config)
                have = summary["runs"].get(cell.key, {}).get("seeds", [])
                if set(want) - set(have):
                    out.append(f"`{cell.key}`: {len(set(have) & set(want))} of {len(want)} seeds")
    return out


def arithmetic_line(runs: list[dict]) -> str:
    """Which arithmetic (``replicate.learn.fingerprint.fingerprint``) trained the runs: one fingerprint means every
    run is reproducible bit for bit by the same code, libraries and CPU."""
    counts = Counter(r.get("arithmetic") or "not recorded" for r in runs)
    kinds = ", ".join(f"`{k}` ({n} run{'s' * (n != 1)})" for k, n in counts.most_common())
    if len(counts) == 1 and "not recorded" not in counts:
        return (f"Arithmetic: all {len(runs)} runs were trained by the same arithmetic, fingerprint "
                f"`{next(iter(counts))}` (`replicate.learn.fingerprint`: the numbers a fixed workload gives with this "
                "code, libraries and CPU).")
    return (f"Arithmetic: the runs carry {len(counts)} fingerprints, {kinds}: runs of different fingerprints were "
            "trained by code, libraries or CPUs that round differently, and a rerun reproduces only its own kind "
            "bit for bit (`replicate.learn.fingerprint`).")
