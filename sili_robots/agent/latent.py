"""The latent strategy model: encoder E(tau^{j-1}) -> z^j, decoder D(s, a, z^j) -> (s', r).

Encoder aggregation (a design choice the paper leaves open): each transition (s, a, r, s') of
the previous interaction goes through the same 2 x 256 MLP, and the set of features is pooled by
mean *and* max before a linear head. The pooling is permutation-invariant, uses every timestep
(no fixed subsample that could miss the one informative step), and max-pooling lets one step,
e.g. the last one whose end position decides the opponent's next move, dominate a feature. The
time fraction t/H is part of s, so order is still available when it matters.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from sili_robots.agent.networks import mlp


def gumbel_straight_through(logits: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """One-hot of argmax(logits + g) forward; softmax((logits + g) / T) gradient backward."""
    gumbels = -torch.empty_like(logits).exponential_().log()
    soft = F.softmax((logits + gumbels) / temperature, dim=-1)
    hard = F.one_hot(soft.argmax(-1), logits.shape[-1]).to(soft.dtype)
    return hard - soft.detach() + soft


class LatentModel(nn.Module):
    """Encoder and decoder trained jointly on consecutive interaction pairs (j-1, j)."""

    def __init__(self, obs_dim: int, act_dim: int, latent_dim: int, hidden: int, kind: str):
        super().__init__()
        if kind not in ("discrete", "continuous"):
            raise ValueError(f"latent model kind must be discrete or continuous, got {kind!r}")
        self.kind = kind
        self.latent_dim = latent_dim
        tr_dim = 2 * obs_dim + act_dim + 1
        self.phi = nn.Sequential(
            nn.Linear(tr_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        self.head = nn.Linear(2 * hidden, latent_dim)
        self.decoder = mlp(obs_dim + act_dim + latent_dim, obs_dim + 1, hidden)

    def encode_logits(self, traj: torch.Tensor) -> torch.Tensor:
        """``traj``: [N, H, tr_dim] -> raw encoder output [N, latent_dim]."""
        h = self.phi(traj)
        pooled = torch.cat([h.mean(1), h.amax(1)], dim=-1)
        return self.head(pooled)

    def encode(self, traj: torch.Tensor, sample: bool = False) -> torch.Tensor:
        """The latent z; ``sample`` draws a straight-through Gumbel one-hot (training)."""
        out = self.encode_logits(traj)
        if self.kind == "continuous":
            return torch.tanh(out)
        if sample:
            return gumbel_straight_through(out)
        return F.one_hot(out.argmax(-1), self.latent_dim).to(out.dtype)

    def decode(self, obs: torch.Tensor, act: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Predicted [s' - s, r] from s, a and z (z broadcast over the time axis)."""
        z = z.unsqueeze(-2).expand(*obs.shape[:-1], z.shape[-1])
        return self.decoder(torch.cat([obs, act, z], dim=-1))

    def loss(
        self,
        prev_traj: torch.Tensor,
        obs: torch.Tensor,
        act: torch.Tensor,
        next_obs: torch.Tensor,
        rew: torch.Tensor,
    ) -> torch.Tensor:
        """Gaussian negative log-likelihood (unit variance, i.e. squared error) of interaction j
        given z^j = E(tau^{j-1}): the paper's max-likelihood objective."""
        z = self.encode(prev_traj, sample=True)
        pred = self.decode(obs, act, z)
        target = torch.cat([next_obs - obs, rew.unsqueeze(-1)], dim=-1)
        return F.mse_loss(pred, target)


def transitions(obs: torch.Tensor, act: torch.Tensor, rew: torch.Tensor) -> torch.Tensor:
    """Stack an interaction's (s, a, r, s') rows: obs [N, H+1, o], act [N, H, a], rew [N, H]."""
    return torch.cat([obs[:, :-1], act, rew.unsqueeze(-1), obs[:, 1:]], dim=-1)
