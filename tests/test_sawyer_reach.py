"""Sawyer-Reach on the real MuJoCo scene: contract, seeding, observation, strategy rule."""

import json

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from sili_robots.cli import main as cli_main
from sili_robots.errors import ConfigError
from sili_robots.policies import scripted_policy
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task, task_spec
from sili_robots.tasks.sawyer_reach import MAX_SPEED, SawyerReachEnv
from sili_robots.tasks.sawyer_scene import GOALS, PLANE_Z, START_EE, TABLE_TOP_Z
from sili_robots.wrappers import OracleObservation, StrategyFlag


@pytest.fixture(scope="module")
def below_plane_qpos() -> np.ndarray:
    """A joint configuration with the end effector at goal 0, below the plane (by physics)."""
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    env.goal = 0
    policy = scripted_policy(env, "oracle")
    obs = env._observation()
    for _ in range(30):
        obs, *_ = env.step(policy(env, obs))
    assert env.scene.ee_pos[2] < PLANE_Z
    return env.scene.data.qpos.copy()


def _end_interaction_at(env: SawyerReachEnv, qpos: np.ndarray) -> None:
    env.scene.data.qpos[:] = qpos
    mujoco.mj_forward(env.scene.model, env.scene.data)


def test_registered_with_gymnasium_and_spaces():
    spec = task_spec("sili/SawyerReach-v0")
    assert spec.gym_id == "sili/SawyerReach-v0"
    env = gym.make("sili/SawyerReach-v0")
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    assert env.observation_space.dtype == np.float32
    assert env.observation_space.shape == (7,)  # ee position, ee velocity, t/H
    assert env.unwrapped.horizon == 50
    env.close()


@pytest.mark.parametrize("wrap", [lambda e: e, OracleObservation, StrategyFlag])
def test_check_env_passes(wrap):
    env = wrap(make_task("sawyer-reach").unwrapped)
    check_env(env, skip_render_check=True)


def test_the_scene_reserves_a_small_arena():
    """robosuite's nconmax = njmax = 5000 made every MjData reserve 1.25 GB of address space:
    under a vmem limit, or with a few envs in one process, MuJoCo could not allocate one."""
    from sili_robots.tasks.sawyer_scene import ACTUATIONS, scene_model

    for actuation in ACTUATIONS:
        assert scene_model(actuation).narena <= 16 * 2**20, actuation


def test_unknown_controller_is_a_config_error_listing_choices():
    for build in (
        lambda: make_task("sawyer-reach", controller="pid"),
        lambda: gym.make("sili/SawyerReach-v0", controller="pid"),
        lambda: SawyerReachEnv(controller="pid"),
    ):
        with pytest.raises(ConfigError, match=r"'pid'; allowed: mink, osc, joint_velocity"):
            build()


def test_observation_is_position_velocity_time_and_never_the_goal():
    firsts = {}
    for seed in range(12):
        obs, info = make_task("sili/SawyerReach-v0").unwrapped.reset(seed=seed)
        firsts.setdefault(info["strategy_id"], obs)
    assert len(firsts) == 3  # every goal drawn at least once...
    for obs in firsts.values():  # ...and the first observation is the same for all of them
        np.testing.assert_array_equal(obs, firsts[0])
    obs = firsts[0]
    np.testing.assert_allclose(obs[:3], START_EE, atol=1e-4)
    np.testing.assert_allclose(obs[3:6], 0.0, atol=1e-6)
    assert obs[6] == 0.0

    env = OracleObservation(make_task("sili/SawyerReach-v0").unwrapped)
    obs, info = env.reset(seed=1)
    np.testing.assert_allclose(obs[-3:], GOALS[info["strategy_id"]], atol=1e-6)
    obs, reward, *_ = env.step(np.array([0.0, 0.0, -1.0]))
    assert obs[6] == pytest.approx(1 / 50)
    # Velocity is measured, not the command: moving down at (at most) MAX_SPEED.
    assert -MAX_SPEED * 1.2 < obs[5] < -0.05
    assert reward == pytest.approx(-np.linalg.norm(obs[:3] - GOALS[info["strategy_id"]]), abs=1e-5)


def test_seed_reproduces_the_repeated_game():
    def play(seed):
        env = make_task("sawyer-reach").unwrapped
        obs, info = env.reset(seed=seed)
        env.action_space.seed(seed)
        trace = [obs]
        ids = [info["strategy_id"]]
        for j in range(3):
            if j:
                obs, info = env.reset()
                ids.append(info["strategy_id"])
            for _ in range(env.horizon):
                obs, *_ = env.step(env.action_space.sample())
                trace.append(obs)
        return np.array(trace), ids

    a, ids_a = play(3)
    b, ids_b = play(3)
    c, _ = play(4)
    np.testing.assert_array_equal(a, b)
    assert ids_a == ids_b
    assert not np.array_equal(a, c)


def test_strategy_rule_above_plane_keeps_below_moves_uniformly(below_plane_qpos):
    env = make_task("sili/SawyerReach-v0").unwrapped
    env.reset(seed=0)
    moves = {0: [], 1: [], 2: []}
    for _ in range(300):
        before = env.goal
        _end_interaction_at(env, below_plane_qpos)  # ends below the plane
        _, info = env.reset()
        assert env.goal != before and info["strategy_changed"]
        moves[before].append(env.goal)
    for before, after in moves.items():
        others = [g for g in range(3) if g != before]
        counts = [after.count(g) for g in others]
        assert min(counts) > 0.3 * len(after), (before, counts)  # uniform among the other two
    for _ in range(5):  # ends at the start pose, above the plane: the goal is kept
        before = env.goal
        assert env.ends_above_plane()
        _, info = env.reset()
        assert env.goal == before and not info["strategy_changed"]


def test_scripted_policies_hold_or_move_the_goal_end_to_end():
    env = make_task("sawyer-reach")
    stable = run_interactions(env, scripted_policy(env, "stabilizing"), 4, seed=0)
    assert all(not s.strategy_changed for s in stable[1:])
    assert len({s.end_strategy_id for s in stable}) == 1
    chase = run_interactions(env, scripted_policy(env, "oracle"), 4, seed=0)
    assert all(s.strategy_changed for s in chase[1:])
    # Reaching the true goal beats ending above the plane on task reward within an interaction.
    assert np.mean([s.task_reward for s in chase]) > np.mean([s.task_reward for s in stable])


def test_table_stops_the_gripper():
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    table = env.scene.model.geom("table_collision").id
    touched = False
    for _ in range(env.horizon):  # push straight down into the table at full speed
        env.step(np.array([0.0, 0.0, -1.0]))
        d = env.scene.data
        touched |= any(table in (d.contact[i].geom1, d.contact[i].geom2) for i in range(d.ncon))
    assert touched
    # The grip site sits ~1.5 cm above the fingertips; the table top is at 0.8 m.
    assert TABLE_TOP_Z + 0.005 < env.scene.ee_pos[2] < TABLE_TOP_Z + 0.03


def test_game_state_resumes_the_repeated_game(below_plane_qpos):
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=5)
    for _ in range(3):
        _end_interaction_at(env, below_plane_qpos)
        env.reset()
    saved = env.game_state()
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (3, env.horizon, 3))

    def tail(e):
        out = []
        for j in range(3):
            for a in actions[j]:
                out.append(e.step(a)[:2])
            out.append(e.reset()[1]["strategy_id"])
        return out

    a = tail(env)
    fresh = make_task("sawyer-reach").unwrapped
    with pytest.raises(ConfigError, match=r"give strategy 7; SawyerReachEnv's strategies are 0, 1"):
        fresh.restore_game_state({**saved, "fields": {"goal": 7}})  # was IndexError, scene moved
    fresh.restore_game_state(saved)
    b = tail(fresh)
    for x, y in zip(a, b, strict=True):
        if isinstance(x, tuple):
            np.testing.assert_array_equal(x[0], y[0])
            assert x[1] == y[1]
        else:
            assert x == y


def test_cli_rollout_runs_on_sawyer(capsys):
    assert (
        cli_main(["rollout", "sawyer-reach", "--policy", "stabilizing", "--interactions", "2"]) == 0
    )
    out = capsys.readouterr().out
    assert "task=sawyer-reach controller='mink' policy=stabilizing" in out  # the default, named
    assert "unchanged (after the first): 1.000" in out


def test_cli_eval_plays_a_trained_run_with_another_controller(tmp_path, capsys):
    """A transfer ablation: a policy trained with mink, played greedily with OSC."""
    run = str(tmp_path / "r")
    train = ["train", "--task", "sawyer-reach", "--method", "sac", "--interactions", "1"]
    assert cli_main([*train, "--set", "hidden=8", "--no-progress", "--out", run]) == 0
    capsys.readouterr()
    played = {}
    for given in ([], ["--controller", "osc"], ["--controller", "osc"]):
        assert cli_main(["eval", run, "--interactions", "2", *given]) == 0
        result = json.loads(capsys.readouterr().out)
        assert result["played_with"] == {"controller": "osc" if given else "mink"}
        assert result["trained_with"] == {"controller": "mink"}
        played.setdefault(tuple(given), []).append(result["mean_task_reward"])
    (own,), (osc, again) = played.values()
    assert osc == again and osc != own  # greedy: the same game, moved by another controller
    refused = {
        "--controller=foo": "unknown controller 'foo'; allowed: mink, osc, joint_velocity",
        "--env-kwarg=foo=1": "takes no argument foo (--controller, --env-kwarg)",
        "--env-kwarg=horizon=9": "horizon=9: the run in ",  # it was trained with horizon 50
    }
    for option, message in refused.items():
        assert cli_main(["eval", run, "--interactions", "2", option]) == 2
        assert message in capsys.readouterr().err


def test_the_strategy_rule_compares_the_hand_with_the_plane_itself():
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    hand = float(env.scene.ee_pos[2])
    env.plane_z = hand - 0.01
    assert env.ends_above_plane()
    env.plane_z = hand + 0.01
    assert not env.ends_above_plane()


def test_an_action_of_one_moves_the_hands_target_at_the_top_speed():
    """|action| = 1 is MAX_SPEED (0.4 m/s), 2 cm per control step of 0.05 s."""
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    before = env.controller.target.copy()
    env.step(np.array([1.0, 0.0, -0.5], np.float32))
    dt = env.controller.arm.control_dt
    np.testing.assert_allclose(env.controller.target - before, [0.02, 0.0, -0.01], atol=1e-12)
    assert MAX_SPEED * dt == pytest.approx(0.02)


def test_the_stabilizing_reference_rises_for_the_last_rise_steps():
    from sili_robots.tasks.sawyer_reach import RISE_MARGIN, RISE_STEPS, stabilizing_point

    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    for _ in range(env.horizon - RISE_STEPS):
        env.step(np.zeros(3, np.float32))
    assert stabilizing_point(env)[2] == pytest.approx(env.plane_z + RISE_MARGIN)


@pytest.mark.parametrize("kind", ["blind", "tracking"])
def test_blind_and_tracking_policies_act_on_the_goal_revealed(kind):
    """Blind stabilizes the goal the last interaction revealed; tracking waits between the
    other two, where the goal moves (the reference bounds of both rest on it)."""
    from sili_robots.tasks.sawyer_reach import action_toward, stabilizing_point

    env = make_task("sawyer-reach")
    task = env.unwrapped
    policy = scripted_policy(env, kind)
    obs, _ = env.reset(seed=0, options={"strategy": 2})
    for _ in range(task.horizon):
        obs, *_ = env.step(policy(env, obs))
    obs, _ = env.reset()
    if kind == "blind":
        wanted = action_toward(task, stabilizing_point(task, 2))
    else:
        wanted = action_toward(task, GOALS[[0, 1]].mean(axis=0))
    np.testing.assert_allclose(policy(env, obs), wanted)


def test_goals_differ_in_worth_as_docs_say():
    """The per-axis clip (docs/tasks.md, README's departures): holding goal 0, straight along x,
    costs more than holding a diagonal goal; the stabilizing reference's per-goal costs."""
    env = gym.make("sili/SawyerReach-v1")
    costs = []
    for goal in range(3):
        policy = scripted_policy(env, "stabilizing")
        played = run_interactions(env, policy, 2, seed=goal, options={"strategy": goal})
        assert [p.end_strategy_id for p in played] == [goal, goal]
        costs.append(-played[1].task_reward)
    env.close()
    assert costs == pytest.approx([2.73, 2.50, 2.57], abs=0.01)


def test_a_diverged_simulation_is_named_with_its_controller(monkeypatch):
    env = make_task("sawyer-reach").unwrapped
    env.reset(seed=0)
    real_step = env.controller.step

    def diverging(velocity):
        real_step(velocity)
        env.scene.data.qpos[env.scene.arm.qpos_adr[0]] = np.nan

    monkeypatch.setattr(env.controller, "step", diverging)
    with pytest.raises(RuntimeError, match=r"simulation diverged under controller 'mink'"):
        env.step(np.zeros(3, np.float32))
    env.close()


def test_the_progress_line_names_the_controller_given_or_not():
    from sili_robots.build import make_run_config
    from sili_robots.training import run_label

    for given, named in ({}, "mink"), ({"controller": "osc"}, "osc"):
        cfg = make_run_config("sawyer-reach", "sac", seed=2, env_kwargs=given)
        assert run_label(cfg) == f"sawyer-reach controller={named} sac seed 2"
    assert run_label(make_run_config("circle-3", "sili")) == "circle-3 sili seed 0"
