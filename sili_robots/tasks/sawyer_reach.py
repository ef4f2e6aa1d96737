"""Sawyer-Reach: a simulated Sawyer arm reaches for one of three goals it never sees.

The scene (``sawyer_scene``) is robosuite's Sawyer on its mount, with its gripper, at a table;
MuJoCo simulates it, so joint limits, reach, torque limits and table contacts are the physics'
business. The opponent's strategy z is which of three goals on the table it has chosen.

- Observation (float32): end-effector position (m, world frame), its linear velocity (m/s), then
  the elapsed fraction t/H. Never the goal (``oracle=True`` appends the goal's position).
- Action: end-effector velocity in [-1, 1]^3, scaled by ``MAX_SPEED`` = 0.4 m/s and held for one
  control step (20 Hz, 50 ms: at most 2 cm per axis per step). The controller chosen with
  ``controller=`` executes it: ``mink`` (default), ``osc`` or ``joint_velocity``
  (``sili_robots.controllers``).
- H = 50 steps; task reward each step: minus the distance from end effector to the chosen goal.
- Strategy dynamics T^z: if the end effector ends the interaction above the height plane
  z = ``PLANE_Z`` (0.95 m, 15 cm above the table) the opponent keeps its goal; otherwise it moves
  to one of the other two goals, drawn uniformly with the env's seeded generator. The start
  (0, 0, 1.0) lies above the plane, at 0.26 m from every goal.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.controllers import DEFAULT_CONTROLLER, controller_class
from sili_robots.tasks.base import RepeatedInteractionEnv
from sili_robots.tasks.sawyer_scene import GOALS, PLANE_Z, SawyerScene

MAX_SPEED = 0.4  # m/s per axis at |action| = 1
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

    def __init__(
        self,
        controller: str = DEFAULT_CONTROLLER,
        horizon: int = 50,
        oracle: bool = False,
        strategy_flag: bool = False,
    ) -> None:
        cls = controller_class(controller)  # ConfigError naming the choices, before any build
        self.controller_name = controller
        self.scene = SawyerScene(cls.actuation)
        self.controller = cls(self.scene.model, self.scene.data, self.scene.arm)
        self.goal = 0
        super().__init__(horizon=horizon, oracle=oracle, strategy_flag=strategy_flag)

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

    def _initial_strategy(self) -> None:
        self.goal = int(self.np_random.integers(len(GOALS)))

    def ends_above_plane(self) -> bool:
        """The strategy rule's test, on where the end effector is now."""
        return float(self.scene.ee_pos[2]) > PLANE_Z

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

    def _step_record(self) -> dict[str, Any]:
        return {"ee": self.scene.ee_pos.copy()}

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


def stabilizing_point(env: SawyerReachEnv) -> np.ndarray:
    """The goal, then (for the last ``RISE_STEPS`` steps) the point just above the plane over it."""
    point = env.goal_position.copy()
    if env.t >= env.horizon - RISE_STEPS:
        point[2] = PLANE_Z + RISE_MARGIN
    return point
