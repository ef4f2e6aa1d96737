"""Detour Speaker-Listener: the ego (listener) must learn what a changeable speaker means.

Layout (documented choice): listener starts at the origin; three goal landmarks at radius 1 and
angles 90, 210 and 330 degrees; a stationary speaker at ``speaker``; visiting it means coming
within ``VISIT_RADIUS`` (0.3) of it. Action: velocity in [-1, 1]^2 scaled by 0.1 per step;
positions clipped to [-2, 2]^2; H = 50.

Each interaction draws a new true goal uniformly. The speaker's strategy is its *mapping* of goals
to messages (one of the 3! = 6 permutations); it utters ``mapping[goal]`` every step and the ego
observes the message as a one-hot. A change of mapping is to a different permutation, uniformly,
with probability ``CHANGE_PROBABILITY`` = 0.5, under one of two rules (``change_rule``):

- ``"interaction"``: at the end of an interaction in which the ego has not gone near the speaker
  the mapping changes (with probability 0.5); a visit keeps it for the next interaction. At most
  one change per interaction, made by ``reset()``: seen in the observation it returns (t = 0).
- ``"step"``: within an interaction the mapping is *locked* while the ego has visited the
  speaker in it or in the previous one; while unlocked it changes with probability 0.5 before
  every step (about 25 changes in an unvisited interaction). At the boundary after an
  interaction it changes with probability 0.5 unless that interaction visited the speaker.

Either way the flag "changed since the last step" (``sili_robots.wrappers.StrategyFlag``) is
the partial observation the paper uses on this task.

Versions (``sili_robots.tasks.registry``):
- v0: ``change_rule="step"``, speaker at (0, -1.5). The message changes so often that, unvisited,
  it is noise, and the detour (about 1.5 each way) costs so much that the best detour-then-decode
  play scores -24.07 per interaction (``sili bounds``) against -3.85 for decoding with the
  mapping known.
- v1: ``change_rule="interaction"``, following the appendix: "If the ego agent has not gone near
  the speaker within the current interaction, the opponent's communication strategy changes
  with probability 0.5" (and the main text: going near the speaker keeps the strategy for the
  next interaction). The speaker at (0, -0.8), so the detour is a real trade, as in the paper's
  figure: it costs a few units per interaction, while decoding a drifting speaker with the
  mapping the last interaction revealed goes to a wrong goal 40% of the time (docs/tasks.md has
  the measured bounds).
"""

from __future__ import annotations

import itertools
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.errors import ConfigError, check_choice, is_number
from sili_robots.tasks.base import RepeatedInteractionEnv

GOALS = np.array([[0.0, 1.0], [-np.sqrt(3) / 2, -0.5], [np.sqrt(3) / 2, -0.5]])
SPEAKER = np.array([0.0, -1.5])  # the default (v0) speaker position
VISIT_RADIUS = 0.3
CHANGE_PROBABILITY = 0.5
CHANGE_RULES = ("step", "interaction")
STEP = 0.1
ARENA = 2.0
MAPPINGS = tuple(itertools.permutations(range(3)))  # mapping[goal] -> message


class SpeakerListenerEnv(RepeatedInteractionEnv):
    """The listener navigates to the goal named by a speaker whose code may drift."""

    strategy_dim: ClassVar[int] = len(MAPPINGS)  # one-hot of the mapping, what Oracle observes
    game_state_fields: ClassVar[tuple[str, ...]] = ("mapping", "visited_before")

    def __init__(
        self,
        horizon: int = 50,
        change_rule: str = "step",
        speaker: tuple[float, float] | list[float] = tuple(SPEAKER),
    ) -> None:
        check_choice("change_rule", change_rule, CHANGE_RULES)
        # two numbers (not "0.5", which numpy would read as one) in the arena
        if not (
            isinstance(speaker, (tuple, list, np.ndarray))
            and np.ndim(speaker) == 1
            and len(speaker) == 2
            and all(is_number(v) and abs(v) <= ARENA for v in speaker)
        ):
            raise ConfigError(
                f"speaker must be an (x, y) position in the arena [-{ARENA:g}, {ARENA:g}]^2, "
                f"got {speaker!r}"
            )
        self.change_rule = change_rule
        self.speaker = np.asarray(speaker, dtype=float)
        self.position = np.zeros(2)
        self.goal = 0
        self.mapping = 0
        self.visited_now = False
        self.visited_before = False
        super().__init__(horizon=horizon)

    def _make_action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (2,), np.float32)

    def _base_observation_space(self) -> spaces.Box:
        low = np.array([-ARENA, -ARENA, 0, 0, 0, 0], np.float32)
        high = np.array([ARENA, ARENA, 1, 1, 1, 1], np.float32)
        return spaces.Box(low, high)

    # -- strategy
    @property
    def locked(self) -> bool:
        """Whether the mapping cannot change before the next step (or the next interaction)."""
        if self.change_rule == "interaction":
            return self.visited_now
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

    def strategy_choices(self) -> list[int]:
        return list(range(len(MAPPINGS)))

    def _set_strategy(self, strategy: int) -> None:
        self.mapping = int(strategy)

    def _initial_strategy(self) -> None:
        self.mapping = int(self.np_random.integers(len(MAPPINGS)))
        self.visited_before = False

    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        self.visited_before = self.visited_now
        if not self.visited_before:
            self._maybe_change_mapping()

    def _within_interaction_update(self) -> None:
        if self.change_rule == "step" and not self.locked and self.t < self.horizon:
            self._maybe_change_mapping()

    # -- dynamics
    def _begin_interaction(self) -> None:
        self.position = np.zeros(2)
        self.goal = int(self.np_random.integers(len(GOALS)))
        self.visited_now = False

    def _apply_action(self, action: np.ndarray) -> float:
        self.position = np.clip(self.position + STEP * action, -ARENA, ARENA)
        if np.linalg.norm(self.position - self.speaker) <= VISIT_RADIUS:
            self.visited_now = True
        return -float(np.linalg.norm(self.position - GOALS[self.goal]))

    def _base_observation(self) -> np.ndarray:
        onehot = np.eye(3, dtype=np.float32)[self.message]
        return np.array([*self.position, *onehot, self.time_fraction], np.float32)
