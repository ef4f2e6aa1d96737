"""A minimal user task: the README's example of writing your own repeated-interaction task.

The ego moves along a line [-1, 1]; the opponent waits behind one of two doors, at -1 or +1.
Task reward: minus the distance to the opponent's door each step. Strategy dynamics: ending an
interaction nearer the middle than 0.8 makes the opponent switch doors; ending at the door (or
beyond 0.8 on either side) keeps it, so stabilizing means committing to one side.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.tasks import RepeatedInteractionEnv


class TwoDoorsEnv(RepeatedInteractionEnv):
    strategy_dim: ClassVar[int] = 1  # the door, -1 or +1 (what Oracle observes)
    strategy_low: ClassVar[float] = -1.0
    strategy_high: ClassVar[float] = 1.0
    game_state_fields: ClassVar[tuple[str, ...]] = ("door",)

    def __init__(self, horizon: int = 20) -> None:
        super().__init__(horizon=horizon)
        self.door, self.x = 1.0, 0.0

    def _make_action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (1,), np.float32)

    def _base_observation_space(self) -> spaces.Box:
        return spaces.Box(np.array([-1.0, 0.0], np.float32), np.array([1.0, 1.0], np.float32))

    def _initial_strategy(self) -> None:
        self.door = float(self.np_random.choice([-1.0, 1.0]))

    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        if not trajectory or abs(trajectory[-1]["x"]) < 0.8:  # no step: still in the middle
            self.door = -self.door

    def _begin_interaction(self) -> None:
        self.x = 0.0

    def _apply_action(self, action: np.ndarray) -> float:
        self.x = float(np.clip(self.x + 0.2 * action[0], -1.0, 1.0))
        return -abs(self.x - self.door)

    def _step_record(self) -> dict[str, Any]:
        return {"x": self.x}

    def _base_observation(self) -> np.ndarray:
        return np.array([self.x, self.time_fraction], np.float32)

    def strategy_id(self) -> float:
        return self.door

    def strategy_encoding(self) -> np.ndarray:
        return np.array([self.door], np.float32)
