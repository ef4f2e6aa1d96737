"""Part of each RL batch from the newest interactions (``addons.recent``).

After a policy has held one strategy for a long time, the replay of the others is old; drawing
the fraction F of each batch's interactions from the newest N makes a new strategy's on-policy
data count sooner.
"""

from __future__ import annotations

import numpy as np

from sili_robots.agent.addon import AgentAddon


class RecentBatches(AgentAddon):
    name = "recent"

    def __init__(self, fraction: float, interactions: int) -> None:
        self.fraction, self.interactions = fraction, interactions

    def rl_interactions(self, j: np.ndarray) -> np.ndarray:
        m_recent = round(j.shape[1] * self.fraction)
        if m_recent:
            n = self.agent.buffer.n
            lo = max(0, n - self.interactions)
            j[:, :m_recent] = self.agent.rng.integers(lo, n, (j.shape[0], m_recent))
        return j
