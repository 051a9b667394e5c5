"""Where the learned policy's layout stops, and whether Lloyd's law settles it further: on the yardstick lakes.

    python benchmarks/settle.py --seeds 1,2 --out FILE [--workers 2]
        every cell of the yardstick (lake x fleet x start x event, the episodes of `replicate compare`) for the
        standing baseline's seeds (yardstick/runs/general-sS/policy.pt): the policy alone; the policy, then
        decentralised Lloyd (the buoys heard and the water sensed since the release, as the policy senses) for the
        last share of the horizon (--shares); decentralised Lloyd alone; tuned Lloyd, the unit. Beside it the mean
        coverage at each tenth of the horizon, as a share of the final, for the policy and for tuned Lloyd.
        Prints each version's mean coverage / lloyd_tuned over the cells, per event and start; FILE keeps the rows.

Run from the repository root with the project's environment (`make setup`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np
import standing
import torch

from replicate.compare.evaluate import fleet_policy, read_general_policy
from replicate.compare.rivals import general_baselines
from replicate.compare.yardstick import yardstick_lakes
from replicate.core import artifacts
from replicate.core.executor import map_jobs
from replicate.core.params import load_params
from replicate.core.sections import SensorsConfig
from replicate.world.scenario import horizon

TENTHS = np.linspace(0.1, 1.0, 10)


def settled(policy, lloyd, switch: int):
    """The policy until step ``switch``, then ``lloyd`` (called at every step, so that its memory of the water
    sensed runs from the release)."""

    def act(env):
        settling = lloyd(env)
        return settling if env.t >= switch else policy(env)

    return act


def lake_rows(job: dict) -> list[dict]:
    """Every yardstick cell of one lake (a job of ``map_jobs``)."""
    torch.set_num_threads(1)
    params, cells = standing.lake_cells(job["params"], job["lake"])
    seeds = {}  # seed → (its policy, its sensors, the rivals with its gains): read once per lake
    for seed in job["seeds"]:
        module, meta = read_general_policy(standing.FOLDER.format(seed) + "policy.pt")
        rivals, _ = general_baselines(params, meta.get("baseline_gains"), False, False, True, False)
        seeds[seed] = fleet_policy(module), SensorsConfig(**meta["sensor_config"]), rivals
    rows = []
    for cell, episodes in cells:
        steps = horizon(params.general, episodes.lake, params.world.region_area)
        row = dataclasses.asdict(cell)
        for seed, (policy, sensors, rivals) in seeds.items():
            if "lloyd" not in row:
                row["lloyd"], row["lloyd_rise"] = episodes.run(rivals["lloyd_tuned"], None, every=True)
                row["decentralised"] = episodes.run(rivals["decentralised_lloyd"], None)
            row[f"policy/{seed}"], row[f"policy_rise/{seed}"] = episodes.run(policy, sensors, every=True)
            for share in job["shares"]:
                switch = steps - round(share * steps)
                row[f"settled_{share}/{seed}"] = episodes.run(
                    settled(policy, rivals["decentralised_lloyd"], switch), sensors)
        rows.append(row)
    return rows


def summary(rows: list[dict]) -> str:
    """Each version's mean coverage / lloyd_tuned per event and start; the rise of coverage over the horizon."""
    versions = [k for k in rows[0] if k == "decentralised" or k.startswith(("policy/", "settled_"))]
    lines = standing.by_group(rows, versions)
    still = [r for r in rows if r["event"] == "none"]
    for name, key in (("tuned Lloyd", "lloyd_rise"), ("the policy", "policy_rise/")):
        rise = np.mean([r[k] for r in still for k in r if k.startswith(key)], axis=0)
        lines.append(f"{name}, still water: coverage at each tenth of the horizon / the final: "
                     + " ".join(f"{x:.3f}" for x in rise))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    standing.add_options(ap)
    ap.add_argument("--shares", default="0.2,0.35,0.5", help="the horizon's last shares Lloyd settles")
    args = ap.parse_args(argv)
    seeds, shares = standing.numbers(ap, "--seeds", args.seeds, int), standing.numbers(ap, "--shares", args.shares)
    if not all(0 < s < 1 for s in shares):
        ap.error(f"--shares lie between 0 and 1, got {args.shares}")
    params = load_params(args.params)
    if standing.refused(ap, args, params, seeds):
        return 2
    jobs = [{"params": args.params, "lake": lake, "seeds": seeds, "shares": shares} for lake in yardstick_lakes(params)]
    rows = [row for rows in map_jobs(lake_rows, jobs, workers=args.workers, progress="lakes") for row in rows]
    artifacts.atomic_write_text(args.out, json.dumps(rows, indent=1) + "\n")
    print(summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
