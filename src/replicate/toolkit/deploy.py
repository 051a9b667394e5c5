"""A policy on a buoy's computer: its commands from observations (``replicate act``, one call or a stream of
steps), and an exported general policy re-exported for one deployment's SI scale with its control contract
(``replicate export --policy FILE --radius-m R --speed-ms V``; ``world.units.contract``), as TorchScript and, for
runtimes without torch, as ONNX (the ``onnx`` extra: ``onnx`` to write it, ``onnxruntime`` to run it)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import IO

import numpy as np
import torch

from replicate.core.params import Params
from replicate.core.sections import SensorsConfig
from replicate.learn.policy import load_policy, save_policy
from replicate.world.units import Units, contract, to_simulation


class Actor:
    """An exported policy ready to act: ``actor(obs)`` [N, obs_dim] → actions [N, 2]. With ``units`` a general
    policy reads its observations in SI (metres, m/s) and converts them (``world.units.to_simulation``); a
    per-region policy reads ``real`` observations in UTM metres through its own map transform."""

    def __init__(self, path: str | Path, real: bool = False, units: Units | None = None):
        self.path, self.real = Path(path), real
        self.module, self.meta = load_policy(path)
        refuse_messages(path, self.meta)
        self.columns = list(self.meta["observation_layout"])
        self.general = self.meta.get("n_agents") == "any"
        if real and self.general and units is None:
            units = stated_units(self.meta)
        if real and self.general and units is None:
            raise ValueError(f"{path}: a general policy reads its sensors in simulation units (radius 0.5); with "
                             "--real give the deployment's --radius-m and --speed-ms (or export it for them, "
                             "`replicate export --policy FILE --radius-m R --speed-ms V`)")
        if real and not self.general and self.meta.get("utm_crs") is None:
            raise ValueError(f"{path}: the policy's region ({self.meta.get('region')}) is synthetic, with no map "
                             "coordinates; give its observations in simulation units (without --real)")
        self.units = units if real else None

    def __call__(self, observations) -> np.ndarray:
        obs = self.checked(observations)
        if self.real:
            obs = self.to_simulation(obs)
        with torch.no_grad():
            return self.module(torch.as_tensor(obs, dtype=torch.float32)).numpy()

    def checked(self, observations) -> np.ndarray:
        obs = np.asarray(observations, dtype=float)
        n = self.meta["n_agents"]
        if obs.ndim != 2 or obs.shape[1] != len(self.columns) or (n != "any" and obs.shape[0] != n):
            raise ValueError(f"expected observations of shape ({n}, {len(self.columns)}) "
                             f"[{', '.join(self.columns)}], got {obs.shape}")
        return obs

    def to_simulation(self, obs: np.ndarray) -> np.ndarray:
        """Real observations → the simulation units the policy reads."""
        if self.general:
            return to_simulation(obs, self.columns, self.units)
        scale, obs = self.meta["scale_m_per_sim_m"], obs.copy()
        if self.meta["observation"] == "local":  # lengths and speeds in the buoy's frame; a heard-mask stays
            lengths = [not c.endswith("_heard") for c in self.columns]
            obs[:, lengths] = obs[:, lengths] / scale
        else:
            obs[:, :2] = (obs[:, :2] - np.asarray(self.meta["offset"])) / scale
            obs[:, 2:] = obs[:, 2:] / scale
        return obs


def stated_units(meta: dict) -> Units | None:
    """The SI scale a policy was exported for (its contract's ``si``), or None."""
    si = meta.get("contract", {}).get("si")
    return None if si is None else Units(si["metres_per_sim_m"], si["seconds_per_sim_s"],
                                         si["control_period_s"] / si["seconds_per_sim_s"])


def act(path: str | Path, observations: np.ndarray, real: bool = False, units: Units | None = None) -> np.ndarray:
    """Commands for every buoy from its observation [N, obs_dim] (one call: ``Actor`` for many)."""
    return Actor(path, real, units)(observations)


def stream(actor: Actor, lines: IO[str] | None = None, out: IO[str] | None = None) -> int:
    """One step per line: each input line a JSON [N, obs_dim] list, each output line a JSON [N, 2] list of
    commands, flushed at once → the steps answered. A line that is not a table of the right shape is answered
    with ``{"error": ...}`` and the stream goes on."""
    lines, out, steps = lines or sys.stdin, out or sys.stdout, 0
    for line in lines:
        if not line.strip():
            continue
        try:
            obs = np.asarray(json.loads(line), dtype=float)
            if obs.ndim != 2 or not np.isfinite(obs).all():
                raise ValueError(f"expected a table of finite numbers, one row per buoy, got shape {obs.shape}")
            reply = np.round(actor(obs).astype(float), 6).tolist()
        except (ValueError, TypeError) as exc:
            reply = {"error": str(exc)}
        out.write(json.dumps(reply) + "\n")
        out.flush()
        steps += 1
    return steps


def refuse_messages(path, meta: dict) -> None:
    """A policy whose buoys pass messages (``learn.messages``) reads positions beside the observations, which the
    control contract (one buoy's observation in, its action out) does not carry yet: refused by name."""
    if meta.get("messages"):
        raise ValueError(f"{path}: a policy whose buoys pass messages ({meta['messages']['hops']} hops) reads the "
                         "fleet's positions beside its observations; the control contract carries observations "
                         "only. Run it with `replicate evaluate --policy` or `replicate plan`")


def export_for(policy: str | Path, out: str | Path, params: Params, units: Units,
               onnx_out: str | Path | None = None) -> dict:
    """A general policy re-exported with its control contract for one deployment's SI scale → the metadata; with
    ``onnx_out`` also as ONNX (``export_onnx``)."""
    module, meta = load_policy(policy)
    if meta.get("n_agents") != "any":
        raise ValueError(f"{policy}: a policy for {meta.get('n_agents')} buoys of one region; --radius-m and "
                         "--speed-ms re-export a general policy (`replicate export` of a general run)")
    refuse_messages(policy, meta)
    sensors = SensorsConfig(**meta["sensor_config"])
    meta = {k: v for k, v in meta.items() if k != "checksum"}
    meta["contract"] = contract(params.world, params.coverage, sensors, meta["observation_layout"], units)
    save_policy(module, meta, out)
    if onnx_out is not None:
        export_onnx(module, meta, onnx_out)
    return meta


def export_onnx(module, meta: dict, out: str | Path) -> None:
    """The policy as an ONNX graph (opset 17) with input ``obs`` [buoys, obs_dim] and output ``action`` [buoys, 2],
    any number of buoys, its metadata (the contract) as the model's ``metadata_props["buoy_policy"]``; written
    atomically. The TorchScript exporter is torch's only one that takes a scripted module (torch.export does not
    trace TorchScript), deprecated upstream: its warning is silenced here."""
    import warnings

    import onnx

    from replicate.core import artifacts

    obs = torch.zeros(2, len(meta["observation_layout"]))
    with artifacts.atomic_path(out) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(module, (obs,), str(tmp), dynamo=False, opset_version=17, input_names=["obs"],
                          output_names=["action"], dynamic_axes={"obs": {0: "buoys"}, "action": {0: "buoys"}})
        model = onnx.load(str(tmp))
        onnx.helper.set_model_props(model, {"buoy_policy": json.dumps(meta)})
        onnx.save(model, str(tmp))
