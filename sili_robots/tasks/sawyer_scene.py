"""The Sawyer-Reach scene: robosuite's Sawyer, its mount and gripper, and a table arena.

Built from robosuite's models (``Sawyer``, ``RethinkMount``, ``RethinkGripper``, ``TableArena``,
merged by ``ManipulationTask``) and compiled once per process and actuation kind; every
environment then gets its own ``MjData`` on the shared, never modified, ``MjModel``. Nothing
here renders: no camera is used, no render context is created.

Before compiling, the arm's actuation is chosen for the controller that will drive it:
- ``"torque"``: robosuite's own torque motors, untouched (robosuite's OSC computes torques with
  its own gravity compensation, ``qfrc_bias``).
- ``"position"``: per joint a position servo and a velocity servo (PD tracking of a joint
  trajectory point with velocity feed-forward); ``"velocity"``: the velocity servo alone. For
  both, gravity compensation is set in the model (``gravcomp`` on the arm's bodies, routed
  through the actuators with ``actuatorgravcomp``) and each joint's total actuator torque,
  compensation included, is clamped to the Sawyer's torque limits (robosuite's motor ranges: 80,
  80, 40, 40, 9, 9, 9 N m) with ``actuatorfrcrange``.
The physics options are robosuite's (Euler integrator, 2 ms timestep, elliptic friction cones,
impratio 20) and the control frequency robosuite's default 20 Hz (25 substeps). The servo gains
keep the explicit part of Euler well inside its stability limit (kv dt / I is about 0.1).

One change to robosuite's Sawyer: the contact between link ``l0`` and the base is excluded (see
``_scene_xml``); left in, its friction holds the first joint almost still.

Unless ``visual=True``, geoms that only render (no collision, and no mass either: every body
carries an explicit inertial, which a test checks) and the meshes, materials and textures only
they use are dropped before compiling: nothing here renders, the physics is unchanged, a
physics step is cheaper and compiling takes a fraction of a second instead of over one.

Geometry (documented choice; the paper gives none): table top at z = 0.8 m, 0.8 x 0.8 m,
centred at the origin; the robot's base sits at x = -0.56 m as in robosuite's table tasks. The
three goals lie 3 cm above the table on a circle of radius 0.2 m around the table centre, at 0,
120 and 240 degrees. Every interaction starts at rest with the gripper pointing down at
(0, 0, 1.0), 0.26 m from each goal (the class's default and v0's start; v1 starts at z = 0.9),
or at another start the task asks for (the same joint configuration every time, found once per
start by inverse kinematics from robosuite's Sawyer ``init_qpos``). The height plane of the
strategy rule is z = 0.95 m.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import cache

import mujoco
import numpy as np

from sili_robots.controllers.base import ArmSpec
from sili_robots.controllers.robosuite_logging import quiet_robosuite_import
from sili_robots.errors import check_choice

ACTUATIONS = ("position", "velocity", "torque")
TIMESTEP = 0.002  # s, robosuite's SIMULATION_TIMESTEP
CONTROL_FREQ = 20  # Hz, robosuite's default control frequency
N_SUBSTEPS = round(1.0 / (CONTROL_FREQ * TIMESTEP))

TABLE_SIZE = (0.8, 0.8, 0.05)
TABLE_TOP_Z = 0.8
GOAL_HEIGHT = 0.03  # above the table top
GOAL_RADIUS = 0.2
GOAL_ANGLES_DEG = (0.0, 120.0, 240.0)
GOALS = np.array(
    [
        [
            GOAL_RADIUS * np.cos(np.deg2rad(a)),
            GOAL_RADIUS * np.sin(np.deg2rad(a)),
            TABLE_TOP_Z + GOAL_HEIGHT,
        ]
        for a in GOAL_ANGLES_DEG
    ]
)
START_EE = np.array([0.0, 0.0, 1.0])
PLANE_Z = 0.95
#: gripper pointing straight down (site z axis to -z), fingers opening along world x
EE_ROTATION = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: Sawyer joint speed limits (rad/s), from Rethink Robotics' sawyer_description URDF
VELOCITY_LIMITS = np.array([1.74, 1.328, 1.957, 1.957, 3.485, 3.485, 4.545])
#: Joint servo gains, from the joint-space inertia at the start configuration (robosuite's
#: armature dominates it: about 6.6, 3.8, 2.2, 1.8, 1.1, 0.9, 0.8 kg m^2) for a natural frequency
#: near 25 rad/s, critically damped: kp ~ I w^2 (N m / rad), kv ~ 2 I w (N m s / rad).
SERVO_KP = np.array([4000.0, 2400.0, 1400.0, 1200.0, 700.0, 550.0, 450.0])
SERVO_KV = np.array([330.0, 190.0, 110.0, 90.0, 55.0, 45.0, 38.0])

ARM_JOINTS = tuple(f"robot0_right_j{i}" for i in range(7))
EE_SITE = "gripper0_right_grip_site"
BASE_SITE = "robot0_right_center"


#: MuJoCo's arena per MjData (contacts, constraints, stack)
ARENA_MEMORY = "16M"


def _scene_xml(actuation: str, visual: bool = False) -> str:
    """robosuite's models merged into one MJCF string, actuated as ``actuation`` asks."""
    quiet_robosuite_import()
    from robosuite.models.arenas import TableArena
    from robosuite.models.bases import robot_base_factory
    from robosuite.models.grippers import gripper_factory
    from robosuite.models.robots import Sawyer
    from robosuite.models.tasks import ManipulationTask

    robot = Sawyer(idn=0)
    robot.add_base(robot_base_factory(robot.default_base, idn=0))
    gripper = gripper_factory(robot.default_gripper["right"], idn="0_right")
    robot.add_gripper(gripper, robot.eef_name["right"])
    robot.set_base_xpos(robot.base_xpos_offset["table"](TABLE_SIZE[0]))
    arena = TableArena(table_full_size=TABLE_SIZE, table_offset=(0.0, 0.0, TABLE_TOP_Z))
    arena.set_origin([0, 0, 0])
    task = ManipulationTask(mujoco_arena=arena, mujoco_robots=[robot])

    root = task.root
    root.find("option").set("timestep", repr(TIMESTEP))
    # robosuite sizes the arena for its busiest scenes (nconmax = njmax = 5000): 1.25 GB of
    # address space per MjData, which a vmem limit or a few envs in one process run out of;
    # this scene's contacts and constraints use about 50 KB
    size = root.find("size")
    if size is None:
        size = ET.SubElement(root, "size")
    size.attrib = {"memory": ARENA_MEMORY}
    world = root.find("worldbody")
    for i, goal in enumerate(GOALS):
        ET.SubElement(
            world,
            "site",
            name=f"goal{i}",
            pos=" ".join(map(repr, goal.tolist())),
            size="0.015",
            rgba="0.1 0.8 0.1 0.6",
            group="1",
        )
    # robosuite's Sawyer: the collision sphere of link l0 rests exactly on the base cylinder,
    # and since the base is welded to the world MuJoCo does not filter this parent-child pair;
    # with robosuite's impratio=20 the friction of that contact holds joint j0 almost still.
    # The real j0 turns freely, so the pair is excluded.
    contact = root.find("contact")
    if contact is None:
        contact = ET.SubElement(root, "contact")
    ET.SubElement(contact, "exclude", body1="robot0_right_arm_base_link", body2="robot0_right_l0")
    if actuation != "torque":
        _replace_arm_motors(root, robot, actuation)
    if not visual:
        _drop_render_only(root)
    return ET.tostring(root, encoding="unicode")


def _drop_render_only(root: ET.Element) -> None:
    """Remove geoms that neither collide nor weigh, then the assets nothing references."""
    for parent in root.iter():
        for geom in parent.findall("geom"):
            if geom.get("contype") == "0" and geom.get("conaffinity") == "0":
                parent.remove(geom)
    asset = root.find("asset")
    used = {g.get(k) for g in root.iter("geom") for k in ("mesh", "material")}
    for mat in asset.findall("material"):
        if mat.get("name") not in used:
            asset.remove(mat)
    used |= {m.get("texture") for m in asset.findall("material")}
    for el in [*asset.findall("mesh"), *asset.findall("texture")]:
        if el.get("name") not in used:
            asset.remove(el)


def _replace_arm_motors(root: ET.Element, robot: object, actuation: str) -> None:
    """Swap the arm's torque motors for joint servos with model-side gravity compensation.

    ``"position"`` puts two actuators on each joint, a position servo (stiffness only) and a
    velocity servo (damping toward a velocity reference), so a controller can send a joint
    trajectory point (q*, qdot*) and the joint gets kp (q* - q) + kv (qdot* - qdot): PD tracking
    with velocity feed-forward, computed inside MuJoCo. ``"velocity"`` keeps only the velocity
    servo. The joint's actuatorfrcrange clamps the sum, gravity compensation included.
    """
    arm_joints = list(robot.joints)
    joints = {j.get("name"): j for j in root.iter("joint")}
    actuator = root.find("actuator")
    motors = [m for m in actuator.findall("motor") if m.get("joint") in arm_joints]
    motors.sort(key=lambda m: arm_joints.index(m.get("joint")))
    servos: list[ET.Element] = []
    for k, motor in enumerate(motors):
        name = motor.get("joint")
        limit = float(motor.get("ctrlrange").split()[1])
        joint = joints[name]
        joint.set("actuatorfrcrange", f"{-limit} {limit}")
        joint.set("actuatorgravcomp", "true")
        actuator.remove(motor)
        vmax = VELOCITY_LIMITS[k]
        if actuation == "position":
            servos.append(
                ET.Element(
                    "position",
                    name=f"{name}_position",
                    joint=name,
                    kp=repr(SERVO_KP[k]),
                    ctrlrange=joint.get("range"),
                )
            )
        servos.append(
            ET.Element(
                "velocity",
                name=f"{name}_velocity",
                joint=name,
                kv=repr(SERVO_KV[k]),
                ctrlrange=f"{-vmax} {vmax}",
            )
        )
    for i, el in enumerate(servos):
        actuator.insert(i, el)
    for body in root.iter("body"):
        if body.get("name", "").startswith(("robot0_", "gripper0_")):
            body.set("gravcomp", "1")


@cache
def scene_model(actuation: str, visual: bool = False) -> mujoco.MjModel:
    """The compiled scene for ``actuation`` (cached per process; treat it as read-only).

    ``visual=True`` keeps robosuite's render-only meshes (for viewers); physics is the same.
    """
    check_choice("actuation", actuation, ACTUATIONS)
    return mujoco.MjModel.from_xml_string(_scene_xml(actuation, visual))


def home_qpos(actuation: str, start: tuple[float, float, float] | None = None) -> np.ndarray:
    """The start configuration: gripper down at ``start`` (default ``START_EE``), found by mink
    from robosuite's ``init_qpos`` (deterministic; the same for every actuation up to solver
    round-off)."""
    return _home_qpos(actuation, tuple(float(x) for x in (START_EE if start is None else start)))


@cache
def _home_qpos(actuation: str, start: tuple[float, float, float]) -> np.ndarray:
    from mink import SE3, SO3, Configuration, ConfigurationLimit, FrameTask, PostureTask, solve_ik
    from robosuite.models.robots import Sawyer

    model = scene_model(actuation)
    q = model.qpos0.copy()
    adr = np.array([model.jnt_qposadr[model.joint(n).id] for n in ARM_JOINTS])
    q[adr] = Sawyer().init_qpos
    config = Configuration(model, q)
    frame = FrameTask(EE_SITE, "site", position_cost=1.0, orientation_cost=1.0)
    frame.set_target(
        SE3.from_rotation_and_translation(SO3.from_matrix(EE_ROTATION), np.array(start))
    )
    posture = PostureTask(model, cost=1e-3)
    posture.set_target(q)
    limits = [ConfigurationLimit(model)]
    for _ in range(500):
        v = solve_ik(config, [frame, posture], 0.05, "daqp", damping=1e-6, limits=limits)
        config.integrate_inplace(v, 0.05)
        if np.linalg.norm(frame.compute_error(config)) < 1e-9:
            break
    out = config.q.copy()
    out.setflags(write=False)
    return out


def _has_actuator(model: mujoco.MjModel, name: str) -> bool:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name) >= 0


class SawyerScene:
    """One simulation of the scene: its own ``MjData`` on the shared compiled model."""

    def __init__(self, actuation: str, start: tuple[float, float, float] | None = None) -> None:
        self.actuation = actuation
        self.model = scene_model(actuation)
        self.data = mujoco.MjData(self.model)
        m = self.model
        jids = [m.joint(n).id for n in ARM_JOINTS]

        def ids(names: list[str]) -> np.ndarray:
            return np.array([m.actuator(a).id for a in names if _has_actuator(m, a)], int)

        torque_motors = ids([f"robot0_torq_right_j{i}" for i in range(7)])
        if actuation == "torque":
            torque = m.actuator_ctrlrange[torque_motors, 1].copy()
        else:
            torque = m.jnt_actfrcrange[jids, 1].copy()
        self.arm = ArmSpec(
            joint_names=ARM_JOINTS,
            qpos_adr=np.array([m.jnt_qposadr[j] for j in jids]),
            dof_adr=np.array([m.jnt_dofadr[j] for j in jids]),
            position_actuators=ids([f"{n}_position" for n in ARM_JOINTS]),
            velocity_actuators=ids([f"{n}_velocity" for n in ARM_JOINTS]),
            torque_actuators=torque_motors,
            ee_site=EE_SITE,
            ee_site_id=m.site(EE_SITE).id,
            base_site=BASE_SITE,
            velocity_limits=VELOCITY_LIMITS.copy(),
            torque_limits=torque,
            home_qpos=home_qpos(actuation, start),
            ee_rotation=EE_ROTATION.copy(),
            n_substeps=N_SUBSTEPS,
            control_dt=N_SUBSTEPS * TIMESTEP,
        )

    def reset(self) -> None:
        """Put the arm at rest in the home configuration, gripper fingers held at rest."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = self.arm.home_qpos
        self.data.ctrl[:] = 0.0
        if self.arm.position_actuators.size:
            self.data.ctrl[self.arm.position_actuators] = self.arm.home_qpos[self.arm.qpos_adr]
        mujoco.mj_forward(self.model, self.data)

    @property
    def ee_pos(self) -> np.ndarray:
        return self.data.site_xpos[self.arm.ee_site_id]

    def ee_velocity(self) -> np.ndarray:
        """Linear velocity of the end-effector site (world frame, m/s)."""
        out = np.zeros(6)
        mujoco.mj_objectVelocity(
            self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self.arm.ee_site_id, out, 0
        )
        return out[3:]
