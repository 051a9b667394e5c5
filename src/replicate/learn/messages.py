"""An actor that hears its neighbours over several hops: message passing over the buoys each buoy hears.

The plain actor μ(o_i) reads one buoy's sensors: the 4 nearest buoys it hears, as offsets, and nothing of what
they sense. Learned coverage controllers that beat Lloyd pass messages over 2-3 hops of the communication graph
(LPAC, Agarwal et al. T-RO 2025: 3 hops; Gosrich et al. ICRA 2022): a buoy then learns of water, shore and
crowding two or three buoys away. Here, with ``general.learner.hops`` = H ≥ 1:

    h⁰_i = enc(ô_i)                                   ô_i: buoy i's observation in its canonical frame
    m^r_ij = relu(S_r h^r_j + P_r ĝ_i (p_j − p_i) / c)   for the buoys j that i hears (its K nearest within c)
    h^{r+1}_i = h^r_i + relu(U_r [h^r_i, mean_j m^r_ij])   r = 0 … H − 1
    a_i = tanh(ĝ_i⁻¹ head(h^H_i))

with c the communication range and K the sensors' neighbours (the graph is the one the sensors list: a buoy hears
exactly the buoys whose offsets it observes), ĝ_i buoy i's canonical compass frame (``symmetry.CompassCanonical``).
What a buoy sends, h_j, is computed in the sender's own canonical frame, so it does not turn with the world; what
the receiver reads of where it came from, p_j − p_i, is turned into the receiver's frame. Turning or mirroring the
whole world by g then leaves every h and every message unchanged and turns every action by g: the actor is
equivariant to the compass as the plain one is. A mean over the heard buoys: any N, any order. Lost buoys and the
padding of a batch of fleets (``live`` False) neither send nor act.

The policy needs the buoys' positions beside their observations, as a fleet's radio link would carry them; what
runs on buoy i reads only its own sensors and what the buoys it hears send, H rounds a step.
"""

from __future__ import annotations

import torch
from torch import nn

from replicate.learn.symmetry import CompassCanonical, d4


class MessageActor(nn.Module):
    """Pre-tanh actions of padded fleets: obs [B, N, D], pos [B, N, 2], live [B, N] bool → [B, N, 2] (module
    docstring). ``canonical`` False runs in the world's frame (``symmetry: none``)."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, hops: int, columns: list[str], neighbours: int,
                 comm_range: float, canonical: bool = True):
        super().__init__()
        self.hops, self.neighbours, self.comm_range, self.canonical = hops, neighbours, float(comm_range), canonical
        # the frames only (their buffers: the group's action on observations and actions); no network of their own
        self.compass = CompassCanonical(nn.Identity(), columns, d4())
        self.register_buffer("turns", torch.as_tensor(d4(), dtype=torch.float32))  # [G, 2, 2], g acting on p
        self.enc = nn.Sequential(nn.Linear(obs_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())
        self.send = nn.ModuleList([nn.Linear(hidden, hidden) for _ in range(hops)])
        self.where = nn.ModuleList([nn.Linear(2, hidden, bias=False) for _ in range(hops)])
        self.merge = nn.ModuleList([nn.Linear(2 * hidden, hidden) for _ in range(hops)])
        self.head = nn.Linear(hidden, act_dim)

    def heard(self, pos: torch.Tensor, live: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Whom each buoy hears: (j [B, N, K] their slots, rel [B, N, K, 2] p_j − p_i, w [B, N, K] 1.0 for a buoy
        heard, 0.0 for an empty slot): the K nearest live others within the communication range."""
        n = pos.shape[1]
        rel = pos[:, None, :, :] - pos[:, :, None, :]  # [B, N (i), N (j), 2]
        dist = rel.square().sum(-1)
        ok = live[:, None, :] & live[:, :, None] & (dist <= self.comm_range**2)
        ok = ok & ~torch.eye(n, dtype=torch.bool, device=pos.device)
        k = min(self.neighbours, n - 1)
        near, j = dist.masked_fill(~ok, float("inf")).topk(k, dim=-1, largest=False)  # [B, N, K]
        rel = rel.gather(2, j[..., None].expand(j.shape[0], j.shape[1], k, 2))
        return j, rel, torch.isfinite(near).to(pos.dtype)

    def forward(self, obs: torch.Tensor, pos: torch.Tensor, live: torch.Tensor) -> torch.Tensor:
        b, n = obs.shape[0], obs.shape[1]
        best = self.compass.frame(obs) if self.canonical else torch.zeros(b, n, dtype=torch.long, device=obs.device)
        h = self.enc(self.compass.into(obs, best) if self.canonical else obs)  # [B, N, H]
        if n > 1 and self.hops > 0:
            j, rel, w = self.heard(pos, live)
            # p_j − p_i in the receiver's frame, in units of the range: [B, N, K, 2]
            rel = torch.einsum("bnxy,bnky->bnkx", self.turns[best], rel) / self.comm_range
            count = w.sum(-1, keepdim=True).clamp(min=1.0)  # [B, N, 1]
            fleet = torch.arange(b, device=obs.device)[:, None, None]
            for send, where, merge in zip(self.send, self.where, self.merge):
                m = torch.relu(send(h)[fleet, j] + where(rel))  # [B, N, K, H]: what each heard buoy tells i
                mean = (m * w[..., None]).sum(2) / count
                h = h + torch.relu(merge(torch.cat([h, mean], dim=-1)))
        pre = self.head(h)
        return self.compass.back(pre, best) if self.canonical else pre

