"""Detour Speaker-Listener: the ego (listener) must learn what a changeable speaker means.

Layout (documented choice): listener starts at the origin; three goal landmarks at radius 1 and
angles 90, 210 and 330 degrees; the stationary speaker at (0, -1.5), so visiting it is a detour
of about 1.5 on the way to any goal; visiting means coming within 0.3 of it. Action: velocity in
[-1, 1]^2 scaled by 0.1 per step; positions clipped to [-2, 2]^2; H = 50.

Each interaction draws a new true goal uniformly. The speaker's strategy is its *mapping* of goals
to messages (one of the 3! = 6 permutations); it utters ``mapping[goal]`` every step and the ego
observes the message as a one-hot. The speaker's mapping is *locked* while the ego has visited
it in the current interaction or in the previous one. While unlocked, before every step and at
the interaction boundary the mapping changes (to a different permutation, uniformly) with
probability 0.5. So visiting every interaction keeps the mapping fixed for good; this breaks
the "fixed within an interaction" assumption, which is why the paper uses partial observations
here (``strategy_flag=True``).
"""

from __future__ import annotations

import itertools
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.tasks.base import RepeatedInteractionEnv

GOALS = np.array([[0.0, 1.0], [-np.sqrt(3) / 2, -0.5], [np.sqrt(3) / 2, -0.5]])
SPEAKER = np.array([0.0, -1.5])
VISIT_RADIUS = 0.3
CHANGE_PROBABILITY = 0.5
STEP = 0.1
ARENA = 2.0
MAPPINGS = tuple(itertools.permutations(range(3)))  # mapping[goal] -> message


class SpeakerListenerEnv(RepeatedInteractionEnv):
    """The listener navigates to the goal named by a speaker whose code may drift."""

    strategy_dim: ClassVar[int] = len(MAPPINGS)  # one-hot of the mapping, what Oracle observes
    game_state_fields: ClassVar[tuple[str, ...]] = ("mapping", "visited_before")

    def __init__(self, horizon: int = 50, oracle: bool = False, strategy_flag: bool = False):
        self.position = np.zeros(2)
        self.goal = 0
        self.mapping = 0
        self.visited_now = False
        self.visited_before = False
        super().__init__(horizon=horizon, oracle=oracle, strategy_flag=strategy_flag)

    def _make_action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (2,), np.float32)

    def _base_observation_space(self) -> spaces.Box:
        low = np.array([-ARENA, -ARENA, 0, 0, 0, 0], np.float32)
        high = np.array([ARENA, ARENA, 1, 1, 1, 1], np.float32)
        return spaces.Box(low, high)

    # -- strategy
    @property
    def locked(self) -> bool:
        return self.visited_now or self.visited_before

    @property
    def message(self) -> int:
        return MAPPINGS[self.mapping][self.goal]

    def strategy_id(self) -> int:
        return self.mapping

    def strategy_encoding(self) -> np.ndarray:
        return np.eye(len(MAPPINGS), dtype=np.float32)[self.mapping]

    def _maybe_change_mapping(self) -> None:
        if self.np_random.random() < CHANGE_PROBABILITY:
            others = [m for m in range(len(MAPPINGS)) if m != self.mapping]
            self.mapping = int(self.np_random.choice(others))

    def _initial_strategy(self) -> None:
        self.mapping = int(self.np_random.integers(len(MAPPINGS)))
        self.visited_before = False

    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        self.visited_before = self.visited_now
        if not self.visited_before:
            self._maybe_change_mapping()

    def _within_interaction_update(self) -> None:
        if not self.locked and self.t < self.horizon:
            self._maybe_change_mapping()

    # -- dynamics
    def _begin_interaction(self) -> None:
        self.position = np.zeros(2)
        self.goal = int(self.np_random.integers(len(GOALS)))
        self.visited_now = False

    def _apply_action(self, action: np.ndarray) -> float:
        self.position = np.clip(self.position + STEP * action, -ARENA, ARENA)
        if np.linalg.norm(self.position - SPEAKER) <= VISIT_RADIUS:
            self.visited_now = True
        return -float(np.linalg.norm(self.position - GOALS[self.goal]))

    def _base_observation(self) -> np.ndarray:
        onehot = np.eye(3, dtype=np.float32)[self.message]
        return np.array([*self.position, *onehot, self.time_fraction], np.float32)
