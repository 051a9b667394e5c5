"""Cover any waterbody: outline (file or OSM place) → UTM → region → a policy → metrics, the comparison with the
baselines, and one evaluation episode for a GIS (``toolkit.field``: ``episode.gpkg``, GeoJSON, waypoints, the map
and the GIF) (``replicate cover``).

Two ways to get the policy:

* ``general`` (default): the general policy (``policies/general.pt``, installed with the package), zero-shot in
  seconds, or fine-tuned on this lake for ``finetune`` episodes (``cover_general``); compared with tuned naive
  swarming, tuned Lloyd and the best layout under the same physics (the shore as a wall).
* ``cr``: per-region CR-MARL trained from scratch with a configuration of params.yaml (``cover``); compared with
  the converged Lloyd layout.

Two scales:

* ``paper`` (default): the region is scaled to the paper's 9 m², N buoys of coverage radius R = 0.5 m.
* ``real``: the region keeps its size in metres and the buoys get a real coverage radius ``radius_m``. The
  simulation unit becomes ``L = radius_m / R`` metres, so the coverage polygon, the start patch, the SW ranges
  and the physics keep their paper values in simulation units; the region is ``A_real / L²`` simulation m², and
  the episode length grows with the region's linear size, ``T = T_paper · sqrt(A_sim / 9)`` (never shorter).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from replicate.compare.evaluate import (
    evaluate_baseline,
    evaluate_policy,
    evaluate_run,
    lloyd_name,
    read_general_policy,
)
from replicate.core import artifacts
from replicate.core.params import Params, run_config
from replicate.core.schema import ConfigError
from replicate.core.sections import IMITATION_UNTIL, SensorsConfig
from replicate.learn.general_train import GeneralTrainer
from replicate.learn.shared_maddpg import SharedActor
from replicate.learn.train import train
from replicate.toolkit.export import export_general
from replicate.toolkit.field import write_mission
from replicate.toolkit.plan import Mission, plan_of, plan_on
from replicate.world.osm import OSMUnavailable, outline_from_osm_xml, query_osm
from replicate.world.regions import RegionError, write_run_region
from replicate.world.scenario import horizon, scaled_setup
from replicate.world.units import BOB_SPEED, Units


def outline_path(region: str) -> Path:
    """``--region``'s file, refused by name when there is none (a named region is not a lake file)."""
    path = Path(region)
    if not path.exists():
        named = "" if path.suffix else (f"; a named region such as {region!r} goes with `replicate evaluate "
                                         "--policy` or `train`")
        raise RegionError(f"--region {region}: no such file; `cover` takes a lake's outline as a vector file "
                          f"(GeoJSON, shapefile, GeoPackage) or OSM XML{named}")
    return path


def outline_file(region: str | None, place: str | None, name: str | None, workdir: Path) -> Path:
    """A vector file holding the outline: the file given, an OSM XML file parsed, or an OSM place queried."""
    if (region is None) == (place is None):
        raise RegionError("give exactly one of --region FILE or --place NAME")
    if region is not None:
        path = outline_path(region)
        if path.suffix.lower() == ".osm":
            outline = outline_from_osm_xml(path, name or path.stem)
            outline.write(workdir / "outline.geojson")
            return workdir / "outline.geojson"
        return path
    try:
        outline = query_osm(place, name or place.split(",")[0], {"natural": "water"}, timeout=10)
    except OSMUnavailable as exc:
        raise RegionError(
            f"{exc}. Offline, download the outline elsewhere (GeoJSON, shapefile, GeoPackage or OSM XML) "
            f"and pass it with --region FILE"
        ) from exc
    outline.write(workdir / "outline.geojson")
    return workdir / "outline.geojson"


def cover(
    path: Path, params: Params, out: Path, episodes: int, seed: int = 0, n_agents: int | None = None,
    radius_m: float | None = None, config: str = "tuned", progress: bool = True, speed_ms: float = BOB_SPEED,
) -> dict:
    """Train CR-MARL on the waterbody in ``path`` and compare its coverage with the converged Lloyd layout."""
    region, params = scaled_setup(path, params, n_agents, radius_m)
    rc = run_config(params, config, "cr")
    n_envs = rc.algo.n_envs
    episodes = max(n_envs, episodes - episodes % n_envs)
    write_run_region(out / "run", region)  # resume, evaluate and export read the run's region from the folder
    train(rc, region, episodes, seed, out / "run", params.train.checkpoint_every, resume=False, progress=progress)
    method = evaluate_run(out / "run", params, region, progress=progress)
    lloyd = evaluate_baseline("lloyd_converged", params, region, config, progress=progress)
    p = plan_of(region, params, {f"CR-MARL ({config})": np.array(method["example"]["trajectory"]),
                                 "lloyd": np.array(lloyd["example"]["trajectory"])}, speed_ms)  # one clock
    write_mission(p, out, "episode", progress)
    summary = {
        **deployment(region, params, params.world.n_agents, params.world.episode_length, speed_ms),
        "episodes": episodes,
        "coverage": method["coverage"],
        "lloyd_coverage": lloyd["coverage"],
        "ratio_to_lloyd": method["coverage"]["mean"] / max(lloyd["coverage"]["mean"], 1e-12),
        "notes": list(region.notes),
    }
    artifacts.write_json(out / "summary.json", summary)
    return summary


def deployment(region, params: Params, n_agents: int, steps: int, speed_ms: float = BOB_SPEED) -> dict:
    """What a summary says of the deployment: the lake, its CRS and scale, its area, the fleet, the coverage
    radius in metres, the episode's steps, and in SI (``world.units``, buoys of top speed ``speed_ms``) the control
    period and the mission's duration."""
    units = Units.of(params.world, params.coverage, params.coverage.radius * region.scale, speed_ms)
    return {"region": region.name, "centre_lonlat": region.centre_lonlat(),
            "centre": region.centre_text(), "utm_crs": region.utm_crs,
            "scale_m_per_sim_m": region.scale,
            "area_m2": region.area * region.scale**2, "n_agents": n_agents,
            "radius_m": params.coverage.radius * region.scale, "episode_length": steps,
            "top_speed_ms": speed_ms, "control_period_s": units.period_s, "mission_s": units.steps_time_s(steps)}


def finetuned(policy: Path, module, meta: dict, params: Params, region, steps: int, episodes: int, seed: int,
              out: Path, progress: bool) -> dict:
    """Train the general policy ``policy`` (``module``, ``meta``) on this one lake for ``episodes`` (rounded down to
    ``general.n_envs``) from its own weights, sensors and width, into ``out/finetune``, and export the kept actor
    to ``out/policy.pt`` → the run's summary. Its Lloyd prior, if it has one, is the file's, not ``params``', and
    does not fade."""

    if meta.get("lloyd_prior", {}).get("added_at_deployment"):
        raise ConfigError(f"{policy}: its Lloyd prior was added at deployment to a network trained without it; "
                          "fine-tune the run's own export (without --lloyd-prior), then add the prior again")
    gc, weights = params.general, dict(module.state_dict())
    try:
        symmetry = meta.get("symmetry", "none")  # a symmetric actor's MLP sits inside its average
        hidden, layers = SharedActor.shape(weights, symmetry)
        learner = dataclasses.replace(gc.learner, hidden=hidden, layers=layers, symmetry=symmetry,
                                      imitation="none", imitation_until=IMITATION_UNTIL,  # no teacher here
                                      lloyd_prior=meta.get("lloyd_prior", {}).get("gain_per_sim_m", 0.0),
                                      lloyd_prior_fade=0.0)  # the file's prior as it is deployed, unfaded
        gc = dataclasses.replace(gc, episodes=episodes - episodes % gc.n_envs, episode_length=steps,
                                 grown_horizon=False,  # ``steps`` is this lake's T already
                                 sensors=SensorsConfig(**meta["sensor_config"]), learner=learner)
        trainer = GeneralTrainer(params, seed, out / "finetune", progress, gc, worlds=[(region, params.world.n_agents)],
                                 actor=weights)
    except (KeyError, RuntimeError, ValueError) as exc:  # another network than the shared actor, or symmetry
        raise ConfigError(f"{policy}: its network is not the general policy's actor ({type(exc).__name__}); "
                          "give a policy exported from a general run (`replicate export RUN`)") from None
    trained = trainer.run()
    export_general(out / "finetune" / "actor.pt", out / "policy.pt", params.world.sensitivity,
                   meta.get("baseline_gains"))
    return trained


def cover_general(path: Path, params: Params, out: Path, policy: Path, finetune: int = 0, seed: int = 0,
                  n_agents: int | None = None, radius_m: float | None = None, progress: bool = True,
                  speed_ms: float = BOB_SPEED) -> dict:
    """The general policy on the waterbody in ``path``: zero-shot, or fine-tuned there first for ``finetune``
    episodes (``general_train`` on this one lake, from the policy's weights, keeping the best-validated actor,
    which is the starting one unless training beats it; written to ``out/finetune`` and ``out/policy.pt``).
    Evaluated from the corner patch with its baselines (``evaluate.evaluate_policy``); ``out/summary.json`` and
    its first episode beside Lloyd's and decentralised Lloyd's as ``out/episode.*`` (``toolkit.field``)."""

    region, params = scaled_setup(path, params, n_agents, radius_m)
    n = params.world.n_agents
    module, meta = read_general_policy(policy)
    steps = horizon(params.general, region, params.world.region_area)
    if finetune:
        trained = finetuned(policy, module, meta, params, region, steps, finetune, seed, out, progress)
        policy = out / "policy.pt"
    result = evaluate_policy(policy, region, params, n, "corner", progress=progress, geodesic=False)
    mission = Mission(n, params.coverage.radius * region.scale, speed_ms, seed=params.evaluate.seed)
    write_mission(plan_on(region, params, mission, policy), out, "episode", progress)
    lloyd = lloyd_name(result["baselines"])
    lloyd_coverage = result["baselines"][lloyd]["coverage"]
    summary = {
        **deployment(region, params, n, steps, speed_ms),
        "policy": str(policy),
        "finetune_episodes": trained["general"]["episodes"] if finetune else 0,
        "coverage": result["coverage"],
        "baselines": result["baselines"],
        "lloyd_baseline": lloyd,
        "lloyd_coverage": lloyd_coverage,
        "ratio_to_lloyd": result["ratio_to_lloyd"],
        "ratio_to_best": result["ratio_to_best"],
        "max_outside_m": result["max_outside_m"],
        "notes": list(region.notes),
    }
    if finetune:
        summary["finetune"] = {k: trained[k] for k in ("selected_episode", "selected_validation_coverage",
                                                        "cpu_seconds")}
    artifacts.write_json(out / "summary.json", summary)
    return summary
