"""The one rollout loop: play whole interactions of a repeated game with any policy.

``play_interaction`` is used by training, evaluation, previews and ``sili rollout``;
``run_interactions`` plays several from a (re)started game and summarises each.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

#: called after each step: (obs, action, reward, next_obs, info)
StepCallback = Callable[[np.ndarray, np.ndarray, float, np.ndarray, dict[str, Any]], None]


@dataclass
class Interaction:
    """One played interaction: its arrays, and where the game went after it."""

    obs: np.ndarray  # [H+1, o]
    act: np.ndarray  # [H, a]
    rew: np.ndarray  # [H] task rewards
    strategy_id: float  # at its start
    end_strategy_id: float  # after its last step (differs where z may change within one)
    strategy_changed: bool  # the true strategy changed at its start or within it
    next_obs: np.ndarray | None  # the next interaction's first observation (after reset)
    next_info: dict[str, Any] | None

    @property
    def task_reward(self) -> float:
        return float(self.rew.sum())


@dataclass
class InteractionSummary:
    """What one interaction amounted to, in the terms the paper plots."""

    interaction: int
    task_reward: float  # sum of task rewards over the interaction
    strategy_changed: bool  # the true strategy changed at the boundary or within it
    end_strategy_id: float  # after its last step


def play_interaction(
    env: gym.Env,
    obs: np.ndarray,
    info: dict[str, Any],
    policy: Callable[[np.ndarray], np.ndarray],
    on_step: StepCallback | None = None,
    reset: bool = True,
) -> Interaction:
    """Play one interaction from (obs, info) to its end; with ``reset`` begin the next one."""
    h = env.unwrapped.horizon
    obs_seq = np.zeros((h + 1, obs.shape[0]), np.float32)
    act_seq = np.zeros((h, env.action_space.shape[0]), np.float32)
    rew_seq = np.zeros(h, np.float32)
    obs_seq[0] = obs
    changed = bool(info["strategy_changed"])
    strategy_id = float(info["strategy_id"])
    for t in range(h):
        a = policy(obs)
        prev = obs
        obs, r, _, _, info = env.step(a)
        if on_step is not None:
            on_step(prev, a, float(r), obs, info)
        obs_seq[t + 1], act_seq[t], rew_seq[t] = obs, a, r
        changed |= bool(info["strategy_changed"])
    end_id = float(info["strategy_id"])
    next_obs, next_info = env.reset() if reset else (None, None)
    return Interaction(obs_seq, act_seq, rew_seq, strategy_id, end_id, changed, next_obs, next_info)


def run_interactions(
    env: gym.Env,
    policy: Callable[[gym.Env, np.ndarray], np.ndarray],
    interactions: int,
    seed: int | None = 0,
    on_step: StepCallback | None = None,
    options: dict | None = None,
) -> list[InteractionSummary]:
    """Play ``interactions`` whole interactions, restarting the game with ``seed`` (and the
    first reset's ``options``, e.g. ``{"strategy": z}``); ``on_step`` sees each step, as in
    ``play_interaction``."""
    out: list[InteractionSummary] = []
    obs, info = env.reset(seed=seed, options=options)
    env.action_space.seed(seed)
    for j in range(interactions):
        last = j == interactions - 1
        played = play_interaction(env, obs, info, lambda o: policy(env, o), on_step, reset=not last)
        out.append(
            InteractionSummary(
                j, played.task_reward, played.strategy_changed, played.end_strategy_id
            )
        )
        obs, info = played.next_obs, played.next_info
    return out
