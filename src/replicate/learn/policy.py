"""The exported policy's modules and file: what a buoy's computer loads.

A policy file is TorchScript with a ``metadata.json`` beside the weights: the observation layout, the action's
meaning and the map between simulation and real coordinates. ``SwarmPolicy`` holds a per-region run's N stacked
actors, ``FleetPolicy`` the general policy's one shared actor for a fleet of any size. ``toolkit.export`` writes
them from training checkpoints; every wing that runs a policy reads it with ``load_policy``.
"""

from __future__ import annotations

import hashlib
import io
import json
import warnings
from pathlib import Path

import torch
from torch import nn

from replicate.core import artifacts
from replicate.core.artifacts import CheckpointError
from replicate.core.sections import SensorsConfig


class SwarmPolicy(nn.Module):
    """a_i = tanh(μ_i(o_i)) for every buoy i at once: obs [N, obs_dim] or [B, N, obs_dim] → actions, same shape
    with 2 in the last axis."""

    def __init__(self, weights: list[torch.Tensor], biases: list[torch.Tensor]):
        super().__init__()
        self.w0, self.w1, self.w2 = (nn.Parameter(w.detach().clone(), requires_grad=False) for w in weights)
        self.b0, self.b1, self.b2 = (nn.Parameter(b.detach().clone(), requires_grad=False) for b in biases)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        squeeze = obs.dim() == 2
        x = obs.unsqueeze(0) if squeeze else obs
        x = x.transpose(0, 1)  # [N, B, obs_dim]
        x = torch.relu(torch.baddbmm(self.b0, x, self.w0))
        x = torch.relu(torch.baddbmm(self.b1, x, self.w1))
        # the 64 → 2 layer as the training actor computes it (``maddpg.stacked_matmul``: column by column, as
        # row-vector products), so that the exported actions are the training actor's bit for bit on any CPU
        # (one ``bmm`` gave the same bits on an AVX-512 CPU and differed in the last bit on another)
        xt = x.transpose(1, 2)
        columns = [torch.bmm(self.w2[:, :, j:j + 1].transpose(1, 2), xt) for j in range(self.w2.shape[2])]
        a = torch.tanh(torch.cat(columns, dim=1).transpose(1, 2) + self.b2).transpose(0, 1)
        return a.squeeze(0) if squeeze else a


class FleetPolicy(nn.Module):
    """a_i = tanh(μ(o_i)) for every buoy of a fleet of any size with the one shared actor: obs [N, obs_dim] or
    [batch, N, obs_dim] → actions, same shape with 2 in the last axis. With a Lloyd prior (``prior`` per m),
    tanh(μ(o_i) + prior · o_i[centroid:centroid + 2]), the offset to the buoy's local centroid. ``reads`` > 0: μ
    reads the observation's first ``reads`` columns only (a network trained without the centroid's columns, to
    which the prior was added at deployment, ``export.export_general``); 0: all of them."""

    def __init__(self, net: nn.Sequential, prior: float = 0.0, centroid: int = 0, reads: int = 0):
        super().__init__()
        self.net = net
        if prior and centroid < 1:
            raise ValueError("a Lloyd prior reads the centroid's columns: give their index (centroid_dx's)")
        self.prior, self.centroid, self.reads = float(prior), int(centroid), int(reads)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        pre = self.net(obs[..., :self.reads] if self.reads > 0 else obs)
        if self.prior != 0.0:
            pre = pre + self.prior * obs[..., self.centroid:self.centroid + 2]
        return torch.tanh(pre)


class FleetMessagePolicy(nn.Module):
    """a_i = tanh(μ(o_i, messages)) for a fleet whose buoys hear each other (``messages.MessageActor``): obs
    [N, obs_dim] or [batch, N, obs_dim], pos [N, 2] or [batch, N, 2] (simulation units) and the buoys in service
    ``live`` (same shape without the last axis) → actions [..., N, 2]."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net
        self.hops: int = net.hops  # read by the runners: this policy takes positions

    def forward(self, obs: torch.Tensor, pos: torch.Tensor, live: torch.Tensor) -> torch.Tensor:
        one = obs.dim() == 2
        if one:
            obs, pos, live = obs.unsqueeze(0), pos.unsqueeze(0), live.unsqueeze(0)
        a = torch.tanh(self.net(obs, pos, live)) * live.unsqueeze(-1)
        return a.squeeze(0) if one else a


def takes_positions(module) -> bool:
    """Whether an exported general policy reads the fleet's positions beside its observations (messages)."""
    return hasattr(module, "hops")


def checksum(module, metadata: dict) -> str:
    """SHA-256 of a policy's tensors (names, shapes, bytes) and of its metadata but this very field: what a file
    carries so that a reader can tell it is the one that was written."""
    digest = hashlib.sha256(json.dumps({k: v for k, v in metadata.items() if k != "checksum"},
                                       sort_keys=True).encode())
    for name, tensor in sorted(module.state_dict().items()):
        digest.update(f"{name}{tuple(tensor.shape)}{tensor.dtype}".encode())
        digest.update(tensor.detach().contiguous().cpu().numpy().tobytes())
    return digest.hexdigest()


def save_policy(module: torch.jit.ScriptModule, metadata: dict, out: str | Path) -> None:
    """The TorchScript ``module`` with ``metadata`` as its ``metadata.json``, written atomically to ``out``; the
    metadata carries the ``checksum`` of both."""
    metadata["checksum"] = checksum(module, metadata)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.jit.save(module, buf, _extra_files={"metadata.json": json.dumps(metadata)})
    artifacts.atomic_write_bytes(out, buf.getvalue())


def sensor_config(meta: dict) -> SensorsConfig | None:
    """The sensors a run's actors observe with (``observation: local``), from their metadata."""
    return SensorsConfig(**meta["sensors"]) if meta.get("sensors") else None


def load_policy(path: str | Path) -> tuple[torch.jit.ScriptModule, dict]:
    """(policy, metadata) from an exported file."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: no policy file here")
    extra = {"metadata.json": ""}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            module = torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
        metadata = json.loads(extra["metadata.json"])
    except Exception as exc:  # noqa: BLE001 - any load failure is a corrupt file
        raise CheckpointError(f"{path}: not a readable exported policy ({type(exc).__name__}: {exc})") from exc
    if "checksum" not in metadata:  # written before policies carried one: read, but said
        warnings.warn(f"{path}: carries no checksum (exported by an older version), so damage to it cannot be "
                      "detected; export it again to add one", stacklevel=2)
    elif checksum(module, metadata) != metadata["checksum"]:
        raise CheckpointError(f"{path}: damaged: its weights or metadata are not the ones exported (checksum "
                              "mismatch); export the policy again")
    return module, metadata
