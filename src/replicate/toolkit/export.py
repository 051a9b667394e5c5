"""Policies a buoy can run: the trained decentralised actors as one TorchScript file per swarm.

The file holds the N stacked actors and, as ``metadata.json``, everything needed to use them without this
package: the observation layout, the action meaning, and the map between simulation and real coordinates
(``real = offset + scale · sim`` in the region's UTM CRS). Load it with ``torch.jit.load`` anywhere torch runs.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import torch

from replicate.core import artifacts
from replicate.core.artifacts import CheckpointError
from replicate.core.schema import ConfigError, to_dict
from replicate.core.sections import SensorsConfig
from replicate.learn.policy import FleetMessagePolicy, FleetPolicy, SwarmPolicy, save_policy, sensor_config
from replicate.learn.shared_maddpg import SharedActor
from replicate.learn.train import load_actors
from replicate.world.env import observation_columns
from replicate.world.regions import Region
from replicate.world.sensors import describe


def export_policy(actors_path: str | Path, region: Region, out: str | Path, sensitivity: float = 5.0) -> dict:
    """Write the run's actors as TorchScript with their metadata; returns the metadata."""
    net, meta = load_actors(actors_path)
    ident = meta["identity"]
    if ident.get("region_key") is not None:
        from replicate.world.geometry import region_key

        if region_key(region.polygon) != ident["region_key"]:
            raise CheckpointError(f"{actors_path}: trained on another region than {region.name!r}")
    with warnings.catch_warnings():  # TorchScript is deprecated upstream but is what a buoy's runtime loads
        warnings.simplefilter("ignore", DeprecationWarning)
        module = torch.jit.script(SwarmPolicy(list(net.weights), list(net.biases)))
    metadata = {
        "format": "buoy-swarm-coverage policy v1",
        "n_agents": int(net.weights[0].shape[0]),
        "agents": [f"buoy_{i}" for i in range(int(net.weights[0].shape[0]))],
        "observation": meta["observation"],
        "observation_layout": observation_columns(meta["observation"], sensor_config(meta)),
        "action": f"force direction in [-1, 1]^2 per buoy; force = {sensitivity} * action (simulation units)",
        "input_shape": "[N, obs_dim] or [batch, N, obs_dim], simulation coordinates",
        "region": region.name,
        "region_wkt_sim": region.polygon.wkt,
        "scale_m_per_sim_m": region.scale,
        "utm_crs": region.utm_crs,
        "offset": list(region.offset),
        "to_real": "utm = offset + scale * sim; sim = (utm - offset) / scale",
        "trained": {k: ident[k] for k in ("config", "method", "seed", "episodes")},
    }
    if meta["observation"] == "local":
        metadata["sensors"] = describe(sensor_config(meta))
        metadata["input_shape"] = "[N, obs_dim] or [batch, N, obs_dim], simulation units, in the buoy's own frame"
    save_policy(module, metadata, out)
    return metadata


def general_module(actor: SharedActor, sensors: SensorsConfig, columns: list[str], added_prior: float = 0.0):
    """A general actor as the TorchScript module its file holds → (module, its sensors, its observation's
    columns). ``added_prior`` g > 0 adds Lloyd's law at deployment to a network trained without it: a = tanh(μ(o) +
    g · (c − p)), the observation with the centroid sensor's columns (last), which μ does not read."""
    if added_prior and (actor.prior or actor.hops):
        raise ConfigError("a Lloyd prior is added at deployment to an actor trained without one and without "
                          "messages; this one has " + ("messages" if actor.hops else "its own prior") +
                          ": export it without --lloyd-prior")
    if added_prior:
        sensors = dataclasses.replace(sensors, centroid=True)
        full = observation_columns("local", sensors)
        reads = 0 if full == columns else len(columns)  # an actor trained with the sensor reads it as before
        if full[:len(columns)] != columns:  # the centroid sensor's columns come last (``sensors.columns``)
            raise CheckpointError("its observation's columns are not the sensors' own: export it without --lloyd-prior")
        policy = FleetPolicy(actor.net.eval(), added_prior, full.index("centroid_dx"), reads)
        columns = full
    elif actor.hops:
        policy = FleetMessagePolicy(actor.net.eval())
    else:
        policy = FleetPolicy(actor.net.eval(), actor.prior, actor.centroid)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return torch.jit.script(policy), sensors, columns


def export_general(actor_path: str | Path, out: str | Path, sensitivity: float = 5.0,
                   baseline_gains: dict | None = None, added_prior: float = 0.0) -> dict:
    """Write a general policy (``general_train``'s ``actor.pt``) as TorchScript with its metadata, carrying
    ``baseline_gains`` (naive swarming's, Lloyd's and decentralised Lloyd's, tuned on its training worlds) when
    given; with ``added_prior`` g, Lloyd's law added at deployment (``general_module``)."""

    saved = artifacts.torch_load(actor_path, "general policy")
    try:
        sensors = SensorsConfig(**saved["sensors"])
        actor = SharedActor.from_checkpoint(saved)
        trained = {"seed": saved["seed"], "selected_episode": saved["selected_episode"]}
    except (KeyError, TypeError, RuntimeError, ValueError) as exc:
        raise CheckpointError(f"{actor_path}: not a complete general policy's actor ({type(exc).__name__}: {exc}); "
                              "train it again with `replicate train-general`") from None
    try:
        module, sensors, columns = general_module(actor, sensors, saved["columns"], added_prior)
    except (ConfigError, CheckpointError) as exc:
        raise type(exc)(f"{actor_path}: {exc}") from None
    metadata = {
        "format": "buoy-swarm-coverage general policy v1",
        "n_agents": "any",
        "observation": "local",
        "observation_layout": columns,
        "sensors": describe(sensors),
        "sensor_config": to_dict(sensors),
        "action": f"force direction in [-1, 1]^2 per buoy; force = {sensitivity} * action (simulation units)",
        "input_shape": "[N, obs_dim] or [batch, N, obs_dim], simulation units, in the buoy's own frame",
        "scale": "simulation metres: the coverage radius is 0.5; real metres = simulation metres * radius_m / 0.5",
        "trained": trained,
    }
    if saved.get("symmetry", "none") != "none":  # an actor averaged over the compass's turns (``symmetry``)
        metadata["symmetry"] = saved["symmetry"]
    if actor.prior or added_prior:  # Lloyd's law toward the local centroid, which the network corrects
        metadata["lloyd_prior"] = {"gain_per_sim_m": actor.prior or added_prior,
                                   "columns": ["centroid_dx", "centroid_dy"],
                                   "action": "tanh(network(obs) + gain_per_sim_m * (centroid_dx, centroid_dy))"}
    if added_prior:
        reads = len(saved["columns"])  # the network's columns, the first of the file's
        metadata["lloyd_prior"] |= {"added_at_deployment": True, "network_reads": reads, "action": f"tanh(network("
                                    f"obs[..., :{reads}]) + gain_per_sim_m * (centroid_dx, centroid_dy))"}
    if actor.hops:  # the buoys' positions beside their observations (``learn.messages``)
        metadata["messages"] = {
            "hops": actor.hops, "heard": f"the {sensors.neighbours} nearest buoys within {sensors.comm_range} m",
            "inputs": "obs [N, obs_dim], pos [N, 2] (simulation metres, any common origin), live [N] bool "
                      "(the buoys in service); each with a leading batch axis or without"}
    if baseline_gains:
        metadata["baseline_gains"] = {k: {"gains": baseline_gains[k]["gains"], "study": baseline_gains[k].get("study")}
                                      for k in ("naive_tuned", "lloyd_tuned", "decentralised_tuned", "geodesic_tuned")
                                      if k in baseline_gains}
    save_policy(module, metadata, out)
    return metadata

