"""Sawyer-Reach: a simulated Sawyer arm reaches for one of three goals it never sees.

The scene (``sawyer_scene``) is robosuite's Sawyer on its mount, with its gripper, at a table;
MuJoCo simulates it, so joint limits, reach, torque limits and table contacts are the physics'
business. The opponent's strategy z is which of three goals on the table it has chosen.

- Observation (float32): end-effector position (m, world frame), its linear velocity (m/s), then
  the elapsed fraction t/H. Never the goal (``OracleObservation`` appends the goal's position).
- Action: end-effector velocity in [-1, 1]^3, scaled by ``MAX_SPEED`` = 0.4 m/s and held for one
  control step (20 Hz, 50 ms: at most 2 cm per axis per step). The controller chosen with
  ``controller=`` executes it: ``mink`` (default), ``osc`` or ``joint_velocity``
  (``sili_robots.controllers``).
- H = 50 steps; task reward each step: minus the distance from end effector to the chosen goal.
- Strategy dynamics T^z: if the end effector ends the interaction above the height plane
  z = ``PLANE_Z`` (0.95 m, 15 cm above the table) the opponent keeps its goal; otherwise it moves
  to one of the other two goals, drawn uniformly with the env's seeded generator.
- Start: the gripper at rest at (0, 0, ``start_z``) above the table centre.

Versions (``sili_robots.tasks.registry``):
- v0: ``start_z=1.0``, above the plane: standing still holds the goal in every interaction and a
  uniformly random policy in about two thirds of them, so true stability says little.
- v1: ``start_z=0.9``, 5 cm below the plane (7 cm above the goals, 0.21 m from each): the paper's
  server "needing to move its arm away from the dish by the end of the interaction" must now
  rise deliberately; standing still never holds the goal and a random policy rarely does
  (docs/tasks.md has the measured bounds).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.controllers import DEFAULT_CONTROLLER, controller_class
from sili_robots.errors import ConfigError, compared, is_number
from sili_robots.tasks.base import RepeatedInteractionEnv
from sili_robots.tasks.sawyer_scene import GOALS, PLANE_Z, START_EE, TABLE_TOP_Z, SawyerScene

MAX_SPEED = 0.4  # m/s per axis at |action| = 1
#: allowed start heights (m): above the goals, within the arm's comfortable reach
START_Z_RANGE = (round(TABLE_TOP_Z + 0.06, 6), 1.1)  # rounded: the bound as it is printed
#: the stabilizing reference leaves the goal this many steps before the end of an interaction
RISE_STEPS = 15
#: ... and ends this far above the plane
RISE_MARGIN = 0.03

_POS_LOW = np.array([-1.5, -1.5, 0.0])
_POS_HIGH = np.array([1.5, 1.5, 2.5])
_VEL_LIMIT = 3.0  # m/s, far above anything the arm reaches


class SawyerReachEnv(RepeatedInteractionEnv):
    """Reach the opponent's hidden goal with a physically simulated Sawyer arm."""

    strategy_dim: ClassVar[int] = 3  # the chosen goal's position, what Oracle observes
    strategy_low: ClassVar[float] = -1.0
    strategy_high: ClassVar[float] = 1.0
    game_state_fields: ClassVar[tuple[str, ...]] = ("goal",)
    named_in_titles: ClassVar[tuple[str, ...]] = ("controller",)

    def __init__(
        self,
        controller: str = DEFAULT_CONTROLLER,
        horizon: int = 50,
        start_z: float = float(START_EE[2]),
    ) -> None:
        cls = controller_class(controller)  # ConfigError naming the choices, before any build
        if not (is_number(start_z) and START_Z_RANGE[0] <= start_z <= START_Z_RANGE[1]):
            raise ConfigError(
                f"start_z must be a height in [{START_Z_RANGE[0]:g}, {START_Z_RANGE[1]:g}] m, "
                f"got {compared(start_z)}"
            )
        self.controller_name = controller
        self.start = np.array([START_EE[0], START_EE[1], float(start_z)])
        self.plane_z = PLANE_Z
        self.scene = SawyerScene(cls.actuation, tuple(self.start))
        self.controller = cls(self.scene.model, self.scene.data, self.scene.arm)
        self.goal = 0
        super().__init__(horizon=horizon)

    # -- spaces
    def _make_action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (3,), np.float32)

    def _base_observation_space(self) -> spaces.Box:
        low = np.concatenate([_POS_LOW, np.full(3, -_VEL_LIMIT), [0.0]])
        high = np.concatenate([_POS_HIGH, np.full(3, _VEL_LIMIT), [1.0]])
        return spaces.Box(low.astype(np.float32), high.astype(np.float32))

    # -- strategy
    @property
    def goal_position(self) -> np.ndarray:
        return GOALS[self.goal]

    def strategy_id(self) -> int:
        return self.goal

    def strategy_encoding(self) -> np.ndarray:
        return self.goal_position.astype(np.float32)

    def strategy_choices(self) -> list[int]:
        return list(range(len(GOALS)))

    def _set_strategy(self, strategy: int) -> None:
        self.goal = int(strategy)

    def _initial_strategy(self) -> None:
        self.goal = int(self.np_random.integers(len(GOALS)))

    def ends_above_plane(self) -> bool:
        """The strategy rule's test, on where the end effector is now."""
        return float(self.scene.ee_pos[2]) > self.plane_z

    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        if not self.ends_above_plane():
            self.goal = int((self.goal + 1 + self.np_random.integers(len(GOALS) - 1)) % len(GOALS))

    # -- dynamics
    def _begin_interaction(self) -> None:
        self.scene.reset()
        self.controller.reset()

    def _apply_action(self, action: np.ndarray) -> float:
        self.controller.step(MAX_SPEED * action)
        ee = self.scene.ee_pos
        if not np.all(np.isfinite(self.scene.data.qpos)):
            raise RuntimeError(f"simulation diverged under controller {self.controller_name!r}")
        return -float(np.linalg.norm(ee - self.goal_position))

    def _base_observation(self) -> np.ndarray:
        return np.concatenate(
            [self.scene.ee_pos, self.scene.ee_velocity(), [self.time_fraction]]
        ).astype(np.float32)


# -- helpers for the scripted reference policies (sili_robots.policies.scripted) --------------
def action_toward(env: SawyerReachEnv, point: np.ndarray) -> np.ndarray:
    """Action that moves the controller's Cartesian target to ``point`` as fast as allowed.

    The references steer the commanded target (not the measured end effector), so they do not
    fight the tracking lag of slower controllers such as robosuite's OSC.
    """
    step = MAX_SPEED * env.scene.arm.control_dt
    return np.clip((point - env.controller.target) / step, -1.0, 1.0).astype(np.float32)


def stabilizing_point(env: SawyerReachEnv, goal: int | None = None) -> np.ndarray:
    """The goal (default: the true one), then (for the last ``RISE_STEPS`` steps) the point just
    above the plane over it."""
    point = (env.goal_position if goal is None else GOALS[goal]).copy()
    if env.t >= env.horizon - RISE_STEPS:
        point[2] = env.plane_z + RISE_MARGIN
    return point
