"""Record a rollout frame by frame: what the scene needs to replay it, nothing more.

Any ``policy(env, obs) -> action`` works (scripted, random, a trained agent through a wrapper
env): the rollout is ``sili_robots.rollout.run_interactions``; the policy is wrapped to take a
snapshot at the start of each interaction and ``on_step`` takes one after every step, so an
interaction of H steps gives H + 1 frames (t = 0 .. H).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from sili_robots.rollout import run_interactions

Snapshot = Callable[[Any], dict[str, Any]]


@dataclass
class Recording:
    """Snapshots of the task's state, one per frame, plus who played."""

    task: str
    policy: str
    horizon: int
    interactions: int
    seed: int | None
    frames: list[dict[str, Any]] = field(default_factory=list)
    #: snapshot of things that never change (layout), taken once
    static: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frames)

    def series(self, key: str) -> np.ndarray:
        """One snapshot field over all frames, stacked."""
        return np.asarray([f[key] for f in self.frames])

    @property
    def last(self) -> int:
        return len(self.frames) - 1


def record_rollout(
    env: gym.Env,
    policy: Callable[[gym.Env, np.ndarray], np.ndarray],
    snapshot: Snapshot,
    interactions: int,
    seed: int | None = 0,
    task: str = "",
    policy_name: str = "",
    static: Snapshot | None = None,
) -> Recording:
    """Play ``interactions`` interactions and snapshot the unwrapped task at every frame."""
    task_env = env.unwrapped
    rec = Recording(
        task=task,
        policy=policy_name,
        horizon=int(task_env.horizon),
        interactions=interactions,
        seed=seed,
    )
    returns = [0.0]
    started = [0]  # interactions begun in this recording (the game may carry an older count)

    def take(reward: float) -> None:
        frame = snapshot(task_env)
        frame.update(
            interaction=started[0] - 1,
            game_interaction=int(task_env.interaction),
            t=int(task_env.t),
            strategy_id=float(task_env.strategy_id()),
            reward=float(reward),
            interaction_return=returns[0],
        )
        rec.frames.append(frame)

    def acting(e: gym.Env, obs: np.ndarray) -> np.ndarray:
        if task_env.t == 0:
            started[0] += 1
            returns[0] = 0.0
            if static is not None and not rec.static:
                rec.static = static(task_env)
            take(0.0)
        return policy(e, obs)

    def after_step(_s: np.ndarray, _a: np.ndarray, reward: float, *_after: Any) -> None:
        returns[0] += reward
        take(reward)

    run_interactions(env, acting, interactions, seed=seed, on_step=after_step)
    return rec
