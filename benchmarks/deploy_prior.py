"""Lloyd's law added at deployment to the network the standing baseline trained without it, on the yardstick lakes
and on the 50-buoy channel: how much each gain moves them, before a gain is put to `replicate compare`.

    python benchmarks/deploy_prior.py --seeds 1,2 --gains 0,3,10 --out FILE [--workers 2]
        every yardstick cell (the episodes of `replicate compare`) for the standing baseline's seeds
        (yardstick/runs/general-sS/actor.pt), each with a = tanh(network(o) + g * (c - p)) at every gain g (0: the
        baseline itself), c - p the local centroid's offset (`sensors.centroid`), which the network does not read;
        tuned Lloyd the unit. Prints each gain's mean coverage / lloyd_tuned per seed, in all and per event and start.
    python benchmarks/deploy_prior.py --channel --seeds 1,2 --gains 0,3,10 [--front] --out FILE
        the rectangle at 1 m² per buoy with 50 buoys from the corner (4 episodes, as benchmarks/channel.py --trace);
        --front: the prior only where no buoy heard lies ahead along c - p, (p_j - p_i) . (c - p) > 0.

Run from the repository root with the project's environment (`make setup`)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys

import standing
import torch

from replicate.compare.evaluate import read_general_policy
from replicate.compare.rivals import general_baselines
from replicate.compare.yardstick import yardstick_lakes
from replicate.core import artifacts
from replicate.core.executor import map_jobs
from replicate.core.params import load_params
from replicate.core.sections import SensorsConfig
from replicate.learn.shared_maddpg import SharedActor
from replicate.world.env import observation_columns
from replicate.world.regions import at_density, make_region

CHANNEL_BUOYS, CHANNEL_EPISODES = 50, 4


def with_prior(seed: int, gain: float, front: bool):
    """The standing baseline's seed ``seed`` with Lloyd's law added at ``gain`` → (policy of an environment, the
    sensors it runs on: the seed's with the centroid sensor)."""
    saved = artifacts.torch_load(standing.FOLDER.format(seed) + "actor.pt", "general policy")
    actor = SharedActor.from_checkpoint(saved).eval()
    sensors = dataclasses.replace(SensorsConfig(**saved["sensors"]), centroid=True)
    columns = observation_columns("local", sensors)
    reads, c, k = len(saved["columns"]), columns.index("centroid_dx"), sensors.neighbours
    others, heard = columns.index("neighbour0_dx"), columns.index("neighbour0_heard")

    def policy(env):
        obs = torch.as_tensor(env.observe(), dtype=torch.float32)
        offset = obs[..., c:c + 2]
        if front:  # 0 where a buoy heard lies ahead along the offset
            rel = obs[..., others:others + 2 * k].unflatten(-1, (k, 2))
            ahead = ((rel * offset.unsqueeze(-2)).sum(-1) > 0) & (obs[..., heard:heard + k] > 0)
            offset = offset * (~ahead.any(-1)).unsqueeze(-1)
        with torch.no_grad():
            action = torch.tanh(actor.net(obs[..., :reads]) + gain * offset).numpy()
        return action if env.alive is None else action * env.alive[..., None]

    return policy, sensors


def lake_rows(job: dict) -> list[dict]:
    """Every yardstick cell of one lake (a job of ``map_jobs``): tuned Lloyd and every seed at every gain."""
    torch.set_num_threads(1)
    params, cells = standing.lake_cells(job["params"], job["lake"])
    _, meta = read_general_policy(standing.FOLDER.format(job["seeds"][0]) + "policy.pt")
    lloyd = general_baselines(params, meta.get("baseline_gains"), False, False)[0]["lloyd_tuned"]
    versions = {f"g{gain:g}/{seed}": with_prior(seed, gain, job["front"])  # read once per lake
                for seed in job["seeds"] for gain in job["gains"]}
    rows = []
    for cell, episodes in cells:
        row = dataclasses.asdict(cell) | {"lloyd": episodes.run(lloyd, None)}
        rows.append(row | {name: episodes.run(*version) for name, version in versions.items()})
    return rows


def channel_rows(params, seeds: list[int], gains: list[float], front: bool) -> list[dict]:
    """The 50-buoy channel from the corner, still water: every seed at every gain."""
    torch.set_num_threads(1)
    params = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, episodes=CHANNEL_EPISODES))
    region = make_region("rectangle", params.regions["rectangle"], params.world.region_area)
    episodes = standing.Episodes(params, at_density(region, params.world.n_agents, CHANNEL_BUOYS), CHANNEL_BUOYS,
                                 "corner")
    return [{"seed": seed, "gain": gain, "front": front, "coverage": episodes.run(*with_prior(seed, gain, front))}
            for seed in seeds for gain in gains]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    standing.add_options(ap)
    ap.add_argument("--gains", default="0,3,10", help="the prior's gains per simulation metre, comma-separated")
    ap.add_argument("--channel", action="store_true", help="the 50-buoy channel instead of the yardstick")
    ap.add_argument("--front", action="store_true", help="the prior only where no buoy heard lies ahead")
    args = ap.parse_args(argv)
    seeds, gains = standing.numbers(ap, "--seeds", args.seeds, int), standing.numbers(ap, "--gains", args.gains)
    if not all(math.isfinite(g) and g >= 0 for g in gains):
        ap.error(f"--gains are 0 or above, got {args.gains}")
    params = load_params(args.params)
    if standing.refused(ap, args, params, seeds):
        return 2
    if args.channel:
        rows = channel_rows(params, seeds, gains, args.front)
        text = "\n".join(f"seed {r['seed']}, g {r['gain']:g}: {r['coverage']:.4f}" for r in rows)
    else:
        jobs = [{"params": args.params, "lake": lake, "seeds": seeds, "gains": gains, "front": args.front}
                for lake in yardstick_lakes(params)]
        rows = [row for rows in map_jobs(lake_rows, jobs, workers=args.workers, progress="lakes") for row in rows]
        text = "\n".join(standing.by_group(rows, [k for k in rows[0] if k.startswith("g")]))
    artifacts.atomic_write_text(args.out, json.dumps(rows, indent=1) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
