"""Scripted reference policies, one ``stabilizing`` and one ``oracle`` per task.

They read the true strategy from the environment (they are references, not learners): the
stabilizing policy shows the behaviour SILI should discover (keep the opponent's strategy fixed,
at a small cost), the oracle policy the best task reward when z is known. Tests use them to
check each task's strategy dynamics end to end; ``random`` is there for previews and baselines.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sili_robots.errors import ConfigError
from sili_robots.tasks.base import RepeatedInteractionEnv

Policy = Callable[[RepeatedInteractionEnv, np.ndarray], np.ndarray]
SCRIPTED_KINDS = ("stabilizing", "oracle", "random")


def _toward(position: np.ndarray, target: np.ndarray, step: float) -> np.ndarray:
    """Unit-box velocity action that moves ``position`` to ``target`` as fast as allowed."""
    return np.clip((target - position) / step, -1.0, 1.0).astype(np.float32)


# -- Circle ---------------------------------------------------------------------------------
def circle_oracle(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Chase the true opponent location greedily."""
    from sili_robots.tasks.circle import STEP

    return _toward(env.position, env.opponent_position, STEP)


def circle_stabilizing(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Chase the opponent but stay just outside the circle, so it is held where it is."""
    from sili_robots.tasks.circle import RADIUS, STEP

    target = env.opponent_position * (RADIUS + 0.02) / RADIUS
    return _toward(env.position, target, STEP)


# -- Speaker-Listener ------------------------------------------------------------------------
def speaker_listener_oracle(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Go straight to the true goal (an upper bound: it knows the goal, not just the code)."""
    from sili_robots.tasks.speaker_listener import GOALS, STEP

    return _toward(env.position, GOALS[env.goal], STEP)


def speaker_listener_stabilizing(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Detour to the speaker first (locking its code), then decode the message and go there."""
    from sili_robots.tasks.speaker_listener import GOALS, MAPPINGS, SPEAKER, STEP

    if not env.visited_now:
        return _toward(env.position, SPEAKER, STEP)
    message = int(np.argmax(obs[2:5]))
    goal = MAPPINGS[env.mapping].index(message)
    return _toward(env.position, GOALS[goal], STEP)


# -- Driving -------------------------------------------------------------------------------------
def _lane_keeping(env: RepeatedInteractionEnv, lane: int) -> np.ndarray:
    """Lateral action that drives the ego to the centre of ``lane`` as fast as allowed."""
    from sili_robots.tasks.driving import DECISION_DT, EGO_LATERAL_SPEED
    from sili_robots.tasks.sumo_scenario import CENTRE_LANE, LANE_WIDTH

    target = (lane - CENTRE_LANE) * LANE_WIDTH
    return _toward(np.array([env.ego_y]), np.array([target]), EGO_LATERAL_SPEED * DECISION_DT)


def driving_stabilizing(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Merge left at once (before the red line): the opponent learns to go right."""
    from sili_robots.tasks.driving import LEFT

    return _lane_keeping(env, LEFT)


def driving_oracle(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Knowing the opponent's intended lane, pass in the other outer lane."""
    from sili_robots.tasks.driving import LEFT, RIGHT

    return _lane_keeping(env, LEFT if env.target_lane == RIGHT else RIGHT)


# -- Sawyer-Reach ------------------------------------------------------------------------------
def sawyer_oracle(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Reach the true goal and stay there."""
    from sili_robots.tasks.sawyer_reach import action_toward

    return action_toward(env, env.goal_position)


def sawyer_stabilizing(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Reach the true goal, then end the interaction just above the height plane."""
    from sili_robots.tasks.sawyer_reach import action_toward, stabilizing_point

    return action_toward(env, stabilizing_point(env))


SCRIPTED_POLICIES: dict[str, dict[str, Policy]] = {
    "CircleEnv": {"stabilizing": circle_stabilizing, "oracle": circle_oracle},
    "SpeakerListenerEnv": {
        "stabilizing": speaker_listener_stabilizing,
        "oracle": speaker_listener_oracle,
    },
    "DrivingEnv": {"stabilizing": driving_stabilizing, "oracle": driving_oracle},
    "SawyerReachEnv": {"stabilizing": sawyer_stabilizing, "oracle": sawyer_oracle},
}


def scripted_policy(env: RepeatedInteractionEnv, kind: str) -> Policy:
    """The scripted policy ``kind`` for ``env`` (its unwrapped task decides which)."""
    if kind not in SCRIPTED_KINDS:
        raise ConfigError(f"unknown scripted policy {kind!r}; allowed: {', '.join(SCRIPTED_KINDS)}")
    task = env.unwrapped
    if kind == "random":
        return lambda e, obs: task.action_space.sample()
    table = SCRIPTED_POLICIES.get(type(task).__name__)
    if table is None:
        raise ConfigError(f"no scripted policies for {type(task).__name__}")
    fn = table[kind]
    return lambda e, obs: fn(task, obs)
