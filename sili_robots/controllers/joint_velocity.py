"""Plain joint-velocity control: resolved-rate motion through the Jacobian, no optimisation.

Each control step the commanded end-effector velocity plus a proportional correction of the
pose error (position toward the target, orientation toward gripper-down) becomes a desired
end-effector twist, mapped to joint velocities with a
damped least-squares Jacobian inverse and scaled down uniformly if any joint would exceed its
speed limit; MuJoCo's velocity servos track those joint velocities over all substeps. Nothing
steers the redundant degree of freedom or keeps joints away from their limits: the physics' joint
limits stop them. This is the ablation's "no IK solver" baseline.
"""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np

from sili_robots.controllers.base import ArmSpec, EndEffectorController

POSITION_GAIN = 5.0  # 1/s: fraction of the position error corrected per second
ORIENTATION_GAIN = 5.0  # 1/s: fraction of the rotation error corrected per second
DLS_DAMPING = 1e-2  # damped least squares lambda (m)


class JointVelocityController(EndEffectorController):
    """Damped least-squares resolved rates -> joint velocity targets -> velocity servos."""

    actuation: ClassVar[str] = "velocity"

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, arm: ArmSpec) -> None:
        super().__init__(model, data, arm)
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._quat = np.zeros(4)
        self._rotvel = np.zeros(3)

    def joint_velocities(self, target: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """Joint velocities (rad/s) for end-effector ``velocity`` while closing on ``target``."""
        m, d, arm = self.model, self.data, self.arm
        sid = arm.ee_site_id
        mujoco.mj_jacSite(m, d, self._jacp, self._jacr, sid)
        jac = np.vstack([self._jacp[:, arm.dof_adr], self._jacr[:, arm.dof_adr]])
        rot_err = arm.ee_rotation @ d.site_xmat[sid].reshape(3, 3).T
        mujoco.mju_mat2Quat(self._quat, rot_err.ravel())
        mujoco.mju_quat2Vel(self._rotvel, self._quat, 1.0)
        twist = np.concatenate(
            [
                velocity + POSITION_GAIN * (target - d.site_xpos[sid]),
                ORIENTATION_GAIN * self._rotvel,
            ]
        )
        jjt = jac @ jac.T + DLS_DAMPING**2 * np.eye(6)
        qdot = jac.T @ np.linalg.solve(jjt, twist)
        ratio = float(np.max(np.abs(qdot) / arm.velocity_limits))
        return qdot / ratio if ratio > 1.0 else qdot

    def _track(self, target: np.ndarray, velocity: np.ndarray) -> None:
        self.data.ctrl[self.arm.velocity_actuators] = self.joint_velocities(target, velocity)
        mujoco.mj_step(self.model, self.data, self.arm.n_substeps)
