"""Controllers on the real Sawyer scene: reaching, joint limits, numerical health, the registry."""

import re

import mujoco
import numpy as np
import pytest
from benchmark_scripts import load_script

from sili_robots.controllers import CONTROLLER_NAMES, controller_class
from sili_robots.errors import ConfigError
from sili_robots.tasks import make_task
from sili_robots.tasks.sawyer_reach import RISE_MARGIN, action_toward
from sili_robots.tasks.sawyer_scene import (
    GOALS,
    PLANE_Z,
    SERVO_KP,
    VELOCITY_LIMITS,
    SawyerScene,
    scene_model,
)

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


def test_mink_s_reference_is_resynced_to_the_joints_only_when_it_runs_ahead():
    """A blocked arm (pressed into the table) lags its IK reference: past ``RESYNC`` the
    reference restarts from the measured joints, so the hand does not slide on; within it, the
    reference is kept (it is what makes the arm track smoothly)."""
    from sili_robots.controllers.mink_ik import RESYNC

    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    ctrl, adr = env.controller, env.scene.arm.qpos_adr
    for ahead, resynced in ((RESYNC / 2, False), (5 * RESYNC, True)):
        ctrl.q_ref = np.array(env.scene.data.qpos)
        ctrl.q_ref[adr[0]] += ahead
        kept = ctrl.q_ref.copy()
        ctrl.ik_step(ctrl.target)
        expected = env.scene.data.qpos if resynced else kept
        np.testing.assert_allclose(ctrl.q_ref[adr], expected[adr], atol=1e-12)
    env.close()


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


@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
def test_a_controller_refuses_a_velocity_that_is_not_three_finite_numbers(controller):
    """Driven directly (not through the task, which checks its action): a NaN velocity made the
    target NaN for the rest of the interaction, the arm frozen without a word."""
    env = make_task("sawyer-reach", controller=controller).unwrapped
    env.reset(seed=0)
    ctl = env.controller
    before = ctl.target.copy()
    for bad, shown in [
        ([np.nan, 0, 0], "[nan, 0.0, 0.0]"),
        ([np.inf, 0, 0], "[inf, 0.0, 0.0]"),
        ([0.1, 0.0], "shape (2,)"),
    ]:
        with pytest.raises(
            ConfigError, match=rf"velocity must be 3 finite numbers \(m/s\), got {re.escape(shown)}"
        ):
            ctl.step(np.array(bad))
    np.testing.assert_array_equal(ctl.target, before)  # refused before anything moved
    ctl.step(np.array([0.2, 0.0, 0.0]))
    assert np.isfinite(ctl.target).all() and ctl.target[0] > before[0]


@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
def test_after_a_step_the_observed_hand_is_the_arms_current_state(controller):
    """The kinematics are brought up to date after the last physics substep: the hand the
    observation, reward and plane rule read is where the joints are now."""
    import mujoco

    env = make_task("sawyer-reach", controller=controller).unwrapped
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([0.0, 1.0, 0.0], np.float32))
    model = env.scene.model
    fresh = mujoco.MjData(model)
    fresh.qpos[:], fresh.qvel[:] = env.scene.data.qpos, env.scene.data.qvel
    mujoco.mj_forward(model, fresh)
    site = fresh.site_xpos[env.scene.arm.ee_site_id]
    np.testing.assert_allclose(env.scene.ee_pos, site, atol=1e-9)


@pytest.mark.parametrize(("controller", "lag"), [("mink", 0.0035), ("joint_velocity", 0.01)])
def test_the_hand_follows_a_full_speed_command_closely(controller, lag):
    """The velocity feed-forward and the IK reference's steps toward the whole target keep the
    hand within millimetres of its target (0.18 cm for mink, 0.38 cm for joint velocity after
    five full-speed steps; without the feed-forward 3-4 cm)."""
    env = make_task("sawyer-reach", controller=controller).unwrapped
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.array([0.0, 1.0, 0.0], np.float32))
    assert np.linalg.norm(env.scene.ee_pos - env.controller.target) < lag


@pytest.mark.parametrize(("controller", "drift"), [("mink", 0.08), ("osc", 0.04)])
def test_the_arm_comes_back_to_its_start_posture(controller, drift):
    """The posture task (mink) and OSC's nullspace pull toward the home joints keep the spare
    seventh joint from drifting: after visiting every goal and coming back to the start, each
    joint is within ``drift`` rad of home (0.051 and 0.008 measured)."""
    env = make_task("sawyer-reach", controller=controller, horizon=200).unwrapped
    env.reset(seed=0)
    for point in [*GOALS, env.start]:
        for _ in range(50):
            env.step(action_toward(env, point))
    arm = env.scene.arm
    away = np.abs(env.scene.data.qpos[arm.qpos_adr] - arm.home_qpos[arm.qpos_adr])
    assert away.max() < drift


@pytest.mark.parametrize(("controller", "slide"), [("mink", 0.02), ("joint_velocity", 0.02)])
def test_pressing_down_onto_the_table_the_hand_stays_where_it_met_it(controller, slide):
    """The leash keeps a target pushed into the table within 5 cm of the hand, so pressing
    down on a goal for 35 steps moves the hand sideways by millimetres (14.6 and 16.6 at the
    worst goal). robosuite's OSC slides it across the table instead (RESULTS.md, 172 mm)."""
    bench = load_script("bench_sawyer_controllers")
    assert bench.press_slide(controller) < 1000 * slide


def test_held_up_out_of_reach_the_ik_reference_stays_inside_the_joint_ranges():
    """mink's joint limits keep a margin inside the stops (35 mrad here): the reference never
    asks the servos for a joint past its range."""
    env = make_task("sawyer-reach", horizon=150).unwrapped
    env.reset(seed=0)
    m, d = env.scene.model, env.scene.data
    for _ in range(150):
        env.step(np.array([0.0, 0.0, 1.0], np.float32))
        for j in range(7):
            lo, hi = m.jnt_range[j]
            assert lo <= d.qpos[m.jnt_qposadr[j]] <= hi, j


def test_gravity_compensation_counts_against_the_torque_limits():
    """Both actuations compensate gravity through the actuators (``actuatorgravcomp``), so the
    arm's torque limits bound the compensation too, as on the robot."""
    for actuation in ("position", "velocity"):
        assert scene_model(actuation).jnt_actgravcomp[:7].tolist() == [1] * 7


def test_the_velocity_servos_cap_joint_speeds_at_the_sawyers_limits():
    scene = SawyerScene("velocity")
    scene.reset()
    m, d, arm = scene.model, scene.data, scene.arm
    ranges = m.actuator_ctrlrange[arm.velocity_actuators]
    np.testing.assert_allclose(ranges, np.stack([-VELOCITY_LIMITS, VELOCITY_LIMITS], 1))
    assert m.actuator_ctrllimited[arm.velocity_actuators].all()
    # the wrist (joint 6) already turning at its limit, asked for twice the limit: the servo
    # pushes no further (its reference is clamped to the limit), so the joint does not speed up
    joint, vmax = 6, VELOCITY_LIMITS[6]
    act, dof = arm.velocity_actuators[joint], arm.dof_adr[joint]
    d.qvel[dof] = vmax
    d.ctrl[act] = 2 * vmax
    mujoco.mj_forward(m, d)
    assert abs(d.actuator_force[act]) < 1e-6, d.actuator_force[act]


def test_a_reset_position_scene_stays_at_rest_in_its_home_configuration():
    scene = SawyerScene("position")
    scene.reset()
    m, d, arm = scene.model, scene.data, scene.arm
    home = np.array(arm.home_qpos[arm.qpos_adr])
    np.testing.assert_allclose(d.ctrl[arm.position_actuators], home)
    start = scene.ee_pos.copy()
    mujoco.mj_step(m, d, 5 * arm.n_substeps)  # 0.25 s with no controller
    mujoco.mj_forward(m, d)
    assert np.abs(d.qpos[arm.qpos_adr] - home).max() < 1e-2
    assert np.linalg.norm(scene.ee_pos - start) < 5e-3


def test_the_ik_step_keeps_every_joint_within_the_sawyers_speed_limits():
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    ctrl, arm = env.controller, env.scene.arm
    fastest = 0.0
    for far in ([0.3, 0.3, -0.15], [-0.3, 0.3, 0.1], [0.25, -0.35, 0.0]):
        v = ctrl.ik_step(env.scene.ee_pos + np.array(far))  # far beyond one step's reach
        ratio = np.abs(v[arm.dof_adr]) / arm.velocity_limits
        assert ratio.max() <= 1.0 + 1e-6, ratio
        fastest = max(fastest, ratio.max())
    assert fastest > 0.9  # a far target is pursued at the limit: the limit binds
    env.close()
