"""Driving on real SUMO (libsumo), sharing one simulation per module as libsumo requires."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from sili_robots.errors import ConfigError
from sili_robots.policies import scripted_policy
from sili_robots.tasks import make_task
from sili_robots.tasks import sumo_scenario as sc
from sili_robots.tasks.driving import (
    CENTRE,
    LEFT,
    MAX_LATERAL_OFFSET,
    MIN_HORIZON,
    RIGHT,
    DrivingEnv,
    lane_of,
    next_target_lane,
)
from sili_robots.wrappers import OracleObservation, StrategyFlag

Policy = Callable[[DrivingEnv, int], float]


@pytest.fixture
def make_env() -> Iterator[Callable[..., DrivingEnv]]:
    """Build Driving envs one at a time (libsumo: one simulation per process); asking for
    another closes the previous one, and the last is closed after the test."""
    live: list[gym.Env] = []

    def make(**kwargs) -> DrivingEnv:
        while live:
            live.pop().close()
        env = make_task("driving", **kwargs)
        live.append(env)
        return env.unwrapped

    yield make
    while live:
        live.pop().close()


@pytest.fixture
def env(make_env) -> DrivingEnv:
    return make_env()


def to_lane(lane: int) -> Policy:
    def policy(env: DrivingEnv, t: int) -> float:
        target = (lane - sc.CENTRE_LANE) * sc.LANE_WIDTH
        return float(np.clip((target - env.ego_y) / 2.0, -1.0, 1.0))

    return policy


def late(lane: int, start: int = 2) -> Policy:
    """Stay in the centre lane for ``start`` steps (past the red line), then merge."""
    merge = to_lane(lane)
    return lambda env, t: 0.0 if t < start else merge(env, t)


def play(env: DrivingEnv, policy: Policy, interactions: int, seed: int | None = None):
    """Per interaction: (strategy at its start, task return, collision partners, info)."""
    out = []
    for j in range(interactions):
        _, info = env.reset(seed=seed) if j == 0 and seed is not None else env.reset()
        z = info["strategy_id"]
        total = 0.0
        for t in range(env.horizon):
            _, r, _, _, info = env.step(np.array([policy(env, t)], np.float32))
            total += r
        out.append((z, total, tuple(info["collision_partners"]), info))
    return out


def first_seed(env: DrivingEnv, lane: int) -> int:
    """A seed whose first interaction has the opponent intending ``lane``."""
    for seed in range(50):
        if env.reset(seed=seed)[1]["strategy_id"] == lane:
            return seed
    raise AssertionError("no seed gives that first strategy")


def test_a_chosen_first_lane_within_rounding_is_that_lane(env):
    for lane in env.strategy_choices():
        _, info = env.reset(seed=0, options={"strategy": lane - 1e-10})
        assert info["strategy_id"] == lane  # not int(1.9999999999) = 1, no lane of the opponent's


def test_stabilizing_policy_forms_the_convention_then_never_collides(env):
    stabilizing = scripted_policy(env, "stabilizing")
    runs = play(env, lambda e, t: float(stabilizing(e, None)[0]), 8, seed=first_seed(env, LEFT))
    # First interaction: the opponent still cuts into the left lane and hits the ego ...
    assert runs[0][0] == LEFT and runs[0][1] == -1.0 and runs[0][2] == ("opponent",)
    assert runs[0][3]["left_before_red_line"]
    # ... after which it goes right every time and nobody collides.
    for z, total, partners, info in runs[1:]:
        assert (z, total, partners) == (RIGHT, 0.0, ())
        assert info["ego_lane"] == LEFT


def test_oracle_never_collides_from_either_start(env):
    oracle = scripted_policy(env, "oracle")
    for lane in (LEFT, RIGHT):
        runs = play(env, lambda e, t: float(oracle(e, None)[0]), 4, seed=first_seed(env, lane))
        assert runs[0][0] == lane
        assert [r[1] for r in runs] == [0.0] * 4


@pytest.mark.parametrize("lane", [LEFT, RIGHT])
def test_late_merge_gets_cut_off_every_time(env, lane):
    other = LEFT if lane == RIGHT else RIGHT  # the first time, the opponent goes the other way
    runs = play(env, late(lane), 5, seed=first_seed(env, other))
    assert runs[0][1] == 0.0  # lucky once ...
    for z, total, partners, info in runs[1:]:
        # ... then it merges into the lane the ego passed in last time: a cut-off.
        assert z == lane and total == -1.0 and partners == ("opponent",)
        assert not info["left_before_red_line"]


def test_centre_policy_hits_opponent_and_hazard(env):
    runs = play(env, lambda e, t: 0.0, 3, seed=0)
    for _, total, partners, _ in runs:
        assert total == -1.0  # one collision per interaction at most is what the reward counts
        assert partners == ("hazard", "opponent")


def test_the_shortest_horizon_is_the_first_in_which_the_cars_meet(make_env):
    """Below ``MIN_HORIZON`` the ego never reaches the opponent: refused, it would score 0."""
    env = make_env(horizon=MIN_HORIZON)
    env.reset(seed=0)
    rewards = [env.step(np.zeros(1, np.float32))[1] for _ in range(MIN_HORIZON)]
    assert rewards == [0.0] * (MIN_HORIZON - 1) + [-1.0]  # met in the last step, not before
    assert env.collision_partners == {"opponent"} and env.passed


def test_red_line_rule(env):
    # Both merge left; A is across the left divider (1.6 m) when crossing the red line, B not.
    just_before = lambda e, t: [0.0, 1.0][t] if t < 2 else to_lane(LEFT)(e, t)  # noqa: E731
    just_after = lambda e, t: [0.0, 0.75][t] if t < 2 else to_lane(LEFT)(e, t)  # noqa: E731
    for policy, convention in ((just_before, True), (just_after, False)):
        runs = play(env, policy, 3, seed=0)
        for _, _, _, info in runs:
            assert info["left_before_red_line"] is convention
            assert info["ego_lane"] == LEFT
        expected_next = RIGHT if convention else LEFT
        assert [r[0] for r in runs[1:]] == [expected_next] * 2
    assert lane_of(1.61) == LEFT and lane_of(1.59) == sc.CENTRE_LANE and lane_of(-1.61) == RIGHT


def test_collisions_are_sumos_and_match_geometry(env):
    """SUMO checks collisions after the longitudinal move and again after the lateral one."""
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    length, width, eps = sc.VEHICLE_LENGTH, sc.VEHICLE_WIDTH, 1e-6
    hazard_x = sc.HAZARD_POSITION - sc.EGO_START
    seen = {True: 0, False: 0}
    for _ in range(25):
        env.reset()
        for _ in range(env.horizon):
            env.step(rng.uniform(-1, 1, size=1).astype(np.float32))
        previous = env.substeps[0]
        for step in env.substeps[1:]:
            _, ex, ey, ox, oy, partners = step
            _, _, pey, _, poy, _ = previous
            overlap = (
                abs(ex - ox) < length - eps and min(abs(ey - oy), abs(pey - poy)) < width - eps
            )
            assert ("opponent" in partners) == overlap, step
            seen[overlap] += 1
            hazard = abs(ex - hazard_x) < length - eps and min(abs(ey), abs(pey)) < width - eps
            assert ("hazard" in partners) == hazard, step
            previous = step
        assert env.collided == any(s[5] for s in env.substeps)
    assert seen[True] > 0 and seen[False] > 0


def test_reset_restores_state_without_restarting_sumo(env):
    env.reset(seed=0)
    session = env.session
    api = session.api
    first, _ = env.reset()
    start_time = api.simulation.getTime()
    for _ in range(env.horizon):
        env.step(np.array([1.0], np.float32))
    assert api.simulation.getTime() == pytest.approx(start_time + env.horizon * 1.0)
    again, _ = env.reset()
    assert env.session is session  # the same running simulation
    assert api.simulation.getTime() == pytest.approx(start_time)
    np.testing.assert_array_equal(first, again)
    # loadState rebuilt the vehicles; the settings it drops were applied again.
    for vid in (sc.EGO_ID, sc.OPPONENT_ID, sc.HAZARD_ID):
        assert api.vehicle.getSpeedMode(vid) == 0
        assert api.vehicle.getLaneChangeMode(vid) == 0
    # Fixed forward speeds: 20 m/s and 10 m/s, i.e. 0.2 and 0.1 observation units per step.
    obs, *_ = env.step(np.array([0.0], np.float32))
    np.testing.assert_allclose(obs[[0, 2]] - again[[0, 2]], [0.2, 0.1], atol=1e-5)


def test_seeded_runs_are_reproducible(env):
    def trace(seed):
        rng = np.random.default_rng(seed)
        obs, info = env.reset(seed=seed)
        out = [obs, info["strategy_id"]]
        for j in range(4):
            if j:
                obs, info = env.reset()
                out += [obs, info["strategy_id"]]
            for _ in range(env.horizon):
                obs, r, *_ = env.step(rng.uniform(-1, 1, size=1).astype(np.float32))
                out += [obs, r]
        return out

    a, b = trace(3), trace(3)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    firsts = {env.reset(seed=s)[1]["strategy_id"] for s in range(10)}
    assert firsts == {RIGHT, LEFT}  # the seed picks z^1


def test_observation_space_and_intent_stays_hidden(make_env):
    plain = make_env()
    observations = {}
    for seed in range(10):
        obs, info = plain.reset(seed=seed)
        assert obs.dtype == np.float32 and plain.observation_space.contains(obs)
        observations[info["strategy_id"]] = obs
    assert set(observations) == {RIGHT, LEFT}
    np.testing.assert_array_equal(observations[RIGHT], observations[LEFT])
    for t in range(1, plain.horizon + 1):
        obs, _, term, trunc, _ = plain.step(np.array([0.3], np.float32))
        assert obs[-1] == pytest.approx(t / plain.horizon)
        assert (term, trunc) == (False, t == plain.horizon)
    oracle = OracleObservation(make_env())
    obs, info = oracle.reset(seed=0)
    assert obs.shape == (7,)
    np.testing.assert_array_equal(obs[-2:], info["strategy"])
    assert obs[-2:].tolist() == ([1.0, 0.0] if info["strategy_id"] == RIGHT else [0.0, 1.0])


@pytest.mark.parametrize("wrap", [lambda e: e, OracleObservation, StrategyFlag])
def test_check_env_passes(make_env, wrap):
    check_env(wrap(make_env()), skip_render_check=True)


def test_a_failed_start_keeps_what_the_next_strategy_is_drawn_from(env, monkeypatch):
    """SUMO refusing to start an interaction must not wipe the finished one's flags, which
    T^z reads at the next reset: in the left lane before the red line, the opponent goes right."""
    from sili_robots.tasks.sumo_session import SumoError

    env.reset(seed=0, options={"strategy": LEFT})
    for t in range(env.horizon):
        env.step(np.array([to_lane(LEFT)(env, t)], np.float32))
    assert env.left_before_red_line
    api = env.session.api

    def refused(_path: str) -> None:
        raise api.TraCIException("state file unreadable")

    monkeypatch.setattr(api.simulation, "loadState", refused)
    with pytest.raises(SumoError, match="state file unreadable"):
        env.reset()
    monkeypatch.undo()
    assert env.left_before_red_line and (env.interaction, env.t) == (0, env.horizon)
    _, info = env.reset()
    assert (info["interaction"], info["strategy_id"]) == (1, RIGHT)


def test_bad_arguments_are_named(env):
    for horizon in (31, 5, 0, 2.5, True):  # one range named, not every task's [1, 10000]
        with pytest.raises(ConfigError, match=rf"integer from 6 \(.*\) to 30.*got {horizon!r}$"):
            DrivingEnv(horizon=horizon)
    with pytest.raises(ConfigError, match=r"unknown SUMO backend 'sumo'; allowed: libsumo, traci"):
        DrivingEnv(backend="sumo")
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=r"shape \(1,\).*got shape \(2,\)"):
        env.step(np.zeros(2))


def test_traci_backend_runs_the_same_scenario(env):
    """The socket client (the benchmark's reference) gives the very same interactions."""
    policy = late(LEFT)
    expected = play(env, policy, 2, seed=5)
    traci_env = DrivingEnv(backend="traci")  # no libsumo slot needed next to `env`
    try:
        got = play(traci_env, policy, 2, seed=5)
        assert traci_env.substeps == env.substeps
    finally:
        traci_env.close()
    assert [g[:3] for g in got] == [e[:3] for e in expected]


def test_game_state_resumes_in_a_fresh_environment(make_env):
    env = make_env()
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (6, env.horizon, 1)).astype(np.float32)

    def tail(e):
        out = []
        for j in range(3, 6):
            out += [e.step(a)[:2] for a in actions[j]]
            e.reset()
        return out

    for j in range(3):
        for a in actions[j]:
            env.step(a)
        env.reset()
    saved = env.game_state()
    expected = tail(env)
    fresh = make_env()  # closes `env`: one libsumo simulation at a time
    with pytest.raises(ConfigError, match=r"give strategy 5; DrivingEnv's strategies are"):
        fresh.restore_game_state({**saved, "fields": {"target_lane": 5}})
    fresh.restore_game_state(saved)
    got = tail(fresh)
    for (oa, ra), (ob, rb) in zip(expected, got, strict=True):
        np.testing.assert_array_equal(oa, ob)
        assert ra == rb
    assert any(r < 0 for _, r in expected) and any(r == 0 for _, r in expected)


def test_a_running_simulation_is_not_copied_and_says_how_to_save_the_game():
    import copy

    env = make_task("driving")
    try:
        copy.deepcopy(env).close()  # before the first reset: no simulation yet
        env.reset(seed=0)
        with pytest.raises(TypeError, match=r"running SUMO simulation cannot be.*game_state"):
            copy.deepcopy(env)  # was "cannot pickle 'module' object"
    finally:
        env.close()


def test_the_opponent_cuts_into_the_lane_the_ego_passed_it_in():
    """T^z: right after a left merge before the red line; else the lane the ego was in when it
    passed the opponent, the centre lane's middle counting as left (driving straight)."""
    half = sc.LANE_WIDTH / 2
    assert next_target_lane(True, 0.0) == RIGHT
    assert next_target_lane(False, 0.0) == LEFT  # straight down the centre
    assert next_target_lane(False, -0.01) == RIGHT
    assert next_target_lane(False, half + 0.5) == LEFT
    assert next_target_lane(False, -half - 0.5) == RIGHT


def test_the_passing_offset_is_where_the_ego_passed_not_where_it_ended(env):
    env.reset(seed=0)
    for _ in range(env.horizon):  # straight until it has passed, then to the left lane
        env.step(np.array([1.0 if env.passed else 0.0], np.float32))
    passed_at = next(ego_y for _, ego_x, ego_y, opp_x, *_ in env.substeps if opp_x <= ego_x)
    assert env.passed and env.passing_offset == passed_at
    assert abs(env.ego_y - passed_at) > 1.0  # it moved on after passing


def test_the_passing_offset_is_taken_when_the_fronts_are_level(env):
    """Merging as the ego passes (the fronts are level at 6.0 s): the offset is the one at the
    SUMO step of passing, not a step later (0.2 m on)."""
    env.reset(seed=0)
    for t in range(env.horizon):
        env.step(np.array([0.0 if t < 6 else 1.0], np.float32))
    passed_at = next(ego_y for _, ego_x, ego_y, opp_x, *_ in env.substeps if opp_x <= ego_x)
    assert env.passing_offset == passed_at


def test_the_passing_offset_is_not_taken_before_the_fronts_are_level(env):
    """Drifting left through the pass: the offset is where the ego was when the opponent's
    front came level, not up to a metre (or a step) before."""
    env.reset(seed=0)
    for t in range(env.horizon):
        env.step(np.array([0.0 if t < 4 else 0.3], np.float32))
    passed_at = next(ego_y for _, ego_x, ego_y, opp_x, *_ in env.substeps if opp_x <= ego_x)
    assert env.passing_offset == passed_at


def test_the_opponents_lateral_position_is_observed_in_lane_widths(env):
    env.reset(seed=0)
    for _ in range(env.horizon):
        obs, *_ = env.step(np.array([0.0], np.float32))
    assert abs(env.opp_y) > 1.0  # it cut in
    assert obs[3] == pytest.approx(env.opp_y / sc.LANE_WIDTH, abs=1e-5)


def test_at_the_road_edge_the_observation_is_inside_its_space(env):
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an observation outside its space warns
        for _ in range(env.horizon):
            obs, *_ = env.step(np.array([1.0], np.float32))
    assert obs[1] * sc.LANE_WIDTH == pytest.approx(env.ego_y, abs=1e-5)
    assert env.ego_y > sc.LANE_WIDTH  # in the left lane, at its edge


def test_the_longest_horizon_allowed_is_played(make_env):
    env = make_env(horizon=30)
    env.reset(seed=0)
    for _ in range(30):
        env.step(np.array([1.0], np.float32))
    assert env.t == 30


def test_the_opponent_cuts_in_at_three_metres_per_second(env):
    """Its vehicle type's lateral speed, which the scenario sets (a change of the dynamics is a
    new task version)."""
    env.reset(seed=0)
    for _ in range(env.horizon):
        env.step(np.array([0.0], np.float32))
    moved = np.abs(np.diff([s[4] for s in env.substeps]))
    assert moved.max() == pytest.approx(sc.OPPONENT_LATERAL_SPEED * sc.STEP_LENGTH, abs=1e-6)
    assert sc.OPPONENT_LATERAL_SPEED == 3.0


def test_the_scenario_cache_key_covers_the_routes(monkeypatch):
    """Changing a vehicle's speed or start builds the scenario anew, not from the cache."""
    key = sc.scenario_key()
    monkeypatch.setattr(sc, "OPPONENT_SPEED", 12.0)
    assert sc.scenario_key() != key


def test_at_the_right_road_edge_the_ego_stays_on_the_road(env):
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an observation outside its space warns
        for _ in range(env.horizon):
            obs, *_ = env.step(np.array([-1.0], np.float32))
            assert env.ego_y >= -MAX_LATERAL_OFFSET - 1e-6
    assert env.ego_y < -sc.LANE_WIDTH  # in the right lane, at its edge
    assert env.ego_y == pytest.approx(-MAX_LATERAL_OFFSET, abs=0.05)
    assert obs[1] * sc.LANE_WIDTH == pytest.approx(env.ego_y, abs=1e-5)


def test_lane_edges_belong_to_the_centre_lane_on_both_sides():
    edge = sc.LANE_WIDTH / 2
    assert lane_of(edge) == lane_of(-edge) == CENTRE
    assert lane_of(edge + 1e-9) == LEFT and lane_of(-edge - 1e-9) == RIGHT
    # passed on the left edge of the centre lane: the opponent cuts in leftwards (centre, lean)
    assert next_target_lane(False, edge) == LEFT
    assert next_target_lane(False, -edge) == RIGHT


@pytest.mark.parametrize("steps", [3, 10])
def test_a_closed_env_says_so_whether_or_not_its_interaction_had_ended(make_env, steps):
    env = make_env()
    env.reset(seed=0)
    for _ in range(steps):
        env.step(np.zeros(1, np.float32))
    env.close()
    for call in (lambda: env.step(np.zeros(1, np.float32)), lambda: env.reset()):
        with pytest.raises(RuntimeError, match="this Driving environment was closed"):
            call()
