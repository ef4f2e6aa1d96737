"""Observation wrappers for what a method may see beyond the ego's own observation.

``OracleObservation`` appends the true strategy's encoding (what Oracle observes);
``StrategyFlag`` appends the partial-observation flag "the opponent's strategy changed since
the last step" as the last element (SILI's third latent setting). Both read the task's ``info``,
which always carries the true strategy, so every task gets them without code of its own.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sili_robots.errors import ConfigError


def _task_of(env: Any, wrapper: str) -> Any:
    """The sili task under ``env``: the wrappers read what only a task's ``info`` carries."""
    from sili_robots.tasks.base import RepeatedInteractionEnv

    task = env.unwrapped if isinstance(env, gym.Env) else None
    if not isinstance(task, RepeatedInteractionEnv):
        raise ConfigError(
            f"{wrapper} wraps a sili task (a RepeatedInteractionEnv, e.g. "
            f"gym.make('sili/Circle3-v1')), got {env!r}"
        )
    return task


class _AppendFromInfo(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Appends ``_extra(info)`` to every observation, within ``low``/``high``."""

    def __init__(self, env: gym.Env, low: np.ndarray, high: np.ndarray) -> None:
        _task_of(env, type(self).__name__)
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        base = env.observation_space
        if not isinstance(base, spaces.Box) or len(base.shape) != 1:
            raise ConfigError(
                f"{type(self).__name__} appends to a flat observation (a 1-D Box, as a sili "
                f"task's), got {base}: wrap the task before wrappers that reshape it"
            )
        self.observation_space = spaces.Box(
            np.concatenate([base.low, low]).astype(np.float32),
            np.concatenate([base.high, high]).astype(np.float32),
        )

    def _extra(self, info: dict[str, Any]) -> np.ndarray:
        raise NotImplementedError

    def _obs(self, obs: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        out = np.concatenate([np.asarray(obs, np.float32), self._extra(info)])
        return np.clip(out, self.observation_space.low, self.observation_space.high)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return self._obs(obs, info), info

    def step(self, action: np.ndarray):
        obs, r, term, trunc, info = self.env.step(action)
        return self._obs(obs, info), r, term, trunc, info


class OracleObservation(_AppendFromInfo):
    """Appends the true strategy's encoding (``info["strategy"]``)."""

    def __init__(self, env: gym.Env) -> None:
        task = _task_of(env, "OracleObservation")
        n = task.strategy_dim
        super().__init__(
            env,
            np.full(n, task.strategy_low, np.float32),
            np.full(n, task.strategy_high, np.float32),
        )

    def _extra(self, info: dict[str, Any]) -> np.ndarray:
        return np.asarray(info["strategy"], np.float32)


class StrategyFlag(_AppendFromInfo):
    """Appends 1.0 when the true strategy changed since the last step, else 0.0."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env, np.zeros(1, np.float32), np.ones(1, np.float32))

    def _extra(self, info: dict[str, Any]) -> np.ndarray:
        return np.array([float(info["strategy_changed"])], np.float32)
