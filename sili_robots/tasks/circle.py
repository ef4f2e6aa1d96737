"""Circle point mass: the ego pursues an opponent it never sees, sitting on a circle.

Geometry (documented choice; the paper gives none): circle of radius 1 centred at the origin,
ego starts at the centre (Unequal: at (0, -0.5)), action is a velocity in [-1, 1]^2 scaled by
0.1 per step, positions clipped to [-2, 2]^2, H = 50. Every location is 1 away from the centre
(10 steps), so reaching it and then stepping out of the circle (a stabilizing "detour": v0 a few
hundredths, v1 at least one step, 0.15-0.17 per interaction) fits comfortably within H but costs
a little reward.

Strategy dynamics T^z: if the ego ends the interaction inside the circle the opponent jumps
counter-clockwise to the next location; ending outside keeps it. "Outside" means at least
``outside_margin`` beyond the circle (distance from the centre >= 1 + margin).
- ``3`` / ``8``: equally spaced locations, first at angle pi/2.
- ``continuous``: any angle; inside moves it on by an angle drawn uniformly in [pi/3, pi].
- ``unequal``: locations at 90, 210 and 330 degrees; the ego starts nearer the lower two, where
  the opponent always moves on (cannot be held); only the farther top location is held by
  ending outside. ``near_moves`` says where a near location is left for: ``counter-clockwise``
  (the next location) or ``random`` (either other location, drawn uniformly).

Versions (``sili_robots.tasks.registry``):
- v0: ``outside_margin=0`` (outside means distance >= 1) and ``near_moves="counter-clockwise"``.
  The opponent sits on the circle, so a greedy chaser that ends on it counts as outside and holds
  it: chasing is free stabilization, and on Unequal the near locations follow a fixed cycle an
  ego can predict and track (about -5.7 per interaction against -10.5 for holding the far one).
- v1: ``outside_margin=0.1`` (one full step): the paper has the ego stabilize by a deliberate act
  ("the ego agent ends each interaction outside the circle"), so ending on the opponent, or
  jittering around it, is inside. On Unequal, ``near_moves="random"``: the paper calls the near
  strategies *unstable* and has the baselines "greedily try to track" them; moving on at random
  makes them unpredictable to an ego that does not see z, so holding the far location is the
  best such an ego can do (the far location keeps the paper's counter-clockwise rule).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.errors import ConfigError, check_choice, compared, is_number
from sili_robots.tasks.base import RepeatedInteractionEnv

VARIANTS = ("3", "8", "continuous", "unequal")
NEAR_MOVES = ("counter-clockwise", "random")
RADIUS = 1.0
STEP = 0.1
ARENA = 2.0
#: Continuous: an angle the opponent moves on by is drawn uniformly from this range
JUMP = (math.pi / 3, math.pi)


class CircleEnv(RepeatedInteractionEnv):
    """Point-mass pursuit of a hidden opponent on a circle (four variants)."""

    strategy_dim: ClassVar[int] = 2  # the opponent's (x, y) position, what Oracle observes
    strategy_low: ClassVar[float] = -RADIUS
    strategy_high: ClassVar[float] = RADIUS
    game_state_fields: ClassVar[tuple[str, ...]] = ("location", "angle")
    identity_arguments: ClassVar[frozenset[str]] = frozenset({"variant"})

    def __init__(
        self,
        variant: str = "3",
        horizon: int = 50,
        outside_margin: float = 0.0,
        near_moves: str = "counter-clockwise",
    ) -> None:
        check_choice("Circle variant", variant, VARIANTS)
        check_choice("near_moves", near_moves, NEAR_MOVES)
        if not (is_number(outside_margin) and 0.0 <= outside_margin < ARENA - RADIUS):
            raise ConfigError(
                f"outside_margin must be a number in [0, {ARENA - RADIUS:g}) (outside must be "
                f"reachable in the arena), got {compared(outside_margin)}"
            )
        self.variant = variant
        self.outside_margin = float(outside_margin)
        self.near_moves = near_moves
        if variant == "unequal":
            self.angles = np.deg2rad([90.0, 210.0, 330.0])
            self.stable_locations = {0}
            self.start = np.array([0.0, -0.5])
        elif variant == "continuous":
            self.angles = np.empty(0)
            self.stable_locations = set()
            self.start = np.zeros(2)
        else:
            n = int(variant)
            self.angles = math.pi / 2 + 2 * math.pi * np.arange(n) / n
            self.stable_locations = set(range(n))
            self.start = np.zeros(2)
        self.position = self.start.copy()
        self.location = 0  # index into self.angles (discrete variants)
        self.angle = math.pi / 2  # continuous variant
        super().__init__(horizon=horizon)

    # -- spaces
    def _make_action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (2,), np.float32)

    def _base_observation_space(self) -> spaces.Box:
        return spaces.Box(
            np.array([-ARENA, -ARENA, 0.0], np.float32), np.array([ARENA, ARENA, 1.0], np.float32)
        )

    # -- strategy
    @property
    def opponent_angle(self) -> float:
        return self.angle if self.variant == "continuous" else float(self.angles[self.location])

    @property
    def opponent_position(self) -> np.ndarray:
        a = self.opponent_angle
        return RADIUS * np.array([math.cos(a), math.sin(a)])

    def strategy_id(self) -> int | float:
        return self.angle if self.variant == "continuous" else self.location

    def strategy_encoding(self) -> np.ndarray:
        return self.opponent_position.astype(np.float32)

    def _initial_strategy(self) -> None:
        if self.variant == "continuous":
            self.angle = float(self.np_random.uniform(0.0, 2 * math.pi))
        else:
            self.location = int(self.np_random.integers(len(self.angles)))

    def strategy_choices(self) -> list[int] | None:
        return None if self.variant == "continuous" else list(range(len(self.angles)))

    def _set_strategy(self, strategy: int | float) -> None:
        if self.variant == "continuous":
            self.angle = float(strategy) % (2 * math.pi)
        else:
            self.location = int(strategy)

    def ends_inside(self, position: np.ndarray) -> bool:
        """The strategy rule's test: closer to the centre than ``RADIUS + outside_margin``.

        Computed in floating point: one step of exactly 0.1 straight out from a location can land
        at 1.0999999999999999, inside; the scripted policies step 0.02 further."""
        return float(np.linalg.norm(position)) < RADIUS + self.outside_margin

    def next_locations(self, location: int, inside: bool) -> list[int]:
        """Where the opponent at ``location`` may be next interaction, each equally likely,
        when the ego ends ``inside`` (or not); discrete variants only."""
        if location in self.stable_locations:
            return [(location + 1) % len(self.angles)] if inside else [location]
        if self.near_moves == "random":
            return [k for k in range(len(self.angles)) if k != location]
        return [(location + 1) % len(self.angles)]

    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        inside = self.ends_inside(self.position)
        if self.variant == "continuous":
            if inside:
                jump = self.np_random.uniform(*JUMP)
                self.angle = float((self.angle + jump) % (2 * math.pi))
            return
        choices = self.next_locations(self.location, inside)
        if len(choices) == 1:  # no draw: the v0 games use the generator exactly as before
            self.location = choices[0]
        else:
            self.location = int(choices[self.np_random.integers(len(choices))])

    # -- dynamics
    def _begin_interaction(self) -> None:
        self.position = self.start.copy()

    def _apply_action(self, action: np.ndarray) -> float:
        self.position = np.clip(self.position + STEP * action, -ARENA, ARENA)
        return -float(np.linalg.norm(self.position - self.opponent_position))

    def _base_observation(self) -> np.ndarray:
        return np.array([*self.position, self.time_fraction], np.float32)
