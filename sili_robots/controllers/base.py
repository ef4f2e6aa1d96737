"""What every end-effector controller shares: the arm it drives and the Cartesian target.

Every controller receives the same command, an end-effector velocity in m/s held for one control
step, and turns it into the same target pose: the target position moves by ``velocity * dt`` and
is kept within ``LEASH`` of the measured end effector (so pushing against the table or beyond the
arm's reach does not wind the target up), the target orientation stays the fixed "gripper
pointing down" rotation. Controllers differ only in how they track that pose, which makes the
ablation a comparison of tracking, as long as the leash does not bind: a controller that lags by
most of it (robosuite's OSC, about 4 cm) gets its full-speed commands shortened, so there an
action moves the target less. Pressed down onto the table, mink and joint velocity keep the hand
where it met the table; robosuite's OSC lets it slide sideways across it (its force toward a
target below the table top; ``benchmarks/bench_sawyer_controllers.py`` measures the slide).
A controller owns physics stepping for its control step because some (robosuite's OSC) must
recompute torques at every physics substep.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import mujoco
import numpy as np

from sili_robots.errors import ConfigError

#: largest distance (m) the Cartesian target may lead the measured end effector
LEASH = 0.05


@dataclass(frozen=True)
class ArmSpec:
    """Indices and limits of one arm inside a compiled MuJoCo model."""

    joint_names: tuple[str, ...]
    qpos_adr: np.ndarray  # qpos addresses of the arm joints
    dof_adr: np.ndarray  # qvel / dof addresses of the arm joints
    # actuator ids per arm joint (same order as the joints); empty when the scene has none
    position_actuators: np.ndarray  # position servos (ctrl: joint angle)
    velocity_actuators: np.ndarray  # velocity servos (ctrl: joint speed)
    torque_actuators: np.ndarray  # torque motors (ctrl: N m)
    ee_site: str  # end-effector site the task is about
    ee_site_id: int
    base_site: str  # a site fixed to the arm's base (robosuite's OSC reads its velocity by name)
    velocity_limits: np.ndarray  # rad/s per arm joint
    torque_limits: np.ndarray  # N m per arm joint
    home_qpos: np.ndarray  # full-model qpos the interaction starts from
    ee_rotation: np.ndarray  # 3x3 target orientation of the end-effector site (world frame)
    n_substeps: int  # physics steps per control step
    control_dt: float  # seconds per control step


class EndEffectorController(ABC):
    """Track a Cartesian target pose, advancing the physics by one control step per command."""

    #: what the scene must put on the arm joints: "position", "velocity" or "torque" actuators
    actuation: ClassVar[str]

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, arm: ArmSpec) -> None:
        self.model = model
        self.data = data
        self.arm = arm
        self.target = np.zeros(3)

    def reset(self) -> None:
        """Start tracking from the current (already forwarded) state: target = where the EE is."""
        self.target = self.data.site_xpos[self.arm.ee_site_id].copy()
        self._reset()

    def step(self, velocity: np.ndarray) -> None:
        """Command an end-effector ``velocity`` (m/s, world frame) for one control step.

        Expects ``data`` forwarded (as after ``mj_forward``) and leaves it forwarded.
        """
        velocity = np.asarray(velocity, float)
        if velocity.shape != (3,) or not np.isfinite(velocity).all():  # a NaN target stays NaN
            got = velocity.tolist() if velocity.shape == (3,) else f"shape {velocity.shape}"
            raise ConfigError(f"velocity must be 3 finite numbers (m/s), got {got}")
        ee = self.data.site_xpos[self.arm.ee_site_id]
        target = self.target + velocity * self.arm.control_dt
        lead = target - ee
        dist = float(np.sqrt(lead @ lead))
        if dist > LEASH:
            target = ee + lead * (LEASH / dist)
        self.target = target
        self._track(target, velocity)
        # Leave derived quantities (site positions, velocities) consistent with the new state.
        mujoco.mj_forward(self.model, self.data)

    def _reset(self) -> None:  # noqa: B027  (optional hook)
        """Per-interaction controller state; most controllers have none."""

    @abstractmethod
    def _track(self, target: np.ndarray, velocity: np.ndarray) -> None:
        """Move toward ``target`` (and ``arm.ee_rotation``) for ``arm.n_substeps`` physics steps;
        ``velocity`` is the commanded end-effector velocity (a feed-forward term, if wanted)."""
