"""SMiRL's surprise-minimising reward: log-likelihood of a state under the states seen so far.

Density (documented choice): one diagonal Gaussian over *all* states visited so far in the run,
updated after each interaction with Welford's algorithm; the reward of step t is
log N(s_{t+1}; mean, diag(max(std, floor)^2)) under the density as it was before that
interaction, clipped to [-300, 300] as in the SMiRL authors' code. Over all visited states
(rather than the current episode) because the paper contrasts SILI's pairwise stability with
SMiRL's "history of previously visited states", and it keeps the policy's input unchanged.
The state is the whole observation, its last element t/H included: that element's term
depends on the step alone, which the policy sees, so it shifts the reward by a function of
time and leaves the best policy unchanged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class RunningGaussian:
    """Diagonal Gaussian with running mean and variance."""

    def __init__(self, dim: int, std_floor: float = 0.05) -> None:
        self.count = 0
        self.mean = np.zeros(dim)
        self.m2 = np.zeros(dim)
        self.std_floor = std_floor

    @property
    def std(self) -> np.ndarray:
        var = self.m2 / self.count if self.count > 1 else np.ones_like(self.m2)
        return np.maximum(np.sqrt(var), self.std_floor)

    def log_likelihood(self, x: np.ndarray) -> np.ndarray:
        std = self.std
        z = (np.asarray(x, np.float64) - self.mean) / std
        ll = -0.5 * (z**2).sum(-1) - np.log(std).sum() - 0.5 * len(std) * math.log(2 * math.pi)
        return np.clip(ll, -300.0, 300.0)

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, np.float64).reshape(-1, len(self.mean))
        n_b = len(x)
        mean_b = x.mean(0)
        m2_b = ((x - mean_b) ** 2).sum(0)
        total = self.count + n_b
        delta = mean_b - self.mean
        self.mean = self.mean + delta * n_b / total
        self.m2 = self.m2 + m2_b + delta**2 * self.count * n_b / total
        self.count = total

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "mean": self.mean.copy(), "m2": self.m2.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count = int(state["count"])
        self.mean = np.array(state["mean"])
        self.m2 = np.array(state["m2"])
