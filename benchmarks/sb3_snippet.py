"""What the README's Stable-Baselines3 snippet learns: PPO with one shared network over every buoy (SuperSuit's
PettingZoo → vector env), trained for several budgets of environment steps, each policy's final coverage over
evaluation episodes beside random and motionless actions on the same starts.

    pip install '.[sb3]' && python benchmarks/sb3_snippet.py --budgets 2000 100000 --json out.json

A measurement of a third-party learner on the environment, not part of the project's results; the README quotes it.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def episode_coverage(env_kwargs: dict, act, seeds) -> np.ndarray:
    """Final coverage of one episode per seed, every buoy acting by ``act(obs [N, d], rng) -> [N, 2]``."""
    from replicate.toolkit.pettingzoo_env import parallel_env

    env, out = parallel_env(**env_kwargs), []
    for seed in seeds:
        obs, infos = env.reset(seed=int(seed))
        rng = np.random.default_rng(int(seed))
        while env.agents:
            agents = list(obs)
            actions = act(np.stack([obs[a] for a in agents]), rng)
            obs, _, _, _, infos = env.step(dict(zip(agents, actions, strict=True)))
        out.append(next(iter(infos.values()))["coverage"])
    return np.array(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--budgets", type=int, nargs="+", default=[2_000, 100_000])
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env", default='{"region": "square", "config": "tuned"}',
                   help="parallel_env's keyword arguments as JSON (default: the README's)")
    p.add_argument("--json", default=None)
    args = p.parse_args()
    import supersuit as ss
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.utils import set_random_seed

    from replicate.toolkit.pettingzoo_env import parallel_env

    torch.set_num_threads(1)
    kwargs = json.loads(args.env)
    seeds = np.arange(10_000, 10_000 + args.episodes)  # evaluation starts no training episode used
    rows = {"random actions": episode_coverage(kwargs, lambda o, rng: rng.uniform(-1, 1, (len(o), 2)), seeds),
            "no motion": episode_coverage(kwargs, lambda o, rng: np.zeros((len(o), 2)), seeds)}
    seconds = {}
    for budget in args.budgets:
        vec = ss.pettingzoo_env_to_vec_env_v1(parallel_env(**kwargs))  # the README's lines
        vec = ss.concat_vec_envs_v1(vec, 4, num_cpus=0, base_class="stable_baselines3")
        set_random_seed(args.seed)  # the network and PPO's draws (SuperSuit's vector env takes no seed)
        start = time.perf_counter()
        model = PPO("MlpPolicy", vec, n_steps=50, batch_size=180).learn(budget)
        seconds[budget] = time.perf_counter() - start
        rows[f"PPO, {budget:,} steps"] = episode_coverage(
            kwargs, lambda o, rng, m=model: m.predict(o, deterministic=True)[0], seeds)
        rows[f"PPO sampled, {budget:,} steps"] = episode_coverage(  # its Gaussian's draws, not its mean
            kwargs, lambda o, rng, m=model: np.clip(m.predict(o, deterministic=False)[0], -1, 1), seeds)
    for name, cov in rows.items():
        print(f"{name:>24}: coverage {cov.mean():.3f} ± {cov.std(ddof=1) / np.sqrt(len(cov)):.3f} "
              f"(over {len(cov)} episodes)")
    for budget, s in seconds.items():
        print(f"PPO {budget:,} steps trained in {s:.0f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"coverage": {k: float(v.mean()) for k, v in rows.items()}, "train_seconds": seconds}, f,
                      indent=1)


if __name__ == "__main__":
    main()
