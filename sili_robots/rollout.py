"""Roll a policy through a repeated game and summarise it per interaction."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np


@dataclass
class InteractionSummary:
    """What one interaction amounted to, in the terms the paper plots."""

    interaction: int
    task_reward: float  # sum of task rewards over the interaction
    strategy_changed: bool  # the true strategy changed at the boundary or within it
    strategy_id: float


def run_interactions(
    env: gym.Env,
    policy: Callable[[gym.Env, np.ndarray], np.ndarray],
    interactions: int,
    seed: int | None = 0,
    on_step: Callable[[np.ndarray, dict], None] | None = None,
    options: dict | None = None,
) -> list[InteractionSummary]:
    """Play ``interactions`` whole interactions, restarting the game with ``seed`` (and the
    first reset's ``options``, e.g. ``{"strategy": z}``)."""
    out: list[InteractionSummary] = []
    obs, info = env.reset(seed=seed, options=options)
    env.action_space.seed(seed)
    for j in range(interactions):
        if j > 0:
            obs, info = env.reset()
        changed = bool(info["strategy_changed"])
        total = 0.0
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(policy(env, obs))
            if on_step is not None:
                on_step(obs, info)
            total += float(reward)
            changed |= bool(info["strategy_changed"])
            done = terminated or truncated
        out.append(InteractionSummary(j, total, changed, float(info["strategy_id"])))
    return out
