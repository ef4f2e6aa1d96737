"""Detour Speaker-Listener: the visit rule and the speaker's change probability."""

import warnings

import numpy as np
import pytest

from sili_robots.errors import ConfigError
from sili_robots.policies import scripted_policy
from sili_robots.policies.scripted import Revealed
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task
from sili_robots.tasks.speaker_listener import (
    ARENA,
    GOALS,
    MAPPINGS,
    SPEAKER,
    VISIT_RADIUS,
    SpeakerListenerEnv,
)
from sili_robots.wrappers import StrategyFlag


def test_change_probability_is_one_half_while_unvisited():
    env = make_task("sili/SpeakerListener-v0").unwrapped
    env.reset(seed=0)
    changes, steps = 0, 0
    for _ in range(400):
        for _ in range(env.horizon):
            before = env.mapping
            _, _, _, _, info = env.step(np.array([0.0, 0.5]))  # away from the speaker
            if env.t < env.horizon:
                changes += int(env.mapping != before)
                steps += 1
                assert info["strategy_changed"] == (env.mapping != before)
        env.reset()
    rate = changes / steps
    assert abs(rate - 0.5) < 0.02, rate


def test_visit_locks_mapping_for_rest_and_next_interaction():
    flagged = StrategyFlag(make_task("sili/SpeakerListener-v0").unwrapped)
    env = flagged.unwrapped
    flagged.reset(seed=1)
    env.position = SPEAKER.copy()
    obs, *_ = flagged.step(np.zeros(2))
    assert env.visited_now
    locked = env.mapping
    for _ in range(env.horizon - 1):
        obs, *_ = flagged.step(np.array([0.0, 1.0]))
        assert env.mapping == locked and obs[-1] == 0.0
    _, info = env.reset()
    assert env.mapping == locked and not info["strategy_changed"]
    for _ in range(env.horizon):  # held all of the next interaction, even without a visit
        env.step(np.array([0.0, 1.0]))
        assert env.mapping == locked
    env.reset()
    seen = set()
    for _ in range(env.horizon):  # no visit last time: free to change again
        env.step(np.array([0.0, 1.0]))
        seen.add(env.mapping)
    assert len(seen) > 1


def test_message_follows_mapping_and_goal():
    env = make_task("speaker-listener").unwrapped
    for seed in range(20):
        obs, _ = env.reset(seed=seed)
        assert int(np.argmax(obs[2:5])) == MAPPINGS[env.mapping][env.goal]


def test_stabilizing_policy_keeps_mapping_and_oracle_is_near_optimal():
    env = make_task("speaker-listener")
    stab = run_interactions(env, scripted_policy(env, "stabilizing"), 200, seed=0)
    assert np.mean([not s.strategy_changed for s in stab[1:]]) >= 0.99
    env = make_task("speaker-listener")
    orc = run_interactions(env, scripted_policy(env, "oracle"), 50, seed=0)
    env = make_task("speaker-listener")
    rnd = run_interactions(env, scripted_policy(env, "random"), 50, seed=0)
    oracle_mean = np.mean([s.task_reward for s in orc])
    assert oracle_mean > -7.5  # 10 steps to any goal from the centre
    assert (
        oracle_mean > np.mean([s.task_reward for s in stab]) > np.mean([s.task_reward for s in rnd])
    )


@pytest.mark.parametrize("mapping", range(len(MAPPINGS)))
def test_the_scripted_listener_reaches_the_goal_under_every_mapping(mapping):
    """The references (and the bounds built on them) decode the speaker's message through the
    mapping the right way round: the two 3-cycles are each other's inverse."""
    env = make_task("speaker-listener")
    task, policy = env.unwrapped, scripted_policy(env, "stabilizing")
    obs, _ = env.reset(seed=0, options={"strategy": mapping})
    for _ in range(task.horizon):
        obs, *_ = env.step(policy(env, obs))
    assert np.linalg.norm(task.position - GOALS[task.goal]) < 0.15


def test_the_v0_mapping_changes_within_an_interaction_but_not_after_its_last_step():
    """Unvisited, v0's mapping may change before each step and at the boundary (each with
    probability 0.5), never after the last step: the next interaction's change is the
    boundary's alone."""
    env = make_task("speaker-listener-v0")
    env.reset(seed=0)
    h = env.unwrapped.horizon
    after_last, at_boundary = [], []
    for _ in range(400):
        for _ in range(h):
            *_, info = env.step(np.zeros(2, np.float32))
        after_last.append(info["strategy_changed"])
        _, info = env.reset()
        at_boundary.append(info["strategy_changed"])
    assert not any(after_last)
    assert 0.44 < np.mean(at_boundary) < 0.56


def test_every_goal_is_drawn_about_a_third_of_the_time():
    env = make_task("speaker-listener").unwrapped
    env.reset(seed=0)
    goals = [env.goal]
    for _ in range(299):
        env.reset()
        goals.append(env.goal)
    counts = np.bincount(goals, minlength=len(GOALS))
    assert counts.min() > 0.25 * len(goals), counts


def test_the_listener_stays_in_the_arena():
    env = make_task("speaker-listener").unwrapped
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an observation outside its space warns
        for _ in range(env.horizon):
            obs, *_ = env.step(np.array([1.0, 1.0]))
    assert np.all(np.abs(env.position) <= ARENA)
    np.testing.assert_allclose(obs[:2], env.position)


def _v0_mappings(env, steps):
    """The mapping after each of ``steps`` steps away from the speaker."""
    out = []
    for _ in range(steps):
        env.step(np.array([0.0, 1.0]))
        out.append(env.mapping)
    return out


def _visit_for_an_interaction(env):
    env.position = SPEAKER.copy()
    for _ in range(env.horizon):
        env.step(np.zeros(2))


def test_a_seeded_restart_forgets_a_visit_of_the_previous_game():
    fresh = make_task("speaker-listener-v0").unwrapped
    fresh.reset(seed=7)
    expected = _v0_mappings(fresh, fresh.horizon)
    env = make_task("speaker-listener-v0").unwrapped
    env.reset(seed=0)
    _visit_for_an_interaction(env)
    env.reset()  # the visit locks this interaction's mapping ...
    env.reset(seed=7)  # ... but a seeded reset starts a new game
    assert _v0_mappings(env, env.horizon) == expected


def test_a_saved_v0_game_keeps_the_lock_a_visit_earned():
    env = make_task("speaker-listener-v0").unwrapped
    env.reset(seed=1)
    _visit_for_an_interaction(env)
    env.reset()
    saved = env.game_state()
    expected = _v0_mappings(env, env.horizon)
    fresh = make_task("speaker-listener-v0").unwrapped
    fresh.restore_game_state(saved)
    assert _v0_mappings(fresh, fresh.horizon) == expected


def test_on_v1_a_visit_locks_only_its_own_interaction():
    env = make_task("speaker-listener").unwrapped  # the interaction rule
    env.reset(seed=0)
    env.position = env.speaker.copy()
    env.step(np.zeros(2))
    assert env.locked
    for _ in range(env.horizon - 1):
        env.step(np.zeros(2))
    env.reset()
    env.step(np.array([0.0, 1.0]))
    assert not env.visited_now and not env.locked  # it may change at the next boundary


def test_the_blind_policy_does_not_read_the_true_mapping():
    """Blind decodes the message with the mapping the last interaction revealed: were it to
    read the true one, its reference bound would be an oracle's."""
    env = make_task("speaker-listener")
    policy = scripted_policy(env, "blind")
    obs, _ = env.reset(seed=0)
    before = policy(env, obs)
    message = int(np.argmax(obs[2:5]))
    env.unwrapped.mapping = next(
        m for m in range(len(MAPPINGS)) if MAPPINGS[m].index(message) != MAPPINGS[0].index(message)
    )
    np.testing.assert_array_equal(policy(env, obs), before)


def test_revealed_is_the_previous_interactions_last_strategy_and_none_after_a_restart():
    env = make_task("speaker-listener-v0").unwrapped  # the mapping changes within interactions
    revealed = Revealed()
    env.reset(seed=0)
    for _ in range(env.horizon):
        revealed(env)
        env.step(np.array([0.0, 1.0]))
    last = env.mapping
    env.reset()
    assert revealed(env) == last  # where the interaction ended, not where it began
    for _ in range(3):
        env.step(np.zeros(2))
        revealed(env)
    env.reset(seed=5)
    assert revealed(env) is None  # a new game reveals nothing yet


def test_an_interactions_end_strategy_is_the_one_after_its_last_step():
    """On v0 the mapping changes within interactions: the summary's end strategy is where it
    ended (what the next interaction reveals), not where it began."""
    env = make_task("speaker-listener-v0")
    horizon = env.unwrapped.horizon
    seen = []
    summaries = run_interactions(
        env,
        lambda e, o: np.zeros(2, np.float32),
        40,
        seed=0,
        on_step=lambda *step: seen.append(step[-1]["strategy_id"]),
    )
    ends = [seen[(j + 1) * horizon - 1] for j in range(40)]
    assert [s.end_strategy_id for s in summaries] == ends
    assert any(s.end_strategy_id != seen[j * horizon] for j, s in enumerate(summaries))


def test_the_speaker_may_stand_on_the_arenas_edge_but_not_beyond():
    env = SpeakerListenerEnv(speaker=(ARENA, -ARENA))
    np.testing.assert_array_equal(env.speaker, [ARENA, -ARENA])
    env.reset(seed=0)
    env.step(np.zeros(2))
    with pytest.raises(ConfigError, match=r"speaker must be an \(x, y\) position in the arena"):
        SpeakerListenerEnv(speaker=(0.0, -ARENA - 1e-9))


def test_a_visit_counts_on_the_visit_circle_itself_and_not_beyond():
    env = make_task("sili/SpeakerListener-v0").unwrapped
    env.reset(seed=0)
    env.position = SPEAKER + np.array([VISIT_RADIUS, 0.0])  # exactly 0.3 away (no rounding)
    assert np.linalg.norm(env.position - SPEAKER) == VISIT_RADIUS
    env.step(np.zeros(2))
    assert env.visited_now and env.locked
    env.reset(seed=0)
    env.position = SPEAKER + np.array([VISIT_RADIUS + 1e-6, 0.0])
    env.step(np.zeros(2))
    assert not env.visited_now
