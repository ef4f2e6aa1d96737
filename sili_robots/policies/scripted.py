"""Scripted reference policies for every task.

They are references, not learners; ``sili bounds`` plays them to measure what each task allows.

- ``stabilizing`` reads the true strategy z and keeps it fixed at a small cost: the behaviour
  SILI should discover.
- ``oracle`` reads z and chases the task reward greedily, whatever happens to z next.
- ``random`` samples the action space; ``still`` is the zero action.
- ``blind`` is the best scripted *stabilizing* policy that does not see z: it acts on the
  strategy the previous interaction revealed (its rewards reveal it to any learner), never the
  current one. On Circle (Unequal) it holds the far location.
- ``tracking`` is the best scripted policy that neither sees z nor stabilizes: the greedy
  response to where the task's dynamics send z after the previous interaction's strategy (the
  weighted geometric median of the predicted targets), ending where the strategy moves on. It
  is the bound for a learner that models the strategy dynamics without stabilizing (LILI).

``blind`` and ``tracking`` exist for the Circle tasks, Speaker-Listener and Sawyer-Reach; on
Driving the stabilizing reference already does not read z.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from sili_robots.errors import ConfigError
from sili_robots.tasks.base import RepeatedInteractionEnv

Policy = Callable[[RepeatedInteractionEnv, np.ndarray], np.ndarray]
#: a per-task policy given what the ego believes about z (``None`` before anything is revealed)
Believing = Callable[[RepeatedInteractionEnv, np.ndarray, Any], np.ndarray]
SCRIPTED_KINDS = ("stabilizing", "oracle", "random", "still", "blind", "tracking")
KIND_DESCRIPTIONS = {
    "random": "uniformly random actions",
    "still": "the zero action",
    "oracle": "greedy chase of the true strategy (sees z)",
    "stabilizing": "keeps the true strategy fixed (sees z)",
    "blind": "keeps the strategy fixed without seeing z",
    "tracking": "predicts z from the last interaction, never stabilizes",
}


def _toward(position: np.ndarray, target: np.ndarray, step: float) -> np.ndarray:
    """Unit-box velocity action that moves ``position`` to ``target`` as fast as allowed."""
    return np.clip((target - position) / step, -1.0, 1.0).astype(np.float32)


def geometric_median(points: np.ndarray, weights: Sequence[float] | None = None) -> np.ndarray:
    """The point minimising the weighted sum of distances to ``points`` (Weiszfeld's method):
    where to wait for a target known only by a distribution over ``points``."""
    pts = np.asarray(points, float)
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    heavy = np.flatnonzero(w >= 0.5 - 1e-12)
    if heavy.size:  # a point carrying half the weight or more is the median
        return pts[heavy[0]].copy()
    x = (w[:, None] * pts).sum(0)
    for _ in range(200):
        d = np.maximum(np.linalg.norm(pts - x, axis=1), 1e-9)
        nxt = ((w / d)[:, None] * pts).sum(0) / (w / d).sum()
        if np.linalg.norm(nxt - x) < 1e-9:
            break
        x = nxt
    return x


class Revealed:
    """What an ego that does not see z can know about it: the strategy in effect during the
    previous interaction (that interaction's rewards reveal it), never the current one."""

    def __init__(self) -> None:
        self._interaction: int | None = None
        self._now: Any = None
        self.previous: Any = None

    def __call__(self, task: RepeatedInteractionEnv) -> Any:
        if task.interaction != self._interaction:
            follows = self._interaction is not None and task.interaction == self._interaction + 1
            self.previous = self._now if follows else None
            self._interaction = task.interaction
        self._now = task.strategy_id()  # kept for the next interaction, never used in this one
        return self.previous


# -- Circle ---------------------------------------------------------------------------------
def _circle_point(env: RepeatedInteractionEnv, strategy: Any) -> np.ndarray:
    from sili_robots.tasks.circle import RADIUS

    angle = float(strategy) if env.variant == "continuous" else float(env.angles[int(strategy)])
    return RADIUS * np.array([math.cos(angle), math.sin(angle)])


def _circle_hold(env: RepeatedInteractionEnv, point: np.ndarray) -> np.ndarray:
    """Reach ``point`` on the circle, stay there, and in the last steps step just far enough
    out (past the outside margin) that the opponent is held."""
    from sili_robots.tasks.circle import RADIUS, STEP

    clearance = env.outside_margin + 0.02
    u = point / np.linalg.norm(point)
    out = u * (RADIUS + clearance)
    remaining = env.horizon - env.t
    # diagonal moves at full speed (the count the packaged bounds were computed with), or more
    # where clipping the axes one by one makes the way out slower (margins past ~0.3)
    diagonal = math.ceil(clearance / (STEP * (abs(u[0]) + abs(u[1]))) - 1e-9)
    reach = math.ceil(clearance * np.abs(u).max() / STEP - 1e-9) + 1  # no way out takes longer
    if remaining > max(diagonal, reach):  # not yet: the way out is simulated only near the end
        return _toward(env.position, point, STEP)
    steps_out = max(diagonal, _steps_to_leave(env, point, out))
    return _toward(env.position, out if remaining <= steps_out else point, STEP)


def _steps_to_leave(env: RepeatedInteractionEnv, start: np.ndarray, out: np.ndarray) -> int:
    """Steps of ``_toward`` from ``start`` to ``out`` until the task counts the ego outside."""
    from sili_robots.tasks.circle import ARENA, STEP

    position, steps = start.astype(float), 0
    while env.ends_inside(position) and steps < env.horizon:
        position = np.clip(position + STEP * _toward(position, out, STEP), -ARENA, ARENA)
        steps += 1
    return steps


def circle_oracle(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Chase the true opponent location greedily."""
    from sili_robots.tasks.circle import STEP

    return _toward(env.position, env.opponent_position, STEP)


def circle_stabilizing(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Reach the opponent, then step just outside the circle at the end, so it is held."""
    return _circle_hold(env, env.opponent_position)


def circle_blind(env: RepeatedInteractionEnv, obs: np.ndarray, revealed: Any) -> np.ndarray:
    """Hold the strategy the last interaction revealed where it can be held, else (and before
    any is revealed) the first that can: on Unequal always the far location, the only one."""
    if env.variant == "continuous":
        belief = math.pi / 2 if revealed is None else revealed
    elif revealed is None or int(revealed) not in env.stable_locations:
        belief = min(env.stable_locations)
    else:
        belief = int(revealed)
    return _circle_hold(env, _circle_point(env, belief))


def circle_prediction(env: RepeatedInteractionEnv, revealed: Any) -> np.ndarray:
    """Where the opponent may be this interaction (equally likely points) after ``revealed``
    when the ego ended the last interaction inside."""
    from sili_robots.tasks.circle import JUMP

    if revealed is None:
        return _circle_point(env, math.pi / 2 if env.variant == "continuous" else 0)[None]
    if env.variant == "continuous":
        angles = float(revealed) + np.linspace(*JUMP, 33)
        return np.array([_circle_point(env, a) for a in angles])
    return np.array([_circle_point(env, k) for k in env.next_locations(int(revealed), True)])


def circle_tracking(env: RepeatedInteractionEnv, obs: np.ndarray, revealed: Any) -> np.ndarray:
    """Wait where the predicted opponent is nearest on average, ending inside the circle."""
    from sili_robots.tasks.circle import RADIUS, STEP

    target = geometric_median(circle_prediction(env, revealed))
    limit = RADIUS + env.outside_margin - 1e-3  # end inside: the tracker never holds
    norm = float(np.linalg.norm(target))
    if norm > limit:
        target = target * limit / norm
    return _toward(env.position, target, STEP)


# -- Speaker-Listener ------------------------------------------------------------------------
def speaker_listener_oracle(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Go straight to the true goal (an upper bound: it knows the goal, not just the code)."""
    from sili_robots.tasks.speaker_listener import GOALS, STEP

    return _toward(env.position, GOALS[env.goal], STEP)


def _decode(obs: np.ndarray, mapping: int) -> int:
    from sili_robots.tasks.speaker_listener import MAPPINGS

    return MAPPINGS[mapping].index(int(np.argmax(obs[2:5])))


def _detour_then(env: RepeatedInteractionEnv, goal: int) -> np.ndarray:
    """Visit the speaker at the point of its visit disk nearest ``goal``, then go to ``goal``."""
    from sili_robots.tasks.speaker_listener import GOALS, STEP, VISIT_RADIUS

    if env.visited_now:
        return _toward(env.position, GOALS[goal], STEP)
    away = GOALS[goal] - env.speaker
    door = env.speaker + 0.9 * VISIT_RADIUS * away / np.linalg.norm(away)
    return _toward(env.position, door, STEP)


def speaker_listener_stabilizing(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    """Detour to the speaker first (holding its code), then decode the message and go there."""
    return _detour_then(env, _decode(obs, env.mapping))


def speaker_listener_blind(
    env: RepeatedInteractionEnv, obs: np.ndarray, revealed: Any
) -> np.ndarray:
    """The detour, decoding with the code the last interaction revealed."""
    return _detour_then(env, _decode(obs, 0 if revealed is None else int(revealed)))


def speaker_listener_tracking(
    env: RepeatedInteractionEnv, obs: np.ndarray, revealed: Any
) -> np.ndarray:
    """No detour: decode with the code the last interaction revealed and go there.

    Unvisited, the code is unchanged with probability 1/2 and otherwise one of the five others,
    one of which decodes this message the same way: the decoded goal carries probability 0.6,
    so it is the geometric median of the goal's distribution.
    """
    from sili_robots.tasks.speaker_listener import GOALS, STEP

    goal = _decode(obs, 0 if revealed is None else int(revealed))
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


def sawyer_blind(env: RepeatedInteractionEnv, obs: np.ndarray, revealed: Any) -> np.ndarray:
    """Reach the goal the last interaction revealed, then rise above the plane at the end."""
    from sili_robots.tasks.sawyer_reach import action_toward, stabilizing_point

    goal = 0 if revealed is None else int(revealed)
    return action_toward(env, stabilizing_point(env, goal))


def sawyer_tracking(env: RepeatedInteractionEnv, obs: np.ndarray, revealed: Any) -> np.ndarray:
    """Wait midway between the two goals the opponent may have moved on to (it moves to either,
    uniformly, when the arm ends below the plane, as this policy always does)."""
    from sili_robots.tasks.sawyer_reach import action_toward
    from sili_robots.tasks.sawyer_scene import GOALS

    if revealed is None:
        return action_toward(env, GOALS[0])
    others = [g for g in range(len(GOALS)) if g != int(revealed)]
    return action_toward(env, GOALS[others].mean(axis=0))


def _still(env: RepeatedInteractionEnv, obs: np.ndarray) -> np.ndarray:
    return np.zeros(env.action_space.shape, env.action_space.dtype)


SCRIPTED_POLICIES: dict[str, dict[str, Policy]] = {
    "CircleEnv": {"stabilizing": circle_stabilizing, "oracle": circle_oracle},
    "SpeakerListenerEnv": {
        "stabilizing": speaker_listener_stabilizing,
        "oracle": speaker_listener_oracle,
    },
    "DrivingEnv": {"stabilizing": driving_stabilizing, "oracle": driving_oracle},
    "SawyerReachEnv": {"stabilizing": sawyer_stabilizing, "oracle": sawyer_oracle},
}
#: the policies that do not see z, given the strategy the previous interaction revealed
BELIEVING_POLICIES: dict[str, dict[str, Believing]] = {
    "CircleEnv": {"blind": circle_blind, "tracking": circle_tracking},
    "SpeakerListenerEnv": {"blind": speaker_listener_blind, "tracking": speaker_listener_tracking},
    "SawyerReachEnv": {"blind": sawyer_blind, "tracking": sawyer_tracking},
}


def available_kinds(env: gym.Env) -> tuple[str, ...]:
    """The scripted kinds that exist for ``env``'s task, in ``SCRIPTED_KINDS`` order (random
    and still on any task: they need no knowledge of it)."""
    name = type(env.unwrapped).__name__
    own = {"random", "still", *SCRIPTED_POLICIES.get(name, {}), *BELIEVING_POLICIES.get(name, {})}
    return tuple(k for k in SCRIPTED_KINDS if k in own)


def scripted_policy(env: gym.Env, kind: str) -> Policy:
    """The scripted policy ``kind`` for ``env``, wrapped or not (its unwrapped task decides
    which, and is what the policy reads)."""
    if kind not in SCRIPTED_KINDS:
        raise ConfigError(f"unknown scripted policy {kind!r}; allowed: {', '.join(SCRIPTED_KINDS)}")
    task = env.unwrapped
    name = type(task).__name__
    if kind not in available_kinds(env):
        raise ConfigError(
            f"no {kind!r} policy for {task.spec.id if task.spec else name}; allowed there: "
            f"{', '.join(available_kinds(env))}"
        )
    if kind == "random":
        return lambda e, obs: task.action_space.sample()
    if kind == "still":
        return lambda e, obs: _still(task, obs)
    if kind in ("blind", "tracking"):
        believing = BELIEVING_POLICIES[name][kind]
        revealed = Revealed()
        return lambda e, obs: believing(task, obs, revealed(task))
    fn = SCRIPTED_POLICIES[name][kind]
    return lambda e, obs: fn(task, obs)
