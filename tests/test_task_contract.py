"""The shared task contract, checked on every registered task."""

import functools
import math
import re
import warnings
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

from sili_robots.errors import ConfigError
from sili_robots.examples.two_doors import TwoDoorsEnv
from sili_robots.tasks import TASKS, RepeatedInteractionEnv, make_task
from sili_robots.tasks.circle import ARENA, RADIUS, CircleEnv
from sili_robots.wrappers import OracleObservation, StrategyFlag

LIGHT_TASKS = [n for n in TASKS if n.startswith(("circle", "speaker"))]


def _rollout(env, seed, interactions=6):
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    trace = [(obs.copy(), info["strategy_id"])]
    for j in range(interactions):
        if j:
            obs, info = env.reset()
            trace.append((obs.copy(), info["strategy_id"]))
        done = False
        while not done:
            obs, r, term, trunc, info = env.step(env.action_space.sample())
            trace.append((obs.copy(), r, info["strategy_id"]))
            done = term or trunc
    return trace


@pytest.mark.parametrize("name", [*LIGHT_TASKS, "two-doors"])
def test_check_env_passes(name):
    """Every light task, and the README's template task (a reset before any step is legal)."""
    for wrap in (lambda e: e, OracleObservation, StrategyFlag):
        env = wrap(TwoDoorsEnv() if name == "two-doors" else make_task(name).unwrapped)
        check_env(env, skip_render_check=True)
        env.close()


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_registered_with_gymnasium(name):
    spec = TASKS[name]
    env = gym.make(spec.gym_id)
    assert isinstance(env.observation_space, gym.spaces.Box)
    assert env.observation_space.dtype == np.float32
    env.close()


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_seed_reproduces_whole_repeated_game(name):
    a = _rollout(make_task(name), seed=3)
    b = _rollout(make_task(name), seed=3)
    c = _rollout(make_task(name), seed=4)
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, v)
    assert any(not np.array_equal(x[0], y[0]) for x, y in zip(a, c, strict=False))


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_episode_is_one_interaction_truncated_at_horizon(name):
    env = make_task(name)
    env.reset(seed=0)
    horizon = env.unwrapped.horizon
    for t in range(1, horizon + 1):
        _, _, term, trunc, info = env.step(env.action_space.sample())
        assert not term
        assert trunc == (t == horizon)
        assert info["interaction"] == 0
    _, info = env.reset()
    assert info["interaction"] == 1
    _, info = env.reset(options={"restart": True})
    assert info["interaction"] == 0


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_oracle_exposes_strategy_and_plain_does_not(name):
    plain = make_task(name).unwrapped
    oracle = OracleObservation(make_task(name).unwrapped)
    obs_p, _info_p = plain.reset(seed=1)
    obs_o, info_o = oracle.reset(seed=1)
    k = plain.strategy_dim
    assert obs_o.shape[0] == obs_p.shape[0] + k
    np.testing.assert_allclose(obs_o[-k:], info_o["strategy"], atol=1e-6)
    np.testing.assert_allclose(obs_o[:-k], obs_p)
    # The plain observation is the same whatever the strategy: it does not leak it.
    first = {}
    for seed in range(30):
        obs, info = make_task(name).unwrapped.reset(seed=seed)
        first.setdefault(info["strategy_id"], obs[:2].tolist())
    assert len(first) >= 2
    assert len({tuple(v) for v in first.values()}) == 1


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_a_chosen_first_strategy_within_rounding_starts_from_that_strategy(name):
    env = make_task(name).unwrapped
    for z in env.strategy_choices() or [1.0, 2.0]:
        for given in (z - 1e-10, np.int64(z) if float(z).is_integer() else np.float64(z)):
            _, info = env.reset(seed=0, options={"strategy": given})
            assert info["strategy_id"] == pytest.approx(z, abs=1e-9), given  # not int(0.99..) = 0


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_the_plain_observation_ends_with_t_over_h_and_the_same_play_sees_the_same_whatever_z(name):
    env = make_task(name).unwrapped
    actions = np.random.default_rng(0).uniform(-1, 1, (env.horizon, *env.action_space.shape))
    # Speaker-Listener: the speaker's message (a z-dependent utterance) is what the ego decodes
    shown = [0, 1, 5] if name.startswith("speaker") else slice(None)
    traces = []
    for z in env.strategy_choices() or [0.0, 2.0]:
        obs, _ = env.reset(seed=0, options={"strategy": z})
        trace = [obs]
        for t, action in enumerate(actions, 1):
            obs, *_ = env.step(action)
            assert obs[-1] == pytest.approx(t / env.horizon)
            trace.append(obs)
        traces.append(np.array(trace)[:, shown])
    assert len(traces) >= 2 and traces[0][0, -1] == 0.0
    for trace in traces[1:]:
        np.testing.assert_array_equal(trace, traces[0])


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_strategy_flag_is_last_element(name):
    env = StrategyFlag(make_task(name).unwrapped)
    flags = []
    for _ in range(8):  # random play ends inside, so the opponent moves on (Speaker-Listener:
        obs, info = env.reset(seed=0) if not flags else env.reset()  # the mapping may change)
        flags.append(obs[-1])
        assert obs[-1] == float(info["strategy_changed"])
        for _ in range(env.unwrapped.horizon):
            obs, _, _, _, info = env.step(env.action_space.sample())
            flags.append(obs[-1])
            assert obs[-1] == float(info["strategy_changed"])
    assert 1.0 in flags and 0.0 in flags  # the flag is raised, and only when z changed


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_a_new_game_begins_unchanged_whatever_strategy_it_starts_at(name):
    """A new game (a seed, a chosen start, a restart) has no earlier interaction to change
    from: its first interaction is never flagged, also after a game at another strategy."""
    env = make_task(name).unwrapped
    starts = []
    for seed in range(4):
        _, info = env.reset(seed=seed)
        starts.append(info["strategy_id"])
        assert not info["strategy_changed"]
        env.step(env.action_space.sample())
        for options in ({"strategy": 0}, {"restart": True}):
            _, info = env.reset(options=options)
            starts.append(info["strategy_id"])
            assert not info["strategy_changed"], options
            env.step(env.action_space.sample())
    assert len(set(starts)) > 1  # games at other strategies followed one another


def test_bad_arguments_are_named():
    with pytest.raises(ConfigError, match=r"'7'.*allowed: 3, 8, continuous, unequal"):
        CircleEnv(variant="7")
    with pytest.raises(
        ConfigError, match=r"circle-3 fixes variant='3' .*variant='7' is not allowed"
    ):
        make_task("circle-3", variant="7")
    with pytest.raises(ConfigError, match=r"horizon must be an integer in \[1, 10000\], got 0"):
        make_task("circle-3", horizon=0)
    with pytest.raises(ConfigError, match="unknown task 'nope'; allowed: circle-3"):
        make_task("nope")
    env = make_task("circle-3").unwrapped
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=r"shape \(2,\).*got shape \(3,\)"):
        env.step(np.zeros(3))
    # refused as an action, before it moves the ego (the NaN reward of a move would be
    # refused as not finite too, after the damage)
    position = env.position.copy()
    for bad in (np.nan, np.inf):
        with pytest.raises(ConfigError, match=r"action must be finite, got \["):
            env.step(np.array([bad, 0.0]))
    np.testing.assert_array_equal(env.position, position)
    with pytest.raises(ConfigError, match=r"takes no argument foo \(make_task\); its arguments: h"):
        make_task("circle-3", foo=1)  # gymnasium's own TypeError names neither
    assert make_task("circle-3", max_episode_steps=5, render_mode=None).spec.max_episode_steps == 5
    for wrapper in (OracleObservation, StrategyFlag):  # they read what only a task's info has
        with pytest.raises(ConfigError, match=f"{wrapper.__name__} wraps a sili task .* got <"):
            wrapper(gym.make("CartPole-v1"))
        stacked = gym.wrappers.FrameStackObservation(make_task("circle-3"), 2)  # [2, obs]
        with pytest.raises(ConfigError, match=f"{wrapper.__name__} appends to a flat .*Box"):
            wrapper(stacked)


@pytest.mark.parametrize("make", [make_task, lambda n: gym.make(TASKS[n].gym_id)])
def test_a_refused_first_reset_leaves_the_task_to_play(make):
    """gymnasium's checker (which the base class's own checks replace) took a refused first
    reset for a done one and failed every step after it."""
    env = make("circle-3")
    with pytest.raises(ConfigError, match="unknown strategy 9; allowed: 0, 1, 2"):
        env.reset(options={"strategy": 9})
    with pytest.raises(ConfigError, match=r"unknown strategy 1000+; allowed: 0, 1, 2"):
        env.reset(options={"strategy": 10**400})  # beyond a float, which numpy raised on
    continuous = make("circle-continuous")
    for given in (10**400, float("nan")):
        with pytest.raises(ConfigError, match=r"unknown strategy .*; allowed: any finite number"):
            continuous.reset(options={"strategy": given})
    continuous.reset(options={"strategy": 2**70})  # an int within a float's range is one
    env.reset(seed=0)
    for _ in range(3):
        assert env.step(np.zeros(2))[1] == pytest.approx(-1.0)


def test_a_reset_that_fails_midway_leaves_the_game_as_it_was(monkeypatch):
    """A task whose interaction cannot begin (Driving's SUMO refused a start) raises from
    ``reset`` after the game had moved on: the next reset must play the interaction it would
    have played, and ``step`` must not act on a half-begun one."""
    env = make_task("circle-3")
    task = env.unwrapped
    env.reset(seed=0)
    env.step(np.ones(2))
    twin = make_task("circle-3")  # the same game, never refused
    twin.reset(seed=0)
    twin.step(np.ones(2))

    def where():
        rng = task.np_random.bit_generator.state
        return task.location, task.t, task.interaction, task._trajectory, rng, task._started

    before = where()
    begin = task._begin_interaction

    def fails() -> None:
        raise RuntimeError("the simulator did not start")

    monkeypatch.setattr(task, "_begin_interaction", fails)
    for seed, options in ((None, None), (7, None), (None, {"strategy": 1})):
        with pytest.raises(RuntimeError, match="did not start"):
            env.reset(seed=seed, options=options)
        assert where() == before
    monkeypatch.setattr(task, "_begin_interaction", begin)
    for _ in range(3):  # it goes on as the game refused nothing goes on
        (obs, info), (twin_obs, twin_info) = env.reset(), twin.reset()
        np.testing.assert_array_equal(obs, twin_obs)
        assert info["interaction"] == twin_info["interaction"]
        assert info["strategy_id"] == twin_info["strategy_id"]
        env.step(np.zeros(2))  # inside the circle: the opponent moves on
        twin.step(np.zeros(2))
    fresh = CircleEnv("3")
    monkeypatch.setattr(fresh, "_begin_interaction", fails)
    with pytest.raises(RuntimeError, match="did not start"):
        fresh.reset(seed=0)
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        fresh.step(np.zeros(2))
    monkeypatch.setattr(
        fresh, "_begin_interaction", functools.partial(CircleEnv._begin_interaction, fresh)
    )
    assert fresh.reset()[1]["interaction"] == 0


def test_bad_reset_options_are_named_and_change_nothing():
    env = make_task("circle-3")
    env.reset(seed=0)
    env.step(np.ones(2))
    task = env.unwrapped
    saved = task.game_state()

    def where():
        return task.location, task.t, task.interaction, task.np_random.bit_generator.state

    before = where()
    for options, said in (
        (
            ["restart"],
            r"reset options must be a dict \(keys restart, restore, strategy\), got list",
        ),
        ({"restart": "no"}, "reset option restart must be True or False, got 'no'"),  # not truthy
        ({"restore": {"fields": {"location": 1}}}, r"a saved game must be what game_state\(\) "),
        ({"restore": "yes"}, r"returns \(keys fields, rng, interaction, last_strategy_id; fie"),
        ({"restore": {**saved, "interaction": -1}}, "interaction must be a count, got -1"),
        ({"restore": {**saved, "interaction": np.nan}}, "interaction must be a count, got nan"),
        ({"restore": {**saved, "fields": {"location": 0}, "rng": {}}}, "rng is not this"),
        ({"restore": {**saved, "rng": {**saved["rng"], "uinteger": 2**200}}}, "rng is not this"),
    ):
        for seed in (None, 123):  # a seed given too: the generator is not re-seeded first
            with pytest.raises(ConfigError, match=said):
                env.reset(seed=seed, options=options)
            assert where() == before, options
    env.reset(options={"restart": None})  # as not given
    saved = task.game_state()
    for seed, options, said in (
        (123, {}, "not with seed=123"),
        (None, {"strategy": 1}, "not with strategy"),
        (0, {"strategy": 1, "restart": True}, "not with seed=0 and strategy and restart=True"),
    ):
        before = where()
        with pytest.raises(ConfigError, match=f"restore continues the saved game .*{said}$"):
            env.reset(seed=seed, options={"restore": saved, **options})
        assert where() == before
    assert env.reset(options={"restore": saved, "restart": False})[1]["interaction"] == 1


def test_a_users_gymnasium_id_of_a_task_is_answered_with_its_class():
    gym.register("user/Doors-v0", entry_point="sili_robots.examples.two_doors:TwoDoorsEnv")
    try:
        with pytest.raises(
            ConfigError, match=r"your own task: give its class, sili_robots.examples.two_doors:Two"
        ):
            make_task("user/Doors-v0")
        with pytest.raises(ConfigError, match=r"\)$"):  # no hint for another kind of env
            make_task("Pendulum-v1")
        gym.register("user/Made-v0", entry_point=functools.partial(TwoDoorsEnv, horizon=5))
        with pytest.raises(ConfigError, match=r"\)$"):  # no class to name
            make_task("user/Made-v0")
    finally:
        del gym.registry["user/Doors-v0"]
        gym.registry.pop("user/Made-v0", None)


def test_task_arguments_take_numpy_numbers_their_printed_bounds_and_name_bad_ones():
    from sili_robots.tasks.speaker_listener import SpeakerListenerEnv

    assert CircleEnv(outside_margin=np.float32(0.25)).outside_margin == 0.25
    with pytest.raises(ConfigError, match=r"horizon must be an integer in .* got 100000000000"):
        CircleEnv(horizon=10**11)  # named here, not an allocation failure of a rollout
    with pytest.raises(ConfigError, match=r"outside_margin must be .*, got 2$"):
        CircleEnv(outside_margin=np.int64(2))  # an integer is named as one
    with pytest.raises(ConfigError, match=r"outside_margin must be .*, got 1000000000000\d+$"):
        CircleEnv(outside_margin=10**400)  # too large for a float, named all the same
    for not_numbers in ("ab", ("0.5", "1"), (True, 0.5), np.array(0.5)):  # numpy reads some
        with pytest.raises(ConfigError, match=r"speaker must be an \(x, y\) position .*got"):
            SpeakerListenerEnv(speaker=not_numbers)


def test_a_run_records_numpy_task_arguments_as_the_numbers_it_is_built_with():
    import json

    from sili_robots.build import make_run_config

    cfg = make_run_config("circle-3", "sac", env_kwargs={"outside_margin": np.float32(0.05)})
    recorded = json.loads(json.dumps(cfg.to_dict()))["env_kwargs"]  # config.json can hold it
    assert recorded == {"outside_margin": float(np.float32(0.05))}
    for unrecordable in (object(), {1: 2}, [{"a": {0.5: 1}}]):  # JSON would make 1 "1"
        with pytest.raises(ConfigError, match=r"cannot be recorded in config\.json"):
            make_run_config("circle-3", "sac", env_kwargs={"outside_margin": unrecordable})


@pytest.mark.parametrize("start_z", [0.86, np.float32(1.0), 1.1])
def test_sawyer_takes_the_start_heights_its_message_names(start_z):
    from sili_robots.tasks.sawyer_reach import START_Z_RANGE, SawyerReachEnv

    assert START_Z_RANGE == (0.86, 1.1)
    env = SawyerReachEnv(start_z=start_z)
    env.close()
    with pytest.raises(ConfigError, match=r"start_z must be a height in \[0.86, 1.1\] m, got 1.2"):
        SawyerReachEnv(start_z=1.2)
    # a numpy float is named as the number compared: float32's 1.1 is above 1.1
    with pytest.raises(ConfigError, match=r"got 1.100000023841858$"):
        SawyerReachEnv(start_z=np.float32(1.1))


def test_an_observation_of_another_shape_than_the_space_is_named():
    class Short(TwoDoorsEnv):
        def _base_observation(self):
            return np.zeros(1)  # the space says 2 values: numpy would broadcast it silently

    with pytest.raises(
        ConfigError,
        match=r"Short._base_observation\(\) returned shape \(1,\); its observation_space has "
        r"shape \(2,\)",
    ):
        Short().reset(seed=0)


def test_a_task_s_own_mistakes_are_named_where_they_are_made():
    """Non-finite values, a strategy the class does not declare and a missing base ``__init__``
    are named by the task's method, not met later in the agent or blamed on its settings."""

    class NaNObservation(TwoDoorsEnv):
        def _base_observation(self):
            return np.array([np.nan, self.time_fraction])

    class NaNReward(TwoDoorsEnv):
        def _apply_action(self, action):
            return float("nan")

    class WideEncoding(TwoDoorsEnv):
        def strategy_encoding(self):
            return np.zeros(3, np.float32)  # strategy_dim says 1

    class NamedStrategy(TwoDoorsEnv):
        def strategy_id(self):
            return "left"

    class NoBase(TwoDoorsEnv):
        def __init__(self):
            self.door = 1.0  # super().__init__ forgotten

    class DrawingNoBase(NoBase):  # a class with render modes takes render_mode itself
        metadata: ClassVar[dict] = {"render_modes": ["rgb_array"]}

        def __init__(self, render_mode=None):
            self.door = 1.0

    with pytest.raises(ConfigError, match=r"NaNObservation._base_observation\(\) returned \[nan"):
        NaNObservation().reset(seed=0)
    env = NaNReward()
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=r"returned reward nan \(interaction 0, step 1\)"):
        env.step(np.zeros(1))
    with pytest.raises(ConfigError, match=r"returned shape \(3,\); its strategy_dim is 1"):
        WideEncoding().reset(seed=0)
    with pytest.raises(ConfigError, match=r"strategy_id\(\) returned 'left'; it must be a number"):
        NamedStrategy().reset(seed=0)
    with pytest.raises(ConfigError, match=r"NoBase.__init__ did not call super\(\).__init__"):
        NoBase()
    with pytest.raises(ConfigError, match=r"DrawingNoBase.__init__ did not call super"):
        DrawingNoBase()

    class Helpers(TwoDoorsEnv):
        def __init__(self):
            self.note = "helpers only"

    class Both(Helpers):  # the base's __init__ called after a parent's that skips it
        def __init__(self):
            Helpers.__init__(self)
            TwoDoorsEnv.__init__(self)

    assert Both().note == "helpers only"


def test_a_tasks_strategy_and_reward_mistakes_are_named_where_they_are_made():
    """Each was let through and met later: a NaN id written to metrics.csv (then read as a
    damaged file), an id beyond strategy_choices() (a saved game at it refused on resume), an
    encoding beyond its bounds (Oracle's clipped observation alike for two strategies), a reward
    that is no number (a TypeError traceback), strategy_dim unset (an AttributeError)."""

    class Doors(TwoDoorsEnv):  # starts from a chosen door
        def strategy_choices(self):
            return [-1.0, 1.0]

        def _set_strategy(self, strategy):
            self.door = strategy

    class NaNId(Doors):
        def strategy_id(self):
            return float("nan") if self.door > 0 else self.door

    class BeyondChoices(Doors):
        def strategy_id(self):
            return 2 * self.door

    class WideEncoding(Doors):
        def strategy_encoding(self):
            return np.array([3 * self.door], np.float32)

    class StartsElsewhere(Doors):
        def _set_strategy(self, strategy):
            self.door = -strategy

    def init(self, horizon: int = 20) -> None:
        RepeatedInteractionEnv.__init__(self, horizon)
        self.door, self.x = 1.0, 0.0

    own = {k: v for k, v in vars(TwoDoorsEnv).items() if not k.startswith("__")}
    del own["strategy_dim"]  # never set
    NoDim = type("NoDim", (RepeatedInteractionEnv,), {**own, "__init__": init})

    assert Doors().reset(options={"strategy": 1.0})[1]["strategy_id"] == 1.0
    for cls, said in (
        (NaNId, r"NaNId.strategy_id\(\) returned nan; it must be finite"),
        (BeyondChoices, r"returned 2.0, not one of its strategy_choices\(\): -1.0, 1.0"),
        (WideEncoding, r"returned \[3.0\], outside its strategy_low -1.0 to strategy_high 1.0"),
        (StartsElsewhere, r"_set_strategy\(1.0\) left strategy_id\(\) at -1.0"),
    ):
        with pytest.raises(ConfigError, match=said):
            cls().reset(options={"strategy": 1.0})
    with pytest.raises(ConfigError, match=r"NoDim.strategy_dim is None; a task sets it"):
        NoDim()

    class Lettered(Doors):  # ids are numbers: a string failed deep in the comparison
        def strategy_choices(self):
            return ["left", "right"]

    class Misspelt(Doors):  # an AttributeError at the first reset
        game_state_fields = ("dor",)

    class Unbounded(Doors):  # an OverflowError of math.isfinite
        def strategy_choices(self):
            return [-1.0, 1.0, 10**400]

    class Arrayed(Doors):  # any sequence of numbers
        def strategy_choices(self):
            return np.array([-1.0, 1.0])

    assert Arrayed().reset(options={"strategy": -1.0})[1]["strategy_id"] == -1.0

    for cls, said in (
        (Lettered, r"strategy_choices\(\) returned \['left', 'right'\]; it must return None or"),
        (Misspelt, r"Misspelt.game_state_fields names dor, which it does not have after its re"),
        (Unbounded, r"Unbounded.strategy_choices\(\) returned \[-1.0, 1.0, 1000+.*; it must"),
    ):
        with pytest.raises(ConfigError, match=said):
            cls().reset(seed=0)

    class Huge(Doors):
        def strategy_id(self):
            return 10**400

    with pytest.raises(ConfigError, match=r"returned 1000+; it must be finite"):
        Huge().reset(seed=0)

    class NamedLater(Doors):  # a task whose strategy changes within an interaction
        label = None

        def _within_interaction_update(self):
            self.label = {2: 10**400, 3: "left"}.get(self.t)

        def strategy_id(self):
            return self.door if self.label is None else self.label

    env = NamedLater()
    env.reset(seed=0)
    env.step(np.zeros(1))
    with pytest.raises(ConfigError, match=r"returned 1000+; it must be finite"):
        env.step(np.zeros(1))
    with pytest.raises(ConfigError, match=r"returned 'left'; it must be a number"):
        env.step(np.zeros(1))

    class Sized(Doors):  # its size set from an argument, after the base's __init__
        strategy_dim = None

        def __init__(self, size: int = 1):
            super().__init__()
            self.strategy_dim = size

    assert Sized().strategy_dim == 1
    with pytest.raises(ConfigError, match=r"Sized.strategy_dim is 0; a task sets it"):
        Sized(0)
    for returned, said in ((None, "None"), (np.zeros(2), r"array\(\[0., 0.\]\)")):

        class Odd(Doors):
            def _apply_action(self, action, returned=returned):
                return returned

        env = Odd()
        env.reset(seed=0)
        with pytest.raises(ConfigError, match=rf"returned reward {said} \(interaction 0, step 1"):
            env.step(np.zeros(1))
    with pytest.raises(ConfigError, match=r"cannot start from a chosen strategy .*_set_strategy"):
        TwoDoorsEnv().reset(options={"strategy": 1.0})


def test_an_observation_outside_the_space_is_clipped_with_a_warning():
    class Narrow(TwoDoorsEnv):
        def _base_observation(self):
            return np.array([2 * self.x, self.time_fraction], np.float32)  # x reaches 2

    env = Narrow()
    env.reset(seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # Python's own filter would hide repeats of a text
        for _ in range(8):
            obs, *_ = env.step(np.ones(1))
    assert obs[0] == 1.0  # clipped to the space
    assert len(caught) == 1  # told once, not on each of the steps outside
    assert re.search(
        r"returned \[1.2.*\(interaction 0, step 3\), outside its observation_sp",
        str(caught[0].message),
    )


def test_an_action_space_other_than_minus_one_to_one_is_refused():
    """Agents act through tanh in [-1, 1]: a task with other bounds would be mis-scaled."""

    class Wide(TwoDoorsEnv):
        def _make_action_space(self):
            return spaces.Box(-2.0, 2.0, (1,), np.float32)

    class Choices(TwoDoorsEnv):
        def _make_action_space(self):
            return spaces.Discrete(3)

    with pytest.raises(
        ConfigError, match=r"bounded by -1 and 1 .*got low \[-2.0\] and high \[2.0\]"
    ):
        Wide()
    with pytest.raises(
        ConfigError, match=r"must be a flat gymnasium Box in \[-1, 1\], got Discrete\(3\)"
    ):
        Choices()
    assert TwoDoorsEnv().action_space == spaces.Box(-1.0, 1.0, (1,), np.float32)
    odd = [  # refused where the task is built, not by numpy or the networks later
        ("_make_action_space", spaces.Box(-1.0, 1.0, ()), "action space must be a flat"),
        ("_base_observation_space", spaces.Box(-1.0, 1.0, (2, 2)), "observation space .* flat"),
        ("_base_observation_space", spaces.Discrete(3), "observation space must be a flat"),
    ]
    for method, space, said in odd:
        task = type("Odd", (TwoDoorsEnv,), {method: lambda self, s=space: s})
        with pytest.raises(ConfigError, match=said):
            task()


def test_vector_env_steps():
    envs = gym.make_vec("sili/Circle3-v0", num_envs=2, vectorization_mode="sync")
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (2, 3)
    truncated_at = []
    for step in range(60):  # crosses an interaction boundary: autoreset begins the next one
        obs, _r, _term, trunc, info = envs.step(envs.action_space.sample())
        if trunc.any():
            truncated_at.append(step)
    assert obs.shape == (2, 3) and truncated_at == [49]  # H = 50
    # the next interaction of the same repeated game, not a new game: 9 steps into interaction 1
    assert info["interaction"].tolist() == [1, 1] and info["t"].tolist() == [9, 9]
    np.testing.assert_allclose(obs[:, -1], 9 / 50)
    envs.close()


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_game_state_resumes_the_repeated_game(name):
    env = make_task(name).unwrapped
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (8, env.horizon, 2))
    for j in range(3):
        for a in actions[j]:
            env.step(a)
        env.reset()
    saved = env.game_state()
    tail_a = []
    for j in range(3, 8):
        for a in actions[j]:
            tail_a.append(env.step(a)[:2])
        env.reset()
    fresh = make_task(name).unwrapped
    fresh.restore_game_state(saved)
    tail_b = []
    for j in range(3, 8):
        for a in actions[j]:
            tail_b.append(fresh.step(a)[:2])
        fresh.reset()
    for (oa, ra), (ob, rb) in zip(tail_a, tail_b, strict=True):
        np.testing.assert_array_equal(oa, ob)
        assert ra == rb


@pytest.mark.parametrize("name", LIGHT_TASKS)
def test_an_edited_saved_game_is_refused_by_name_and_the_game_goes_on_as_it_was(name):
    """A hand-edited save raised IndexError deep in the task, after the game had moved."""
    env, twin = make_task(name).unwrapped, make_task(name).unwrapped
    for e in (env, twin):
        e.reset(seed=3)
        for _ in range(e.horizon):
            e.step(_zeros(e))
    saved = env.game_state()
    for field in saved["fields"]:
        with pytest.raises(ConfigError, match=rf"saved game's field {field} must be .*, got 'x'"):
            env.restore_game_state({**saved, "fields": {**saved["fields"], field: "x"}})
    if env.strategy_choices() is not None:  # the field that holds the strategy, out of range
        field = next(k for k, v in saved["fields"].items() if v == env.strategy_id())
        with pytest.raises(ConfigError, match=r"give strategy 99; .*'s strategies are 0, 1, 2"):
            env.restore_game_state({**saved, "fields": {**saved["fields"], field: 99}})
    obs, info = env.reset()
    twin_obs, twin_info = twin.reset()
    np.testing.assert_array_equal(obs, twin_obs)
    assert (info["interaction"], info["strategy_id"]) == (1, twin_info["strategy_id"])


def test_restore_takes_no_none_and_a_placeholder_of_another_number_type():
    """restore_game_state(None) was a plain reset (the game went on unasked); a fresh task's
    placeholder (an int 1 for a door saved as -1.0) is no kind a saved game must have."""

    class IntPlaceholder(TwoDoorsEnv):
        def __init__(self, **kw):
            super().__init__(**kw)
            self.door = 1  # reset sets -1.0 or 1.0

    env = IntPlaceholder()
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="a saved game must be what game_state"):
        env.restore_game_state(None)
    env.door = -1.0
    saved = {**env.game_state(), "fields": {"door": -1.0}}
    saved.pop("strategy_id")
    assert IntPlaceholder().restore_game_state(saved)[1]["strategy_id"] == -1.0


def test_a_game_state_without_the_strategy_s_attributes_is_refused_on_restore():
    """A task that leaves its strategy out of ``game_state_fields`` resumed silently with
    another opponent; games saved before the strategy was kept still restore."""

    class Forgetful(TwoDoorsEnv):
        game_state_fields = ()

    env = Forgetful()
    env.reset(seed=0)
    for _ in range(env.horizon):
        env.step(np.zeros(1))  # stays in the middle: the opponent switches doors
    env.reset()
    saved = env.game_state()
    with pytest.raises(ConfigError, match=r"-?1.0 came back as -?1.0; .*game_state_fields"):
        Forgetful().restore_game_state(saved)
    legacy = {k: v for k, v in saved.items() if k != "strategy_id"}
    _, info = TwoDoorsEnv().restore_game_state({**legacy, "fields": {"door": env.door}})
    assert info["strategy_id"] == env.door


@pytest.mark.filterwarnings("ignore:.*render_mode=.rgb_array. that is not in the possible")
def test_render_mode_none_is_taken_and_any_mode_refused_by_every_task():
    """Training scripts pass render_mode=None (or their flag's value) to gym.make as a matter
    of course: it was a TypeError on every task."""
    for name in TASKS:
        if name == "driving":
            continue  # one libsumo simulation per process: built below, once
        env = gym.make(TASKS[name].gym_id, render_mode=None)
        assert env.reset(seed=0)[0].shape == env.observation_space.shape
        with pytest.raises(NotImplementedError, match="sili preview"):
            env.unwrapped.render()
        env.close()
    vec = gym.make_vec("sili/Circle3-v1", 2, render_mode=None)
    assert vec.reset(seed=0)[0].shape == (2, 3)
    vec.close()
    with pytest.raises(ConfigError, match="render_mode 'rgb_array': the tasks draw no frames"):
        gym.make("sili/Driving-v0", render_mode="rgb_array")
    assert TwoDoorsEnv(render_mode=None).init_kwargs == {}  # a user's task class too

    class Drawn(TwoDoorsEnv):  # declares a mode, with the constructor it inherits
        metadata: ClassVar[dict] = {"render_modes": ["rgb_array"]}

    assert Drawn(render_mode="rgb_array").render_mode == "rgb_array"
    with pytest.raises(ConfigError, match="render_mode 'human': allowed: None, 'rgb_array'"):
        Drawn(render_mode="human")


@pytest.mark.filterwarnings("ignore:.*render_mode=.rgb_array. that is not in the possible")
def test_stable_baselines3_make_vec_env_builds_the_tasks():
    """It asks for render_mode='rgb_array' and falls back on a TypeError only: every task
    failed there with the refusal, a ValueError."""
    from stable_baselines3.common.env_util import make_vec_env

    vec = make_vec_env("sili/Circle3-v1", n_envs=2, seed=0)
    assert vec.reset().shape == (2, 3)
    vec.close()


def test_gym_make_cannot_build_another_task_under_an_id():
    """gym.make("sili/Circle3-v1", variant="8") built Circle (8 Goals) whose spec said Circle
    (3 Goals); refused at its first reset, as make_task refuses it at once."""
    env = gym.make("sili/Circle3-v1", variant="8")
    with pytest.raises(ConfigError, match=r"circle-3 fixes variant='3'.*circle-8"):
        env.reset(seed=0)
    assert gym.make("sili/Circle3-v1", variant="3").reset(seed=0)[0].shape == (3,)


def _zeros(env: gym.Env) -> np.ndarray:
    return np.zeros(env.action_space.shape, env.action_space.dtype)


@pytest.mark.parametrize("task", LIGHT_TASKS)
def test_an_action_outside_the_box_acts_as_the_clipped_action(task):
    a, b = (make_task(task).unwrapped for _ in range(2))
    a.reset(seed=0)
    b.reset(seed=0)
    high = a.action_space.high
    signs = np.where(np.arange(high.size) % 2, -1.0, 1.0).reshape(high.shape)
    np.testing.assert_array_equal(a.step(5 * signs * high)[0], b.step(signs * high)[0])


@pytest.mark.parametrize("task", LIGHT_TASKS)
def test_no_step_after_the_horizon(task):
    env = make_task(task).unwrapped
    env.reset(seed=0)
    for _ in range(env.horizon):
        env.step(_zeros(env))
    with pytest.raises(RuntimeError, match="already ended after"):
        env.step(_zeros(env))


@pytest.mark.parametrize("task", LIGHT_TASKS)
def test_a_chosen_first_strategy_plays_the_game_a_drawn_one_does(task):
    """The first strategy is drawn even when chosen, so reset(seed, strategy=z) plays the game
    reset(seed) plays when it draws z."""
    a, b = (make_task(task).unwrapped for _ in range(2))
    _, info = a.reset(seed=3)
    b.reset(seed=3, options={"strategy": info["strategy_id"]})
    for j in range(3):
        if j:
            (obs_a, info_a), (obs_b, info_b) = a.reset(), b.reset()
            np.testing.assert_array_equal(obs_a, obs_b)
            assert info_a["strategy_id"] == info_b["strategy_id"]
        for _ in range(a.horizon):
            step_a, step_b = a.step(_zeros(a)), b.step(_zeros(b))
            np.testing.assert_array_equal(step_a[0], step_b[0])
            assert step_a[1] == step_b[1]  # the reward: where the opponent is


@pytest.mark.parametrize("task", LIGHT_TASKS)
def test_a_restored_game_reports_the_change_at_its_boundary(task):
    env = make_task(task).unwrapped
    _, info = env.reset(seed=0)
    for _ in range(50):
        for _ in range(env.horizon):
            env.step(_zeros(env))
        _, info = env.reset()
        if info["strategy_changed"]:
            break
    assert info["strategy_changed"]
    _, restored = make_task(task).unwrapped.restore_game_state(env.game_state())
    assert restored["strategy_changed"]


class _Overshooting(gym.ObservationWrapper):
    """A user's task whose observations leave the space it declares."""

    def observation(self, obs):
        return np.asarray(obs, np.float32) * 100.0


class _Reshaped(gym.ObservationWrapper):
    """The task's flat observation made another shape (a 0-D or 2-D Box)."""

    def __init__(self, env, shape):
        super().__init__(env)
        size, base = int(np.prod(shape)), env.observation_space
        self.shape = shape
        low, high = base.low[:size].reshape(shape), base.high[:size].reshape(shape)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

    def observation(self, obs):
        return np.asarray(obs, np.float32)[: int(np.prod(self.shape))].reshape(self.shape)


@pytest.mark.parametrize("wrap", [OracleObservation, StrategyFlag])
@pytest.mark.parametrize("shape", [(), (1, 2)])
def test_a_wrapper_refuses_an_observation_that_is_not_flat(wrap, shape):
    with pytest.raises(ConfigError, match=rf"{wrap.__name__} appends to a flat observation"):
        wrap(_Reshaped(TwoDoorsEnv(horizon=4), shape))


@pytest.mark.parametrize("wrap", [OracleObservation, StrategyFlag])
def test_wrapped_observations_stay_within_the_declared_space(wrap):
    env = wrap(_Overshooting(TwoDoorsEnv(horizon=4)))
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert env.observation_space.contains(env.step(env.action_space.sample())[0])


def test_restoring_a_game_saved_at_its_first_interaction_reports_no_change():
    env = make_task("circle-3").unwrapped
    _, first = env.reset(seed=0)
    saved = env.game_state()
    assert saved["last_strategy_id"] is None and first["strategy_changed"] is False
    fresh = make_task("circle-3").unwrapped
    _, info = fresh.restore_game_state(saved)
    assert info["strategy_changed"] is False
    assert info["interaction"] == 0 and info["strategy_id"] == first["strategy_id"]
    # a later boundary with an unchanged strategy: also no change
    env.position = np.array([0.0, 1.5])  # end outside: circle-3 holds its location
    for _ in range(env.horizon):
        env.step([0.0, 0.0])
    _, info = env.reset()
    later = env.game_state()
    _, restored = make_task("circle-3").unwrapped.restore_game_state(later)
    assert restored["strategy_changed"] is info["strategy_changed"] is False


def test_strategy_ids_are_the_same_within_1e_9_and_no_further():
    env = make_task("circle-3")
    _, info = env.reset(options={"strategy": 1 - 5e-10})  # rounding: it is 1
    assert info["strategy_id"] == 1
    with pytest.raises(ConfigError, match=r"unknown strategy 0.999999998; allowed: 0, 1, 2"):
        env.reset(options={"strategy": 1 - 2e-9})
    task = make_task("circle-continuous").unwrapped
    task.reset(seed=0, options={"strategy": 1.0})
    task.step(np.zeros(2))
    task.angle = 1.0 + 2e-9  # a (tiny) change of strategy within the interaction
    *_, info = task.step(np.zeros(2))
    assert info["strategy_changed"] is True
    assert math.isclose(info["strategy_id"], 1.0 + 2e-9)


def test_outside_margin_range_is_closed_at_zero_and_open_at_its_top():
    assert CircleEnv(outside_margin=0.0).outside_margin == 0.0
    assert CircleEnv(outside_margin=0.999).outside_margin == 0.999
    with pytest.raises(
        ConfigError, match=r"outside_margin must be a number in \[0, 1\) .*got 1\.0$"
    ):
        CircleEnv(outside_margin=ARENA - RADIUS)
    with pytest.raises(ConfigError, match=r"outside_margin must be"):
        CircleEnv(outside_margin=-1e-9)


def test_a_saved_game_with_a_field_the_task_does_not_save_is_refused():
    """A save naming an attribute outside game_state_fields (here the horizon) would have it
    set on the task by restore; it is no save this task wrote, and the game goes on as it was."""
    env = TwoDoorsEnv()
    env.reset(seed=0)
    saved = env.game_state()
    horizon = env.horizon
    with pytest.raises(ConfigError, match=r"a saved game must be what game_state\(\) returns"):
        env.restore_game_state({**saved, "fields": {**saved["fields"], "horizon": 1}})
    assert env.horizon == horizon
    env.step(np.zeros(1))
    assert env.t == 1


class CountingDoors(TwoDoorsEnv):
    """A user's task whose game keeps an array it moves on in place between interactions."""

    game_state_fields = ("door", "visits")

    def __init__(self, **kw):
        super().__init__(**kw)
        self.visits = np.zeros(2)
        self.fail_next_begin = False

    def _initial_strategy(self):
        super()._initial_strategy()
        self.visits = np.zeros(2)

    def _advance_strategy(self, trajectory):
        super()._advance_strategy(trajectory)
        self.visits += 1  # in place, as numpy code often does

    def _begin_interaction(self):
        if self.fail_next_begin:
            self.fail_next_begin = False
            raise RuntimeError("the simulator would not start")
        super()._begin_interaction()


def test_a_failed_reset_rolls_back_an_array_the_task_moved_on_in_place():
    env = CountingDoors()
    env.reset(seed=0)
    env.reset()
    before = env.visits.copy()
    env.fail_next_begin = True
    with pytest.raises(RuntimeError, match="would not start"):
        env.reset()
    np.testing.assert_array_equal(env.visits, before)
    assert env.reset()[1]["interaction"] == 2  # the game goes on from where it was
    np.testing.assert_array_equal(env.visits, before + 1)


def test_a_restored_game_leaves_the_saved_state_as_it_was():
    """Restoring the same save twice continues the same game: playing on from it never
    changes the save's arrays."""
    env = CountingDoors()
    env.reset(seed=0)
    env.reset()
    saved = env.game_state()
    kept = saved["fields"]["visits"].copy()
    fresh = CountingDoors()
    fresh.restore_game_state(saved)
    fresh.reset()
    fresh.reset()
    np.testing.assert_array_equal(saved["fields"]["visits"], kept)
    again = CountingDoors()
    again.restore_game_state(saved)
    np.testing.assert_array_equal(again.visits, kept)
