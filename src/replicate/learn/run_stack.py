"""One run's part of a stacked ``MADDPG``: what its checkpoint holds, in the same form whatever the stack.

``MADDPG`` trains S runs (seeds) at once with every network and Adam moment stacked along the first axis
(run s holds rows s·N … s·N + N − 1). A run's checkpoint must not depend on the stack it trained in, so that it
resumes alone or beside any other runs: ``run_state`` cuts its rows out into the shapes of a one-run ``MADDPG``,
``load_run_state`` writes such a state back into any place of a stack.
"""

from __future__ import annotations

import torch

from replicate.learn.maddpg import MADDPG, NETWORKS, OPTIMISERS


def rows(agent: MADDPG, run: int) -> slice:
    """Run ``run``'s rows of every stacked tensor: its N agents."""
    return slice(run * agent.n, (run + 1) * agent.n)


def network_state(agent: MADDPG, name: str, run: int = 0) -> dict:
    """Run ``run``'s part of one network (a name of ``NETWORKS``), as a one-run MADDPG's ``state_dict`` holds it."""
    return {p: t[rows(agent, run)].clone() for p, t in getattr(agent, name).state_dict().items()}


def run_state(agent: MADDPG, run: int = 0) -> dict:
    """Run ``run``'s networks and Adam states, shaped as a one-run MADDPG's."""
    mine = rows(agent, run)
    state = {k: network_state(agent, k, run) for k in NETWORKS}
    for k in OPTIMISERS:
        full = getattr(agent, k).state_dict()
        part = {i: {"step": st["step"].clone(), "exp_avg": st["exp_avg"][mine].clone(),
                    "exp_avg_sq": st["exp_avg_sq"][mine].clone()} for i, st in full["state"].items()}
        state[k] = {"state": part, "param_groups": full["param_groups"]}
    return state


def load_run_state(agent: MADDPG, state: dict, run: int = 0) -> None:
    """Write a one-run state (``run_state``) into run ``run``'s part of the stack. Every run of a stack is loaded
    before it trains on: their Adam steps must agree."""
    mine = rows(agent, run)
    with torch.no_grad():
        for k in NETWORKS:
            net, theirs = getattr(agent, k), state[k]
            if set(theirs) != set(net.state_dict()):
                raise KeyError(f"{k}: parameters {sorted(theirs)} do not match")
            for name, t in net.state_dict().items():
                t[mine] = theirs[name]
    for k in OPTIMISERS:
        opt, theirs = getattr(agent, k), state[k]
        if not theirs["state"]:
            continue  # saved before the first update
        if not opt.state:
            opt.load_state_dict(_tiled(theirs, agent.runs))
        for p, st in zip(opt.param_groups[0]["params"], theirs["state"].values(), strict=True):
            moments = opt.state[p]
            if not torch.equal(moments["step"], st["step"]):
                raise ValueError(f"{k}: runs of one stack are at different steps")
            moments["exp_avg"][mine] = st["exp_avg"]
            moments["exp_avg_sq"][mine] = st["exp_avg_sq"]
        opt.param_groups[0]["lr"] = theirs["param_groups"][0]["lr"]


def _tiled(one: dict, runs: int) -> dict:
    """An optimiser state for a stack of ``runs``, every run's moments tiled from one run's (then overwritten)."""
    def tile(t):
        return t.repeat(runs, *[1] * (t.dim() - 1))

    return {"state": {i: {"step": st["step"].clone(), "exp_avg": tile(st["exp_avg"]),
                          "exp_avg_sq": tile(st["exp_avg_sq"])} for i, st in one["state"].items()},
            "param_groups": one["param_groups"]}
