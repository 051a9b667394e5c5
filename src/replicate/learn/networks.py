"""The networks a buoy's actor is made of: a ReLU MLP over its observation, and, when the observation holds a
local raster (``sensors.local_raster``), a small convolutional encoder that reads the raster as the image it is.

LPAC's robots read their local maps through a CNN (Agarwal et al. T-RO 2025); an MLP over the same cells would have
to learn from data that a cell's neighbours are its neighbours. Here two 3×3 convolutions (the first padded with
zeros, dry and uncovered, the second with stride 2) turn the raster's channels [C, k, k] into a few features, which
the MLP reads beside the other sensors. The raster's columns stay where ``sensors.columns`` puts them, so a compass
symmetry (``symmetry``) that permutes them turns the image, and the encoder sees the turned map.
"""

from __future__ import annotations

import math

import torch
from torch import nn

RASTER_FILTERS = 8  # channels of both convolutions


def mlp(sizes: list[int]) -> nn.Sequential:
    """ReLU MLP with a linear last layer."""
    layers: list[nn.Module] = []
    for k, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if k < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class RasterMLP(nn.Module):
    """μ(o) = MLP([o without the raster, CNN(raster)]): obs [..., D] → [..., out]. ``columns`` name the
    observation's; its ``raster_CHANNEL_A_B`` columns (``sensors.columns``: channel by channel, each row by row
    from the south, each row from the west) are the image [C, k, k]."""

    def __init__(self, columns: list[str], hidden: int, out: int, layers: int = 2):
        super().__init__()
        raster = [c for c, name in enumerate(columns) if name.startswith("raster_")]
        channels = len({name.split("_")[1] for name in columns if name.startswith("raster_")})
        self.channels, self.cells = channels, math.isqrt(len(raster) // max(channels, 1))
        if not raster or channels * self.cells**2 != len(raster):
            raise ValueError(f"a raster of square channels, got {len(raster)} raster columns in {channels} channels")
        self.register_buffer("raster_index", torch.as_tensor(raster))
        self.register_buffer("rest_index", torch.as_tensor([c for c in range(len(columns)) if c not in set(raster)]))
        self.encoder = nn.Sequential(nn.Conv2d(channels, RASTER_FILTERS, 3, padding=1), nn.ReLU(),
                                     nn.Conv2d(RASTER_FILTERS, RASTER_FILTERS, 3, stride=2), nn.ReLU(), nn.Flatten())
        features = self.encoder(torch.zeros(1, channels, self.cells, self.cells)).shape[-1]
        self.mlp = mlp([len(columns) - len(raster) + features, *[hidden] * layers, out])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        image = obs.index_select(-1, self.raster_index).reshape(-1, self.channels, self.cells, self.cells)
        seen = self.encoder(image).reshape(list(obs.shape[:-1]) + [-1])
        return self.mlp(torch.cat([obs.index_select(-1, self.rest_index), seen], dim=-1))


def observation_net(columns: list[str], in_dim: int, hidden: int, out: int, layers: int = 2) -> nn.Module:
    """The network over one buoy's observation [..., in_dim] → [..., out]: ``RasterMLP`` when ``columns`` hold a
    local raster, else the MLP of ``layers`` hidden layers ``hidden`` wide."""
    if any(name.startswith("raster_") for name in columns):
        return RasterMLP(columns, hidden, out, layers)
    return mlp([in_dim, *[hidden] * layers, out])
