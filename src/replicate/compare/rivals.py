"""The general policy's comparisons: which controllers an evaluation runs beside it (``general_baselines``), the
Lloyd it is read against (``lloyd_name``), and the limits of a cell (the best layout and the upper bound)."""

from __future__ import annotations

from replicate.compare import baselines
from replicate.compare.decentralised import decentralised_lloyd
from replicate.compare.planner import clairvoyant_planner
from replicate.core.params import Params
from replicate.core.studies import LloydConfig, NaiveConfig
from replicate.world import coverage
from replicate.world.regions import Region


def general_baselines(params: Params, gains: dict | None, geodesic: bool = True, naive: bool = True,
                      decentralised: bool = False, planner: bool = False,
                      near_fleet: bool = False) -> tuple[dict[str, baselines.Policy], str]:
    """The general policy's comparisons → ({name: policy}, how their gains were set). With ``gains`` (the study of
    ``tuning.general_baselines``, carried in the policy's metadata): ``naive_tuned``, ``lloyd_tuned`` and
    geodesic Lloyd with its own tuned gains (Lloyd's where the study has none), each tuned once on the policy's
    training worlds, never on the lake evaluated; without them, the paper's hand-set ``naive`` and ``lloyd`` and
    geodesic Lloyd with Lloyd's.
    ``geodesic`` False leaves geodesic Lloyd out (its paths through the water cost the most of the three),
    ``naive`` False naive swarming; ``decentralised`` True adds decentralised Lloyd with its own tuned gains
    (likewise; ``compare.decentralised``: the buoys heard and the water sensed, on the geodesic
    raster); ``planner`` True adds the clairvoyant planner (``compare.planner``: the best layout, sailed to) steering
    with Lloyd's gains, its layout gathered near the fleet with ``near_fleet`` (a mission on a large lake)."""
    ev = params.evaluate
    if gains:
        naive_gains, lloyd = NaiveConfig(**gains["naive_tuned"]["gains"]), LloydConfig(
            **gains["lloyd_tuned"]["gains"], converged_steps=ev.lloyd.converged_steps)
        names, how = ("naive_tuned", "lloyd_tuned"), "tuned on the policy's training worlds"
    else:
        naive_gains, lloyd, names, how = ev.naive, ev.lloyd, ("naive", "lloyd"), "hand-set"
    rivals = {names[1]: baselines.lloyd(lloyd)}
    if naive:
        rivals = {names[0]: baselines.naive_swarming(naive_gains)} | rivals

    def own(name: str) -> LloydConfig:  # a Lloyd's own tuned gains where the study has them, else Lloyd's
        mine = (gains or {}).get(name)
        return LloydConfig(**mine["gains"], converged_steps=ev.lloyd.converged_steps) if mine else lloyd

    if geodesic:
        rivals["geodesic_lloyd"] = baselines.geodesic_lloyd(own("geodesic_tuned"), ev.geodesic.spacing,
                                                            ev.geodesic.lookahead)
    if decentralised:
        rivals["decentralised_lloyd"] = decentralised_lloyd(own("decentralised_tuned"), ev.geodesic.spacing)
    if planner:
        rivals["planner"] = clairvoyant_planner(lloyd, ev.geodesic.spacing, ev.geodesic.lookahead,
                                                near_fleet=near_fleet)
    return rivals, how


def lloyd_name(rivals: dict) -> str:
    """The Lloyd a general policy is read against among its baselines ``rivals`` (names as keys):
    ``lloyd_tuned`` when the policy carries tuned gains, else the hand-set ``lloyd``."""
    return "lloyd_tuned" if "lloyd_tuned" in rivals else "lloyd"


def limits(region: Region, params: Params, buoys: int, best: float | None, from_policy: bool = False) -> dict:
    """The best layout's coverage (``best``, when searched; ``from_policy``: the search from a policy's final layout
    found it) and the upper bound min(1, N·A(Cov)/A(Reg)) of ``buoys`` in service, as baselines: no layout covers
    more than the bound."""
    bound = coverage.coverage_ceiling(region.polygon.area, buoys, params.coverage.radius, params.coverage.edges)
    out = {"upper_bound": {"coverage": {"mean": bound}, "buoys": buoys}}
    layout = {"coverage": {"mean": best}, "buoys": buoys, "from_policy": from_policy}
    return out if best is None else {"best_layout": layout} | out


def rivals_and_limit(rivals: dict, covered, limit, aside: dict, phase) -> tuple[dict, tuple[float, bool]]:
    """Each rival's coverage (``covered(policy)``, or the result of its ``aside`` run in a second process) and
    the best layout's (``limit()`` → (coverage, whether a policy's layout gave it); (0, False) without one) →
    ({name: {"coverage"}}, (best, from_policy)). With a rival aside the best layout is searched first, while it
    runs."""
    best = (0.0, False)
    if limit is not None and aside:
        phase("the best layout")
        best = limit()
    out = {}
    for name, policy in rivals.items():
        phase(name)
        out[name] = {"coverage": aside[name].result() if name in aside else covered(policy)}
    if limit is not None and not aside:
        phase("the best layout")
        best = limit()
    return out, best
