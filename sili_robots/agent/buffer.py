"""Replay of whole interactions, kept in order.

Interaction j is stored as its H+1 observations, H actions and H task rewards, plus the first
observation of interaction j+1 (where the critic bootstraps across the boundary) and the true
strategy's id (diagnostics only: the metrics and benchmarks that score the latents; Oracle reads
the strategy from its observation). Keeping interactions whole and in order gives the latent
model its (j-1, j) pairs and lets latents be recomputed for any j.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: what a checkpoint holds (earlier ones also hold "strategy", the true strategy's encoding,
#: which nothing read)
KEYS = ("obs", "act", "rew", "aux", "next_first", "strategy_id")


class InteractionBuffer:
    """Growable arrays of complete interactions (the paper keeps the whole history)."""

    def __init__(self, obs_dim: int, act_dim: int, horizon: int, capacity: int = 256) -> None:
        self.obs_dim, self.act_dim, self.horizon = obs_dim, act_dim, horizon
        self.n = 0
        self._alloc(capacity)

    def _alloc(self, capacity: int) -> None:
        h, o, a = self.horizon, self.obs_dim, self.act_dim
        new = {
            "obs": np.zeros((capacity, h + 1, o), np.float32),
            "act": np.zeros((capacity, h, a), np.float32),
            "rew": np.zeros((capacity, h), np.float32),
            "aux": np.zeros((capacity, h), np.float32),  # e.g. the SMiRL reward
            "next_first": np.zeros((capacity, o), np.float32),
            "strategy_id": np.zeros(capacity, np.float64),
        }
        if hasattr(self, "obs"):
            for k, v in new.items():
                v[: self.n] = getattr(self, k)[: self.n]
        for k, v in new.items():
            setattr(self, k, v)
        self.capacity = capacity

    def add(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        aux: np.ndarray,
        next_first: np.ndarray,
        strategy_id: float,
    ) -> int:
        """Store a finished interaction; returns its index."""
        if self.n == self.capacity:
            self._alloc(2 * self.capacity)
        i = self.n
        self.obs[i], self.act[i], self.rew[i], self.aux[i] = obs, act, rew, aux
        self.next_first[i] = next_first
        self.strategy_id[i] = strategy_id
        self.n += 1
        return i

    def state_dict(self) -> dict[str, Any]:
        return {"n": self.n, **{k: getattr(self, k)[: self.n].copy() for k in KEYS}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        n = int(state["n"])
        self.n = 0
        self._alloc(max(256, 1 << max(n - 1, 1).bit_length()))
        for k in KEYS:
            getattr(self, k)[:n] = state[k]
        self.n = n
