"""The default controller: differential inverse kinematics with mink, tracked by joint servos.

Each control step one differential-IK QP is solved with mink: a frame task on the end-effector
site toward the target pose, a light posture task toward the start configuration (it settles the
redundant seventh degree of freedom), configuration limits and the Sawyer's joint speed limits.
Its joint velocity, integrated over the control step, moves a joint-space reference (kept
``LIMIT_MARGIN`` inside the arm's joint ranges); the
scene's joint servos track the reference with velocity feed-forward (kp (q* - q) + kv (qdot* -
qdot), gravity compensated in the model), the position reference interpolated in a few chunks
of substeps, so the physics runs in C between chunks. The reference is re-synchronised to the
measured joints whenever they fall more than ``RESYNC`` behind it (the arm is blocked, e.g. by
the table), so the IK never drifts away from the physics.

mink 0.0.5 notes: ``from mink import *`` is broken in that release (its ``__all__`` lists names
it does not define), so names are imported explicitly; and its ``solve_ik`` asserts on an
infeasible QP, so the problem is built with ``build_ik`` and solved here, holding the reference
if the solver finds nothing.
"""

from __future__ import annotations

from typing import ClassVar

import mujoco
import numpy as np
import qpsolvers
from mink import (
    SE3,
    SO3,
    Configuration,
    ConfigurationLimit,
    FrameTask,
    PostureTask,
    VelocityLimit,
    build_ik,
)

from sili_robots.controllers.base import ArmSpec, EndEffectorController

#: QP back end for mink (qpsolvers name); "daqp" and "quadprog" are both installed
IK_SOLVER = "daqp"
POSTURE_COST = 1e-2
ORIENTATION_COST = 0.5
IK_DAMPING = 1e-2
#: largest joint lag (rad) behind the reference before the reference is reset to the measurement
RESYNC = 0.1
#: the joint reference stays this far (rad) inside the joint limits, so the servos' overshoot
#: does not run the joints into MuJoCo's limit constraints
LIMIT_MARGIN = 0.05
#: position-reference interpolation points per control step
CHUNKS = 5


class MinkIKController(EndEffectorController):
    """mink differential IK -> joint reference (q*, qdot*) -> MuJoCo PD servos."""

    actuation: ClassVar[str] = "position"

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, arm: ArmSpec) -> None:
        super().__init__(model, data, arm)
        self.configuration = Configuration(model, arm.home_qpos)
        self.frame_task = FrameTask(
            arm.ee_site, "site", position_cost=1.0, orientation_cost=ORIENTATION_COST
        )
        self.posture_task = PostureTask(model, cost=POSTURE_COST)
        self.posture_task.set_target(np.array(arm.home_qpos))
        self.tasks = [self.frame_task, self.posture_task]
        self.limits = [
            ConfigurationLimit(model),
            VelocityLimit(model, dict(zip(arm.joint_names, arm.velocity_limits, strict=True))),
        ]
        self._rotation = SO3.from_matrix(arm.ee_rotation)
        self._q_lo = np.full(model.nq, -np.inf)
        self._q_hi = np.full(model.nq, np.inf)
        for j in range(model.njnt):
            if model.jnt_limited[j]:
                a = model.jnt_qposadr[j]
                self._q_lo[a], self._q_hi[a] = model.jnt_range[j]
        lo, hi = self._q_lo[arm.qpos_adr], self._q_hi[arm.qpos_adr]
        self._arm_lo, self._arm_hi = lo + LIMIT_MARGIN, hi - LIMIT_MARGIN
        self.q_ref = np.array(arm.home_qpos)
        if CHUNKS < 1 or arm.n_substeps % CHUNKS:
            raise ValueError(f"{arm.n_substeps} substeps do not split into {CHUNKS} chunks")

    def _reset(self) -> None:
        self.q_ref = np.clip(self.data.qpos, self._q_lo, self._q_hi)

    def ik_step(self, target: np.ndarray) -> np.ndarray:
        """One IK QP from the reference toward ``target``: the joint velocity (model nv)."""
        arm = self.arm
        lag = np.max(np.abs(self.data.qpos[arm.qpos_adr] - self.q_ref[arm.qpos_adr]))
        if lag > RESYNC:
            # Physics may sit a hair past a limit (soft constraints); the IK must start inside.
            self.q_ref = np.clip(self.data.qpos, self._q_lo, self._q_hi)
        self.configuration.update(self.q_ref)
        self.frame_task.set_target(SE3.from_rotation_and_translation(self._rotation, target))
        problem = build_ik(
            self.configuration, self.tasks, arm.control_dt, damping=IK_DAMPING, limits=self.limits
        )
        dq = qpsolvers.solve_problem(problem, solver=IK_SOLVER).x
        if dq is None or not np.all(np.isfinite(dq)):
            return np.zeros(self.model.nv)  # no feasible step: hold the reference
        return dq / arm.control_dt

    def _track(self, target: np.ndarray, velocity: np.ndarray) -> None:
        m, d, arm = self.model, self.data, self.arm
        v = self.ik_step(target)
        q_next = self.configuration.integrate(v, arm.control_dt)
        start = self.q_ref[arm.qpos_adr]
        q_next[arm.qpos_adr] = np.clip(q_next[arm.qpos_adr], self._arm_lo, self._arm_hi)
        delta = q_next[arm.qpos_adr] - start
        d.ctrl[arm.velocity_actuators] = delta / arm.control_dt
        per_chunk = arm.n_substeps // CHUNKS
        for k in range(1, CHUNKS + 1):
            d.ctrl[arm.position_actuators] = start + (k / CHUNKS) * delta
            mujoco.mj_step(m, d, per_chunk)
        self.q_ref = q_next
