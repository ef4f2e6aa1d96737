"""The repeated-interaction contract shared by every task.

One gymnasium episode is one *interaction* of ``horizon`` steps. The opponent's hidden strategy
z^j is fixed within interaction j (unless a task documents otherwise) and moves by the task's
strategy dynamics T^z(z^{j+1} | z^j, tau^j) when ``reset()`` begins the next interaction. The
repeated game itself restarts only on ``reset(seed=...)`` or ``reset(options={"restart": True})``;
``reset(options={"strategy": z})`` restarts it with z^1 = z instead of a drawn one (one of
``strategy_choices()``, or any angle on the continuous circle), e.g. to average over the first
strategy exactly.

``info`` always carries the true strategy (``strategy``, ``strategy_id``), the interaction index
(``interaction``) and whether the true strategy changed since the previous step
(``strategy_changed``); none of it enters the observation. What a method may see beyond it
is added by wrappers (``sili_robots.wrappers``): ``OracleObservation`` appends
``strategy_encoding()``, ``StrategyFlag`` the partial-observation flag "the opponent's strategy
changed since the last step".
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import math
import numbers
import warnings
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sili_robots.errors import ConfigError, RenderModeRefused, check_count, check_flag, is_number

StrategyId = int | float
#: what ``reset(options=...)`` takes: restart the game, restore a saved one, start from z
RESET_OPTIONS = ("restart", "restore", "strategy")
#: what ``game_state()`` holds: the ``restore`` reset option takes it back
GAME_STATE_KEYS = ("fields", "rng", "interaction", "last_strategy_id")
#: the longest interaction a task takes (steps): far beyond the paper's (50), and small enough
#: that a slip (1e11) is named here, not met as a failed allocation of the history's arrays
LONGEST_HORIZON = 10_000


NO_FRAMES = "the tasks draw no frames; a task's scene is previewed with `sili preview TASK`"


class RepeatedInteractionEnv(gym.Env[np.ndarray, np.ndarray], ABC):
    """Base class: subclasses describe one interaction; this class runs the repeated game."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}
    #: size of ``strategy_encoding()``; subclasses set it.
    strategy_dim: ClassVar[int]
    #: bounds of ``strategy_encoding()`` (checked): the box of Oracle's observation.
    strategy_low: ClassVar[float] = 0.0
    strategy_high: ClassVar[float] = 1.0
    #: attributes that hold the opponent's strategy between interactions; with the RNG state
    #: they are what ``game_state()`` saves so a run can resume at an interaction boundary.
    game_state_fields: ClassVar[tuple[str, ...]] = ()
    #: constructor arguments that change how the task runs, not what it is (a simulator's
    #: interface): results given them are compared with, and bounded like, the default ones
    same_dynamics_arguments: ClassVar[frozenset[str]] = frozenset()
    #: constructor arguments that say which task it is (Circle's ``variant``): each registered
    #: name fixes them, so a run built by name cannot be another task under that name
    identity_arguments: ClassVar[frozenset[str]] = frozenset()
    #: constructor arguments an ablation varies (Sawyer-Reach's ``controller``): the outputs of
    #: ``rollout``, ``bounds``, ``eval`` and ``preview`` name them at their defaults too
    named_in_titles: ClassVar[tuple[str, ...]] = ()
    #: the arguments the instance was built with, by name (None when some have no name), so a
    #: run given an instance can record them and rebuild the same task
    init_kwargs: dict[str, Any] | None

    def __new__(cls, *args: Any, **kwargs: Any) -> RepeatedInteractionEnv:
        env = super().__new__(cls)
        kwargs.pop("render_mode", None)  # how it is shown, not which task: not recorded
        env.init_kwargs = _named_arguments(cls, args, kwargs)
        return env

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        init = cls.__dict__.get("__init__")
        if init is not None:
            if not cls.metadata.get("render_modes"):
                init = _taking_render_mode(init)
            cls.__init__ = _calling_base_init(init)  # type: ignore[method-assign]

    def __init__(self, horizon: int) -> None:
        if type(self).__init__ is RepeatedInteractionEnv.__init__:  # else once its own is done
            _check_strategy_dim(self)
        self.horizon = check_count("horizon", horizon, 1, LONGEST_HORIZON)
        self.interaction = -1  # index of the current interaction; -1 before the first reset
        self.t = 0
        self._trajectory: list[dict[str, Any]] = []
        self._started = False
        self._last_strategy_id: StrategyId | None = None
        self._changed_since_last_step = False
        self._warned_outside = False  # an observation outside the space: told once
        self.action_space = _checked_action_space(self._make_action_space())
        base = _checked_observation_space(self._base_observation_space())
        low, high = base.low.astype(np.float32), base.high.astype(np.float32)
        self.observation_space = spaces.Box(low, high)

    # ----------------------------------------------------------------- subclass hooks
    @abstractmethod
    def _make_action_space(self) -> spaces.Box:
        """The ego's action space: a flat Box in [-1, 1] (scale it in ``_apply_action``)."""

    @abstractmethod
    def _base_observation_space(self) -> spaces.Box:
        """What the ego sees, without oracle encoding or strategy flag: a flat Box."""

    @abstractmethod
    def _initial_strategy(self) -> None:
        """Draw z^1 with ``self.np_random`` when the repeated game (re)starts."""

    @abstractmethod
    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        """Apply T^z: move to z^{j+1} given the finished interaction's trajectory (short, or
        empty, when ``reset`` comes before the interaction's last step, or before its first)."""

    @abstractmethod
    def _begin_interaction(self) -> None:
        """Reset the ego (and any per-interaction state) at the start of an interaction."""

    @abstractmethod
    def _apply_action(self, action: np.ndarray) -> float:
        """Advance one step under ``action`` (already validated); return the task reward."""

    @abstractmethod
    def _base_observation(self) -> np.ndarray:
        """The ego's observation (no privileged information)."""

    @abstractmethod
    def strategy_id(self) -> StrategyId:
        """A number naming the current true strategy (ids equal within 1e-9 = the same
        strategy): a category's index, or the continuous strategy itself."""

    @abstractmethod
    def strategy_encoding(self) -> np.ndarray:
        """A fixed-size vector encoding of the true strategy (what Oracle observes)."""

    def _step_record(self) -> dict[str, Any]:
        """What the strategy dynamics may read about one step; subclasses may extend."""
        return {}

    def _within_interaction_update(self) -> None:
        """Hook for strategies that may change between timesteps (e.g. Speaker-Listener)."""

    def strategy_choices(self) -> list[StrategyId] | None:
        """Every strategy a game can start from, when there are finitely many (else ``None``);
        ``strategy_id()`` is checked to be one of them."""
        return None

    def _set_strategy(self, strategy: StrategyId) -> None:
        """Make ``strategy`` (already checked) the current one; tasks that allow a chosen first
        strategy override this (``_check_start`` refuses the rest)."""
        raise NotImplementedError

    def _choices(self) -> list[StrategyId] | None:
        """``strategy_choices()``, checked: None or numbers (an id is a number)."""
        choices = self.strategy_choices()
        if choices is None:
            return None
        try:
            listed = list(choices)  # a range or an array too
        except TypeError:
            listed = []
        if not listed or not all(is_number(c) and _finite(c) for c in listed):
            raise ConfigError(
                f"{type(self).__name__}.strategy_choices() returned {choices!r:.80}; it must "
                "return None or a list of finite numbers (the ids strategy_id() returns)"
            )
        return listed

    def _check_start(self, strategy: Any) -> StrategyId:
        """The task's own value of a chosen first strategy (the choice it equals, within
        rounding), refusing one this task cannot start from before ``reset`` changes anything,
        so a refused reset leaves the game as it was."""
        if type(self)._set_strategy is RepeatedInteractionEnv._set_strategy:
            raise ConfigError(
                f"{type(self).__name__} cannot start from a chosen strategy (a task that can "
                "overrides _set_strategy, and strategy_choices when its strategies are few)"
            )
        choices = self._choices()
        matched = None
        number = isinstance(strategy, (int, float, np.number)) and not isinstance(strategy, bool)
        with contextlib.suppress(OverflowError):  # an int beyond a float's range matches none
            if number and choices is None:
                matched = float(strategy) if math.isfinite(strategy) else None
            elif number:  # 0.9999999999 starts from 1, not from int(0.9999999999)
                matched = next((c for c in choices if _same(strategy, c)), None)
        if matched is None:
            allowed = "any finite number" if choices is None else ", ".join(map(str, choices))
            raise ConfigError(f"unknown strategy {strategy!r}; allowed: {allowed}")
        return matched

    # ----------------------------------------------------------------- gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if options is not None and not isinstance(options, Mapping):
            raise ConfigError(
                f"reset options must be a dict (keys {', '.join(RESET_OPTIONS)}), got "
                f"{type(options).__name__}"
            )
        options = dict(options or {})
        unknown = set(options) - set(RESET_OPTIONS)
        if unknown:
            raise ConfigError(
                f"unknown reset options {sorted(unknown)}; allowed: {list(RESET_OPTIONS)}"
            )
        start = self._check_start(options["strategy"]) if "strategy" in options else None
        if options.get("restart") is not None:
            check_flag("reset option restart", options["restart"])
        if options.get("restore") is not None:
            self._check_game_state(options["restore"])
            ignored = [f"seed={seed}"] if seed is not None else []
            ignored += ["strategy"] if "strategy" in options else []
            ignored += ["restart=True"] if options.get("restart") else []
            if ignored:  # each would start another game than the saved one
                raise ConfigError(
                    f"reset option restore continues the saved game as it was: give it alone, "
                    f"not with {' and '.join(ignored)}"
                )
        if not self._started and self.spec is not None and self.spec.id.startswith("sili/"):
            from sili_robots.tasks.registry import check_identity

            check_identity(self.spec.id, self.spec.kwargs)  # gym.make(id, variant=another)
        before = self._game_before_reset()
        try:
            return self._reset(seed, options, start)
        except BaseException:  # e.g. a simulator that would not start: the game is as it was
            self._roll_back(before)
            raise

    #: what ``reset`` changes besides the task's ``game_state_fields`` and the generator's state
    #: (a task adds what its ``_begin_interaction`` clears that the next T^z reads)
    RESET_CHANGES: ClassVar[tuple[str, ...]] = (
        "interaction",
        "t",
        "_trajectory",
        "_started",
        "_last_strategy_id",
        "_changed_since_last_step",
        "_boundary_state",
        "_np_random",
        "_np_random_seed",
    )

    def _game_before_reset(self) -> tuple[dict[str, Any], Any]:
        names = (*self.RESET_CHANGES, *self.game_state_fields)
        kept = {k: _copy(getattr(self, k)) for k in names if hasattr(self, k)}
        rng = kept.get("_np_random")
        return kept, None if rng is None else rng.bit_generator.state

    def _roll_back(self, before: tuple[dict[str, Any], Any]) -> None:
        kept, rng_state = before
        for name in (*self.RESET_CHANGES, *self.game_state_fields):
            if name in kept:
                setattr(self, name, kept[name])
            elif hasattr(self, name):
                delattr(self, name)
        if rng_state is not None:  # its draws moved the same generator on
            self._np_random.bit_generator.state = rng_state

    def _reset(
        self, seed: int | None, options: dict[str, Any], start: StrategyId | None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if options.get("restore") is not None:
            return self._restore_game_state(options["restore"])
        restart = (
            seed is not None
            or bool(options.get("restart", False))
            or "strategy" in options
            or not self._started
        )
        if restart:
            self.interaction = 0
            self._initial_strategy()  # drawn even when chosen: the generator moves on the same
            if start is not None:
                self._set_strategy(start)
            self._last_strategy_id = None
            self._started = True
        else:
            self._advance_strategy(self._trajectory)
            self.interaction += 1
        self._trajectory = []
        self.t = 0
        self._boundary_state = self._capture_game_state()
        self._begin_interaction()
        sid = self._checked_strategy()
        if start is not None and self._choices() is not None and not _same(sid, start):
            raise ConfigError(
                f"{type(self).__name__}._set_strategy({start!r}) left strategy_id() at {sid!r}; "
                f"it must make {start!r} the current strategy"
            )
        self._boundary_state["strategy_id"] = sid
        self._changed_since_last_step = self._last_strategy_id is not None and not _same(
            sid, self._last_strategy_id
        )
        self._last_strategy_id = sid
        return self._observation(), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if self.t >= self.horizon:
            raise RuntimeError(
                f"interaction {self.interaction} already ended after {self.horizon} steps; "
                "call reset() to begin the next interaction"
            )
        action = self._validate_action(action)
        returned = self._apply_action(action)
        try:
            reward = float(returned)
        except (TypeError, ValueError):
            reward = math.nan  # refused below, naming what came back
        if not math.isfinite(reward):  # else met as a diverged training, blamed on its settings
            raise ConfigError(
                f"{type(self).__name__}._apply_action() returned reward {returned!r} "
                f"(interaction {self.interaction}, step {self.t + 1}): a task's reward is one "
                "finite number"
            )
        self.t += 1
        record = {"t": self.t, "reward": reward, **self._step_record()}
        self._trajectory.append(record)
        self._within_interaction_update()
        sid = self.strategy_id()
        try:
            self._changed_since_last_step = not _same(sid, self._last_strategy_id)
        except (TypeError, ValueError, OverflowError):  # no number: named just below
            self._changed_since_last_step = True
        if self._changed_since_last_step:  # within the interaction (Speaker-Listener v0)
            sid = self._checked_strategy()
        self._last_strategy_id = sid
        truncated = self.t >= self.horizon
        return self._observation(), reward, False, truncated, self._info()

    # ----------------------------------------------------------------- resumable games
    def _capture_game_state(self) -> dict[str, Any]:
        missing = [k for k in self.game_state_fields if not hasattr(self, k)]
        if missing:  # else an AttributeError from here, at the first reset
            raise ConfigError(
                f"{type(self).__name__}.game_state_fields names {', '.join(missing)}, which it "
                "does not have after its reset; name the attributes that hold the opponent's "
                "strategy"
            )
        return {
            "fields": {k: _copy(getattr(self, k)) for k in self.game_state_fields},
            "rng": self.np_random.bit_generator.state,
            "interaction": self.interaction,
            "last_strategy_id": self._last_strategy_id,
        }

    def game_state(self) -> dict[str, Any]:
        """The repeated game's state at the start of the current interaction (picklable).

        Valid right after ``reset()``; ``restore_game_state`` in a fresh env of the same kind
        then continues the game exactly as this one would have.
        """
        if not self._started:
            raise RuntimeError("call reset() before game_state()")
        return dict(self._boundary_state)

    def restore_game_state(self, state: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        """Continue a saved game: start its current interaction again; returns reset's output
        (it is ``reset(options={"restore": state})``: a refused game leaves this one as it was)."""
        self._check_game_state(state)  # None too: reset takes a restore of None for none asked
        return self.reset(options={"restore": state})

    def _restore_game_state(self, state: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
        if not self._started:
            self.reset(seed=0)
        for name, saved in state["fields"].items():  # against a started game's values, not
            required = _unfit(getattr(self, name, None), saved)  # a fresh task's placeholders
            if required is not None:
                raise ConfigError(
                    f"a saved game's field {name} must be {required}, as {type(self).__name__}'s "
                    f"is, got {saved!r}"
                )
        self.np_random.bit_generator.state = state["rng"]
        for k, v in state["fields"].items():
            setattr(self, k, _copy(v))
        choices = self._choices()
        if choices is not None and not any(_same(self.strategy_id(), c) for c in choices):
            raise ConfigError(  # before the scene is set up for it (an index out of its range)
                f"a saved game's fields {dict(state['fields'])} give strategy "
                f"{self.strategy_id()!r}; {type(self).__name__}'s strategies are "
                f"{', '.join(map(str, choices))}"
            )
        self.interaction = int(state["interaction"])
        self._trajectory = []
        self.t = 0
        self._boundary_state = self._capture_game_state()
        self._begin_interaction()
        sid = self._checked_strategy()
        saved = state.get("strategy_id")  # absent from games saved before it was kept
        if saved is not None and not _same(sid, saved):
            raise ConfigError(
                f"{type(self).__name__} did not restore its saved game: strategy {saved} came "
                f"back as {sid}; the saved game's fields disagree with its strategy_id (an edited "
                f"save), or game_state_fields {self.game_state_fields} miss an attribute that "
                "holds the opponent's strategy between interactions"
            )
        self._boundary_state["strategy_id"] = sid
        prev = state["last_strategy_id"]
        self._changed_since_last_step = prev is not None and not _same(sid, prev)
        self._last_strategy_id = sid
        return self._observation(), self._info()

    def _check_game_state(self, state: Any) -> None:
        """A saved game is what ``game_state()`` returns, checked whole before any of it is set."""
        fields = state.get("fields") if isinstance(state, Mapping) else None
        whole = isinstance(fields, Mapping) and all(k in state for k in GAME_STATE_KEYS)
        if not whole or set(fields) - set(self.game_state_fields):
            raise ConfigError(
                f"a saved game must be what game_state() returns (keys {', '.join(GAME_STATE_KEYS)}"
                f"; fields among {', '.join(self.game_state_fields) or 'none'}), got "
                f"{type(state).__name__}"
                + (f" with keys {', '.join(map(str, state))}" if isinstance(state, Mapping) else "")
            )
        interaction = state["interaction"]
        if not (is_number(interaction) and math.isfinite(interaction)) or (
            int(interaction) != interaction or interaction < 0
        ):
            raise ConfigError(f"a saved game's interaction must be a count, got {interaction!r}")
        try:  # numpy checks a generator's state: on a new one, before this game's changes
            type(self.np_random.bit_generator)().state = state["rng"]
        except (TypeError, ValueError, KeyError, OverflowError) as err:
            raise ConfigError(f"a saved game's rng is not this generator's state: {err}") from None

    def render(self) -> None:
        """No frames (gymnasium's ``render``): ``sili_robots.preview`` records a task's scene."""
        raise NotImplementedError(NO_FRAMES)

    # ----------------------------------------------------------------- helpers
    def _validate_action(self, action: Any) -> np.ndarray:
        arr = np.asarray(action, dtype=np.float64)
        shape = self.action_space.shape
        if arr.shape != shape:
            raise ConfigError(
                f"action must have shape {shape} (bounds {self.action_space.low.tolist()} to "
                f"{self.action_space.high.tolist()}), got shape {arr.shape}"
            )
        if not math.isfinite(sum(arr.tolist())) and not np.all(np.isfinite(arr)):  # 0.2 us first
            raise ConfigError(f"action must be finite, got {arr.tolist()}")
        # outside the box: clipped to it, as gymnasium's ClipAction (a policy's noise may cross it)
        return np.clip(arr, self.action_space.low, self.action_space.high)

    def _checked_strategy(self) -> StrategyId:
        """``strategy_id()``, checked with ``strategy_encoding()`` against what the class
        declares (a task's own mistake, else met deep in the agent's buffers)."""
        name, sid = type(self).__name__, self.strategy_id()
        if isinstance(sid, bool) or not isinstance(sid, (int, float, np.integer, np.floating)):
            raise ConfigError(f"{name}.strategy_id() returned {sid!r}; it must be a number")
        if not _finite(sid):  # else written to metrics.csv, which then reads as damaged
            raise ConfigError(f"{name}.strategy_id() returned {sid!r}; it must be finite")
        choices = self._choices()
        if choices is not None and not any(_same(sid, c) for c in choices):
            raise ConfigError(  # else a saved game at it could not be resumed
                f"{name}.strategy_id() returned {sid!r}, not one of its strategy_choices(): "
                f"{', '.join(map(str, choices))}"
            )
        encoding = np.asarray(self.strategy_encoding(), float)
        if encoding.shape != (self.strategy_dim,):
            raise ConfigError(
                f"{name}.strategy_encoding() returned shape {encoding.shape}; its strategy_dim "
                f"is {self.strategy_dim}"
            )
        if not np.all((encoding >= self.strategy_low) & (encoding <= self.strategy_high)):
            raise ConfigError(  # Oracle's observation clips it: two strategies could look alike
                f"{name}.strategy_encoding() returned {encoding.tolist()}, outside its "
                f"strategy_low {self.strategy_low} to strategy_high {self.strategy_high}; set "
                "them to bound every strategy's encoding"
            )
        return sid

    def _observation(self) -> np.ndarray:
        obs = np.asarray(self._base_observation(), np.float32)
        space = self.observation_space
        if obs.shape != space.shape:  # a task's own mistake: numpy would broadcast or fail
            raise ConfigError(
                f"{type(self).__name__}._base_observation() returned shape {obs.shape}; its "
                f"observation_space has shape {space.shape}"
            )
        clipped = np.clip(obs, space.low, space.high)
        # two tests of ~0.1 us each, every step; what they let through is looked at closely
        if clipped.tobytes() != obs.tobytes() or not math.isfinite(sum(obs.tolist())):
            self._check_observation(obs, clipped)
        return clipped

    def _check_observation(self, obs: np.ndarray, clipped: np.ndarray) -> None:
        """ConfigError for a non-finite observation; a warning for one outside the space."""
        name, space = type(self).__name__, self.observation_space
        where = f"(interaction {self.interaction}, step {self.t})"
        if not np.all(np.isfinite(obs)):
            raise ConfigError(
                f"{name}._base_observation() returned {obs.tolist()} {where}: a task's "
                "observations must be finite"
            )
        if not self._warned_outside and not (clipped == obs).all():  # not merely -0.0 to 0.0
            self._warned_outside = True
            warnings.warn(
                f"{name}._base_observation() returned {obs.tolist()} {where}, outside its "
                f"observation_space ({space.low.tolist()} to {space.high.tolist()}); it is "
                "clipped to the space: widen _base_observation_space if such values are real",
                stacklevel=3,
            )

    def _info(self) -> dict[str, Any]:
        return {
            "strategy": np.asarray(self.strategy_encoding(), np.float32),
            "strategy_id": self.strategy_id(),
            "interaction": self.interaction,
            "t": self.t,
            "strategy_changed": bool(self._changed_since_last_step),
        }

    @property
    def time_fraction(self) -> float:
        """Elapsed fraction of the interaction, part of every task's observation."""
        return self.t / self.horizon


def _checked_observation_space(space: Any) -> spaces.Box:
    """``space`` if it is a flat Box: the agent's networks take a vector of numbers."""
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ConfigError(
            f"the observation space must be a flat gymnasium Box (shape (n,)), got {space!r}: "
            "return spaces.Box(low, high, (n,)) from _base_observation_space (flatten images, "
            "one-hot discrete values)"
        )
    return space


def _checked_action_space(space: Any) -> spaces.Box:
    """``space`` if it is a flat Box in [-1, 1]: every agent acts through a tanh policy (and
    uniform random actions) in [-1, 1], so other bounds would be silently mis-scaled or clipped."""
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ConfigError(
            f"the action space must be a flat gymnasium Box in [-1, 1], got {space!r}: return "
            f"spaces.Box(-1.0, 1.0, (n,), np.float32) from _make_action_space"
        )
    if not (np.all(space.low == -1.0) and np.all(space.high == 1.0)):
        raise ConfigError(
            f"the action space must be bounded by -1 and 1 (agents act through tanh), got low "
            f"{space.low.tolist()} and high {space.high.tolist()}: return spaces.Box(-1.0, 1.0, "
            f"{space.shape}, np.float32) and scale the action to your units in _apply_action"
        )
    return space


def _unfit(current: Any, saved: Any) -> str | None:
    """What a saved game's field must be to stand for the task's ``current`` value, when
    ``saved`` is not (None: it fits; a field of another type is the task's to read)."""
    if isinstance(current, (bool, np.bool_)):
        return None if isinstance(saved, (bool, np.bool_)) else "a bool"
    if isinstance(current, numbers.Integral):
        return None if isinstance(saved, numbers.Integral) and is_number(saved) else "an integer"
    if is_number(current):
        return None if is_number(saved) and math.isfinite(saved) else "a finite number"
    return None


def _copy(value: Any) -> Any:
    return value.copy() if isinstance(value, np.ndarray) else value


def _finite(x: float) -> bool:
    """``math.isfinite``, False for an int beyond a float's range (which it raises for)."""
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _same(a: StrategyId | None, b: StrategyId | None) -> bool:
    """Ids within 1e-9 (np.isclose with atol 1e-9, rtol 0, in plain floats: once a step)."""
    if a is None or b is None:
        return a is b
    x, y = float(a), float(b)
    return x == y or abs(x - y) <= 1e-9


def resume_game(env: gym.Env, state: dict[str, Any]) -> tuple[np.ndarray, dict[str, Any]]:
    """Restore a saved game through any wrappers (each sees a reset, as they require, and
    shapes the restored observation as it shapes any other)."""
    return env.reset(options={"restore": state})


def _taking_render_mode(init: Any) -> Any:
    """``init`` that also takes gymnasium's ``render_mode``: None (what many scripts pass) or
    one of the modes the class's ``metadata`` declares; the tasks here declare none, as they draw
    no frames. (A class that declares modes and has its own ``__init__`` takes it itself.)"""

    @functools.wraps(init)  # its signature stays the class's (inspect follows __wrapped__)
    def __init__(self: Any, *args: Any, render_mode: str | None = None, **kwargs: Any) -> None:
        modes = list(type(self).metadata.get("render_modes") or [])
        if render_mode is not None and render_mode not in modes:
            why = f"allowed: {', '.join(map(repr, [None, *modes]))}" if modes else NO_FRAMES
            raise RenderModeRefused(f"render_mode {render_mode!r}: {why}")
        init(self, *args, **kwargs)
        if render_mode is not None:
            self.render_mode = render_mode

    return __init__


def _calling_base_init(init: Any) -> Any:
    """``init`` that names a subclass whose ``__init__`` never called the base's, which sets up
    the spaces and the game (else an AttributeError far from the cause)."""

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        outermost = type(self).__init__ is __init__  # a parent's may run before the base's
        if outermost and "horizon" not in vars(self):
            raise ConfigError(
                f"{type(self).__name__}.__init__ did not call super().__init__(horizon), "
                "where a RepeatedInteractionEnv sets up its spaces and its game"
            )
        if outermost:  # a task may set it in its __init__, e.g. from its arguments
            _check_strategy_dim(self)

    return __init__


def _check_strategy_dim(env: RepeatedInteractionEnv) -> None:
    dim = getattr(env, "strategy_dim", None)
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ConfigError(
            f"{type(env).__name__}.strategy_dim is {dim!r}; a task sets it to the length of its "
            "strategy_encoding() (a count >= 1)"
        )


RepeatedInteractionEnv.__init__ = _taking_render_mode(RepeatedInteractionEnv.__init__)  # type: ignore[method-assign]


def _named_arguments(cls: type, args: tuple, kwargs: dict[str, Any]) -> dict[str, Any] | None:
    """``cls(*args, **kwargs)``'s constructor arguments by name; None if some are unnamed."""
    try:
        bound = inspect.signature(cls.__init__).bind(None, *args, **kwargs)
    except TypeError:
        return None  # the constructor raises its own error
    named: dict[str, Any] = {}
    for name, value in list(bound.arguments.items())[1:]:  # after self
        kind = bound.signature.parameters[name].kind
        if kind is inspect.Parameter.VAR_POSITIONAL:
            return None
        if kind is inspect.Parameter.VAR_KEYWORD:
            named.update(value)
        else:
            named[name] = value
    return named
