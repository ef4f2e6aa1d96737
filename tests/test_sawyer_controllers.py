"""Controllers on the real Sawyer scene: reaching, joint limits, numerical health, the registry."""

import numpy as np
import pytest

from sili_robots.controllers import CONTROLLER_NAMES, controller_class
from sili_robots.errors import ConfigError
from sili_robots.tasks import make_task
from sili_robots.tasks.sawyer_reach import RISE_MARGIN, action_toward
from sili_robots.tasks.sawyer_scene import GOALS, PLANE_Z, SERVO_KP, scene_model

ABOVE_PLANE = GOALS.copy()
ABOVE_PLANE[:, 2] = PLANE_Z + RISE_MARGIN
POINTS = [*GOALS, *ABOVE_PLANE]
ARM_LIMIT_TOL = 5e-3  # rad past a joint stop (soft constraint penetration)


def _joint_limit_violation(env, arm: bool = True) -> float:
    """Largest excursion past a joint limit: the arm's 7 joints, or the 2 gripper fingers."""
    m, d = env.scene.model, env.scene.data
    worst = 0.0
    for j in range(m.njnt):
        if m.jnt_limited[j] and m.joint(j).name.startswith("robot0_") == arm:
            q = d.qpos[m.jnt_qposadr[j]]
            lo, hi = m.jnt_range[j]
            worst = max(worst, lo - q, q - hi)
    return worst


def test_registry_names_and_errors():
    assert CONTROLLER_NAMES == ("mink", "osc", "joint_velocity")
    actuations = {n: controller_class(n).actuation for n in CONTROLLER_NAMES}
    assert actuations == {"mink": "position", "osc": "torque", "joint_velocity": "velocity"}
    with pytest.raises(ConfigError, match=r"unknown controller 'ik'; allowed: mink, osc"):
        controller_class("ik")


def test_osc_is_robosuites_own_controller():
    from robosuite.controllers.parts.arm.osc import OperationalSpaceController

    env = make_task("sawyer-reach", controller="osc").unwrapped
    assert isinstance(env.controller.osc, OperationalSpaceController)
    env.reset(seed=0)
    env.step(np.array([1.0, 0.0, 0.0]))
    # Torques are what drives the arm: the motors, not servos, carry the load.
    assert np.any(np.abs(env.scene.data.ctrl[env.scene.arm.torque_actuators]) > 1.0)


def test_scenes_differ_only_in_actuation():
    pos, vel, tor = (scene_model(a) for a in ("position", "velocity", "torque"))
    for m in (pos, vel, tor):
        assert m.nq == 9 and m.ngeom == tor.ngeom  # 7 arm joints + 2 gripper fingers
        assert m.body("robot0_right_l0").id > 0 and m.geom("table_collision").id > 0
    assert tor.nu == 9 and vel.nu == 9 and pos.nu == 16  # position: a PD pair per arm joint
    np.testing.assert_allclose(pos.actuator_gainprm[0, 0], SERVO_KP[0])
    l1 = pos.body("robot0_right_l1").id
    assert pos.body_gravcomp[l1] == 1.0 and tor.body_gravcomp[l1] == 0.0
    np.testing.assert_allclose(pos.jnt_actfrcrange[:7, 1], [80, 80, 40, 40, 9, 9, 9])


def test_dropping_render_only_geoms_keeps_the_physics():
    lean, full = scene_model("position"), scene_model("position", visual=True)
    assert lean.ngeom < full.ngeom and lean.nmesh == 0 < full.nmesh
    assert lean.nbody == full.nbody and lean.njnt == full.njnt and lean.nu == full.nu
    for field in (
        "body_mass",
        "body_inertia",
        "body_ipos",
        "body_pos",
        "jnt_range",
        "dof_armature",
    ):
        np.testing.assert_array_equal(getattr(lean, field), getattr(full, field), err_msg=field)
    assert lean.opt.integrator == full.opt.integrator == 0  # robosuite's Euler
    assert lean.opt.timestep == 0.002


@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
def test_reaches_each_goal_and_above_the_plane_within_horizon(controller):
    env = make_task("sawyer-reach", controller=controller).unwrapped
    env.reset(seed=0)
    for point in POINTS:
        dists = []
        for _ in range(env.horizon):
            env.step(action_toward(env, point))
            dists.append(float(np.linalg.norm(env.scene.ee_pos - point)))
        assert dists[-1] < 0.01, (controller, point, dists[-1])
        assert _joint_limit_violation(env) < 1e-3
        env.reset()


@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
def test_joint_limits_hold_when_pushed_to_the_extremes(controller):
    env = make_task("sawyer-reach", controller=controller).unwrapped
    env.reset(seed=0)
    # Full speed into each corner of the command box: out of reach, into the table, behind.
    for corner in ([1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]):
        for _ in range(env.horizon):
            obs, *_ = env.step(np.array(corner, dtype=np.float32))
            assert np.all(np.isfinite(obs))
            # MuJoCo's limits are stiff soft constraints: a joint driven into its stop sinks in
            # by milliradians; the fingers are squeezed more when pressed onto the table.
            assert _joint_limit_violation(env) < ARM_LIMIT_TOL
            assert _joint_limit_violation(env, arm=False) < 1e-2
        env.reset()


@pytest.mark.slow
@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
def test_no_nan_over_long_random_rollouts(controller):
    env = make_task("sawyer-reach", controller=controller)
    env.reset(seed=0)
    env.action_space.seed(0)
    rng = np.random.default_rng(0)
    worst = 0.0
    for j in range(60):
        if j:
            env.reset()
        # Alternate uniform noise and held random directions (long pushes against limits).
        held = rng.uniform(-1, 1, 3).astype(np.float32)
        for t in range(50):
            a = env.action_space.sample() if j % 2 == 0 else held
            obs, r, _term, trunc, _info = env.step(a)
            assert np.all(np.isfinite(obs)) and np.isfinite(r)
            worst = max(worst, _joint_limit_violation(env.unwrapped))
            assert trunc == (t == 49)
    assert worst < ARM_LIMIT_TOL
