"""Circle point mass: geometry and the inside/outside strategy rule."""

import math

import numpy as np
import pytest

from sili_robots.policies import scripted_policy
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task
from sili_robots.tasks.circle import RADIUS


def _finish_at(env, target, seed=None):
    """Play one interaction that ends at ``target`` (by teleporting the last step)."""
    for _ in range(env.horizon - 1):
        env.step(np.zeros(2))
    env.position = np.asarray(target, float)
    env.step(np.zeros(2))


def test_the_reward_is_minus_the_distance_to_the_opponent_after_the_move():
    """Euclidean, after the move (the action, a velocity, times 0.1 per step)."""
    env = make_task("circle-3").unwrapped
    env.reset(seed=0, options={"strategy": 0})
    env.position = np.array([0.3, -0.2])
    _, reward, *_ = env.step(np.array([1.0, 0.5]))
    np.testing.assert_allclose(env.position, [0.4, -0.15])
    other = env.opponent_position
    assert reward == pytest.approx(-math.hypot(0.4 - other[0], -0.15 - other[1]))


def test_the_point_mass_stays_in_the_arena_and_is_paid_where_it_stopped():
    """Positions are clipped to [-2, 2]^2 (the observation's bounds): pushing past the corner
    leaves the ego at it, observed and rewarded there."""
    env = make_task("circle-3").unwrapped
    env.reset(seed=0, options={"strategy": 0})
    env.position = np.array([1.95, -1.97])
    obs, reward, *_ = env.step(np.array([1.0, -1.0]))
    np.testing.assert_array_equal(env.position, [2.0, -2.0])
    np.testing.assert_array_equal(obs[:2], [2.0, -2.0])
    other = env.opponent_position
    assert reward == pytest.approx(-math.hypot(2.0 - other[0], -2.0 - other[1]))


@pytest.mark.parametrize("variant,n", [("3", 3), ("8", 8)])
def test_inside_moves_counter_clockwise_outside_holds(variant, n):
    env = make_task(f"circle-{variant}").unwrapped
    env.reset(seed=0)
    loc = env.location
    _finish_at(env, [0.0, 0.0])  # inside
    env.reset()
    assert env.location == (loc + 1) % n
    a_before = env.angles[loc]
    assert math.isclose((env.angles[env.location] - a_before) % (2 * math.pi), 2 * math.pi / n)
    _finish_at(env, [0.0, 1.5])  # outside
    _, info = env.reset()
    assert env.location == (loc + 1) % n
    assert info["strategy_changed"] is False


def test_continuous_inside_moves_by_bounded_angle_outside_holds():
    env = make_task("circle-continuous").unwrapped
    env.reset(seed=0)
    jumps = []
    for _ in range(200):
        before = env.angle
        _finish_at(env, [0.0, 0.0])
        env.reset()
        jumps.append((env.angle - before) % (2 * math.pi))
    jumps = np.array(jumps)
    assert jumps.min() >= math.pi / 3 - 1e-9 and jumps.max() <= math.pi + 1e-9
    assert len(np.unique(np.round(jumps, 6))) > 100  # a continuum of strategies
    before = env.angle
    _finish_at(env, [1.5, 1.5])
    env.reset()
    assert env.angle == before


def test_unequal_only_the_far_location_can_be_held():
    env = make_task("sili/CircleUnequal-v0").unwrapped
    env.reset(seed=0)
    start = env.start
    dists = [
        np.linalg.norm(start - RADIUS * np.array([math.cos(a), math.sin(a)])) for a in env.angles
    ]
    assert dists[0] > max(dists[1], dists[2])  # the stable location is the farther one
    for loc in (1, 2):  # unstable: moves on even when the ego ends outside
        env.location = loc
        _finish_at(env, [0.0, 1.8])
        env.reset()
        assert env.location == (loc + 1) % 3
    env.location = 0
    _finish_at(env, [0.0, 1.8])
    env.reset()
    assert env.location == 0
    _finish_at(env, [0.0, 0.0])
    env.reset()
    assert env.location == 1


@pytest.mark.parametrize(
    "name", ["circle-3", "circle-8", "circle-continuous", "sili/CircleUnequal-v0"]
)
def test_stabilizing_policy_holds_the_opponent(name):
    env = make_task(name)
    # 300 interactions: Unequal must first pass its (at most two) unstable locations.
    summary = run_interactions(env, scripted_policy(env, "stabilizing"), 300, seed=0)
    unchanged = np.mean([not s.strategy_changed for s in summary[1:]])
    assert unchanged >= 0.99


@pytest.mark.parametrize("kind", ["stabilizing", "blind"])
def test_scripted_holds_also_hold_with_a_wide_margin(kind):
    # circle-3's 210 and 330 degree locations lie off the axes and diagonals: stepping out
    # 0.5 + 0.02 there takes more steps than diagonal moves at full speed would
    env = make_task("circle-3", outside_margin=0.5)
    summary = run_interactions(env, scripted_policy(env, kind), 40, seed=0)
    assert not any(s.strategy_changed for s in summary[1:])


@pytest.mark.parametrize("name", ["circle-3", "circle-8", "circle-continuous"])
def test_oracle_policy_is_near_optimal(name):
    env = make_task(name)
    summary = run_interactions(env, scripted_policy(env, "oracle"), 20, seed=0)
    # Lower bound on the cost: straight line at full speed from the centre (distance 1).
    best = -sum(max(0.0, 1.0 - 0.1 * math.sqrt(2) * t) for t in range(1, 51))
    mean = np.mean([s.task_reward for s in summary])
    assert mean >= best * 1.6  # within the slack of an axis-aligned (box) action
    random_env = make_task(name)
    rand = run_interactions(random_env, scripted_policy(random_env, "random"), 20, seed=0)
    assert mean > np.mean([s.task_reward for s in rand]) + 20


def test_every_location_reachable_and_detour_feasible():
    env = make_task("sili/Circle8-v0").unwrapped
    env.reset(seed=0)
    policy = scripted_policy(env, "stabilizing")
    for _ in range(8):
        obs = env._observation()
        for _ in range(env.horizon):
            obs, *_ = env.step(policy(env, obs))
        assert np.linalg.norm(env.position - env.opponent_position) < 0.05
        assert np.linalg.norm(env.position) >= RADIUS
        env.location = (env.location + 1) % 8
        env.reset()


def test_the_continuous_first_strategy_is_drawn_from_the_whole_circle():
    env = make_task("circle-continuous").unwrapped
    angles = []
    for seed in range(200):
        env.reset(seed=seed)
        angles.append(env.angle)
    angles = np.array(angles)
    assert angles.min() >= 0.0 and angles.max() < 2 * math.pi
    # each quarter of the circle gets about a quarter of the draws
    counts = np.bincount((angles // (math.pi / 2)).astype(int), minlength=4)
    assert counts.min() > 0.15 * len(angles), counts


def test_on_v0_the_tracking_reference_ends_inside_so_the_opponent_always_moves_on():
    env = make_task("sili/Circle3-v0")
    summary = run_interactions(env, scripted_policy(env, "tracking"), 12, seed=0)
    assert all(s.strategy_changed for s in summary[1:])
    task = env.unwrapped
    assert task.ends_inside(task.position)
    assert np.linalg.norm(task.position) > RADIUS - 0.01  # it waits at the circle, just inside
