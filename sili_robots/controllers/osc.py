"""robosuite's own OperationalSpaceController, run on the Sawyer-Reach scene.

The controller is robosuite 1.5.2's ``OperationalSpaceController`` with the settings of
robosuite's default Sawyer controller (kp 150, critically damped, position and orientation
decoupled, nullspace pull to the start configuration) except that it receives absolute world
frame pose goals, the shared Cartesian target and the fixed gripper-down orientation, instead of
deltas. As inside robosuite, torques are recomputed at every physics substep (with robosuite's
``qfrc_bias`` gravity compensation) and clipped to the motor ranges; the substep is split into
``mj_step1`` / ``mj_step2`` so the controller reads kinematics of the current state.

robosuite's controllers read the simulation through its ``MjSim`` wrapper; the wrapper is made
on the scene's model and pointed at the scene's own ``MjData``.
"""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np

from sili_robots.controllers.base import ArmSpec, EndEffectorController
from sili_robots.controllers.robosuite_logging import quiet_robosuite_import

OSC_KP = 150.0
OSC_DAMPING_RATIO = 1.0
#: robosuite's names for the arm: its OSC reads the velocity of the site
#: ``{NAMING_PREFIX}{PART_NAME}_center``, which must be the scene's ``ArmSpec.base_site``
NAMING_PREFIX, PART_NAME = "robot0_", "right"


def _rotvec(rotation: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    vel = np.zeros(3)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation).ravel())
    mujoco.mju_quat2Vel(vel, quat, 1.0)
    return vel


class RobosuiteOSCController(EndEffectorController):
    """robosuite OSC torques every substep on the scene's torque motors."""

    actuation: ClassVar[str] = "torque"

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, arm: ArmSpec) -> None:
        super().__init__(model, data, arm)
        if arm.base_site != f"{NAMING_PREFIX}{PART_NAME}_center":
            raise ValueError(
                f"robosuite's OSC reads the site {NAMING_PREFIX}{PART_NAME}_center; this arm's "
                f"base site is {arm.base_site!r}"
            )
        quiet_robosuite_import()
        from robosuite.controllers.parts.arm.osc import OperationalSpaceController
        from robosuite.utils.binding_utils import MjSim

        self.sim = MjSim(model)
        self.sim.data._data = data  # read and write the scene's state, not a private copy
        joint_ids = [model.joint(n).id for n in arm.joint_names]
        self.osc = OperationalSpaceController(
            self.sim,
            ref_name=arm.ee_site,
            joint_indexes={
                "joints": joint_ids,
                "qpos": list(arm.qpos_adr),
                "qvel": list(arm.dof_adr),
            },
            actuator_range=(-arm.torque_limits, arm.torque_limits),
            kp=OSC_KP,
            damping_ratio=OSC_DAMPING_RATIO,
            policy_freq=round(1.0 / arm.control_dt),
            control_ori=True,
            input_type="absolute",
            input_ref_frame="world",
            uncouple_pos_ori=True,
            part_name=PART_NAME,
            naming_prefix=NAMING_PREFIX,
            lite_physics=True,
        )
        self._goal_rotvec = _rotvec(arm.ee_rotation)

    def _reset(self) -> None:
        self.osc.update(force=True)
        self.osc.update_initial_joints(self.data.qpos[self.arm.qpos_adr].copy())

    def _track(self, target: np.ndarray, velocity: np.ndarray) -> None:
        m, d, arm, osc = self.model, self.data, self.arm, self.osc
        mujoco.mj_step1(m, d)
        osc.set_goal(np.concatenate([target, self._goal_rotvec]))
        lo, hi = -arm.torque_limits, arm.torque_limits
        for i in range(arm.n_substeps):
            if i:
                mujoco.mj_step1(m, d)
            d.ctrl[arm.torque_actuators] = np.clip(osc.run_controller(), lo, hi)
            mujoco.mj_step2(m, d)
