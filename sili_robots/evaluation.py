"""Running a trained agent: evaluation without exploration, and policies for previews.

A trained agent continues the repeated game it was trained in (restored from the checkpoint),
so its latents and the opponent's strategy carry on where training left them.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import EnvSpec

from sili_robots.agent import SILIAgent
from sili_robots.build import (
    build_agent,
    make_run_env,
    observed_as,
    same_task_arguments,
    same_task_version,
    task_kwargs_of,
    task_name_of,
    task_version_of,
)
from sili_robots.errors import (
    CheckpointMismatch,
    ConfigError,
    CutInteractionWarning,
    check_count,
    compared,
)
from sili_robots.rollout import run_interactions
from sili_robots.runs import CHECKPOINT, CONFIG, RunConfig, read_config, require_checkpoint
from sili_robots.tasks.base import RESET_OPTIONS, resume_game


class AgentFeedback(gym.Wrapper):
    """Feeds each finished interaction back to the agent so z^{j+1} = E(tau^j) is inferred.

    The first ``reset`` continues the checkpointed game, unless it asks for another one: a
    ``seed``, or ``options`` ``restart``, ``strategy`` or ``restore`` (as every reset of the task
    does). In another game the agent starts as in a run's first interaction, with no history:
    the interactions of the game before are not its history. Without a checkpointed game, a
    first reset that gives no seed takes ``seed`` (a new model's game is its training's).
    """

    def __init__(
        self,
        env: gym.Env,
        agent: SILIAgent,
        game_state: dict[str, Any] | None,
        seed: int | None = None,
    ) -> None:
        """Play ``env`` with ``agent`` from ``game_state`` (``seed``: the first reset's without
        one)."""
        super().__init__(env)
        self.agent = agent
        self._game_state = game_state
        self._seed = seed
        self._steps: list[tuple[np.ndarray, np.ndarray, float]] = []
        self._first_obs: np.ndarray | None = None
        self._last_obs: np.ndarray | None = None
        self._first_info: dict[str, Any] = {}
        self._cut_told = False  # CutInteractionWarning given

    #: the wrapper made anew in place, as ``__init__`` takes it: a model's ``env`` stays the
    #: object a user holds when training replaces its agent
    rebind = __init__

    @property
    def spec(self) -> EnvSpec | None:
        """The task's: no spec can make this wrapper (it holds a live agent), so ``spec.make()``,
        as gymnasium's ``check_env`` calls it, makes the task alone."""
        return self.env.spec

    @property
    def continues_game(self) -> bool:
        """Whether the next reset, given no seed or other game, goes on with a trained game."""
        return self._game_state is not None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        options = kwargs.get("options") or {}
        if not isinstance(options, Mapping):  # the task refuses it, naming what it takes
            return self.env.reset(**kwargs)
        another = options.get("restart") or "strategy" in options or options.get("restore")
        another = another or set(options) - set(RESET_OPTIONS)  # the task names what it lacks
        if self._game_state is not None and not (another or kwargs.get("seed") is not None):
            obs, info = resume_game(self.env, self._game_state)
            self._game_state = None
        else:
            if kwargs.get("seed") is None and self._seed is not None:  # the first reset alone
                kwargs = {**kwargs, "seed": self._seed}
            obs, info = self.env.reset(**kwargs)
            self._seed = None
            self._game_state = None  # only once reset took it: a refused one keeps the game
            goes_on = info["interaction"] == self._first_info.get("interaction", -2) + 1
            if not goes_on:  # another game (restart, strategy, seed, restore): no history
                self.agent.begin_game(info)
            elif len(self._steps) == self.env.unwrapped.horizon:
                o = np.stack([self._first_obs, *[s[0] for s in self._steps]])
                a = np.stack([s[1] for s in self._steps])
                r = np.array([s[2] for s in self._steps], np.float32)
                self.agent.observe_interaction(
                    o,
                    a,
                    r,
                    obs,
                    float(self._first_info["strategy_id"]),
                    info,
                    refresh=False,
                )
            elif self._steps:  # cut short (none played: a reset after a reset, which gymnasium's
                self._warn_cut(len(self._steps))  # check_env makes, is no interaction to tell)
        self._steps, self._first_obs, self._first_info = [], obs, info
        self._last_obs = obs
        return obs, info

    def _warn_cut(self, steps: int) -> None:
        """Once per ``model.env``, and only to an agent that acts on a latent strategy."""
        if self._cut_told or not self.agent.n_latents:
            return
        self._cut_told = True
        warnings.warn(
            f"an interaction ended after {steps} of its {self.env.unwrapped.horizon} steps (a "
            "TimeLimit, or a reset before its end), so the agent's latent strategy does not "
            "follow it: the latent model encodes whole interactions; play each to its end (for "
            "shorter ones, train on the task built with horizon=N). Said once per model.env",
            CutInteractionWarning,
            stacklevel=2,
        )

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, r, term, trunc, info = self.env.step(action)
        space = self.env.action_space  # the agent learns from the action the task applied
        applied = np.clip(np.asarray(action, np.float32), space.low, space.high)
        self._steps.append((obs, applied, float(r)))
        self.agent.observe_step(self._last_obs, applied, float(r), obs)
        self._last_obs = obs
        return obs, r, term, trunc, info


def check_same_task(run_dir: Path, cfg: RunConfig, env: gym.Env) -> None:
    """ConfigError when the task instance ``env`` is another task (version) than the run's, or
    of another horizon: the run's game and agent are that task's (its other arguments, such as
    the controller, may differ)."""
    recorded = cfg.task_id or cfg.task
    if not same_task_version(recorded, task_version_of(env)):
        raise ConfigError(
            f"env is {task_version_of(env)}; the run in {run_dir} was trained on {recorded}: "
            "give an instance of that task (its arguments, such as the controller, may differ)"
        )
    check_played_horizon(run_dir, cfg, {"horizon": env.unwrapped.horizon}, "env")


@contextlib.contextmanager
def fitting(run_dir: Path, cfg: RunConfig, env: gym.Env | None) -> Iterator[None]:
    """Name both sides when the run's networks or stored interactions do not fit ``env``, a
    task instance of other sizes (observation, action, horizon); ``None``: the run's own, which
    its checkpoint fits unless it came from another run."""
    try:
        yield
    except CheckpointMismatch as err:
        if env is None or _is_the_runs_own(cfg, env):
            raise ConfigError(
                f"{run_dir / CHECKPOINT} does not fit the agent {run_dir / CONFIG} describes: "
                f"{err}; was it copied from another run? Train this run again (sili train ... "
                "--overwrite)"
            ) from None
        task = env.unwrapped
        sizes = (
            f"horizon {task.horizon}, observations {task.observation_space.shape}, actions "
            f"{task.action_space.shape}"
        )
        given = f"{task_name_of(env)} with {task_kwargs_of(env)} ({sizes})"
        raise ConfigError(
            f"env does not fit the run in {run_dir}, trained on {cfg.task} with "
            f"{cfg.env_kwargs}; env is {given}: give the task the run's horizon and sizes, or, "
            f"if it has them, {run_dir / CHECKPOINT} is another run's ({str(err).splitlines()[0]})"
        ) from None


def _is_the_runs_own(cfg: RunConfig, env: gym.Env) -> bool:
    """Whether ``env``, an instance of the run's task (``check_same_task``), was built with the
    run's own arguments (one at its default too): then a checkpoint that does not fit it does
    not fit the run's config."""
    try:
        return same_task_arguments(env, cfg.env_kwargs)
    except ConfigError:  # arguments it cannot record: not the run's
        return False


def load_trained(
    run_dir: Path, task_env: gym.Env | None = None
) -> tuple[RunConfig, gym.Env, SILIAgent, dict[str, Any]]:
    """Rebuild a run's env (or observe ``task_env``, the task instance, of the run's task) and
    agent from its config and last checkpoint (returned too: its ``game`` and ``interaction``)."""
    cfg = read_config(run_dir)
    state = require_checkpoint(run_dir)
    if task_env is not None:
        check_same_task(run_dir, cfg, task_env)
    with fitting(run_dir, cfg, task_env):
        env = make_run_env(cfg, run_dir) if task_env is None else observed_as(task_env, cfg)
        agent = build_agent(cfg, env)
        agent.load_state_dict(state["agent"])
    return cfg, env, agent, state


def check_played_horizon(
    run_dir: Path, cfg: RunConfig, given: Mapping[str, Any], option: str
) -> None:
    """A trained run plays the horizon it was trained with: its networks and stored
    interactions are that long; said before anything loads, naming ``option``, where ``given``
    (the task arguments to play with) came from."""
    from sili_robots.tasks.registry import task_defaults

    if "horizon" not in given:
        return
    own = cfg.env_kwargs.get("horizon")
    if own is None:
        try:
            own = task_defaults(cfg.task_id or cfg.task).get("horizon")
        except ConfigError:  # a user's task (a class path): the checkpoint's check names sizes
            return
    if own is not None and given["horizon"] != own:
        raise ConfigError(
            f"{option} horizon={compared(given['horizon'])}: the run in {run_dir} was trained "
            f"with horizon {own}, and a trained run plays the horizon it was trained with"
        )


def policy_from_run(
    run_dir: Path,
) -> tuple[str, dict[str, Any], Callable[[gym.Env], tuple[gym.Env, Callable]]]:
    """(task version, env kwargs, make_policy) where ``make_policy(env)``, ``env`` an instance
    of the run's task (its own arguments or others: another controller), returns the env to step
    (the task as the method observes it, feeding the agent) and a deterministic
    ``policy(env, obs) -> action``; the task version is the gymnasium id the run trained on."""
    cfg = read_config(run_dir)

    def make_policy(env: gym.Env) -> tuple[gym.Env, Callable]:
        _, observed, agent, state = load_trained(run_dir, env)
        wrapped = AgentFeedback(observed, agent, state["game"])
        return wrapped, lambda _env, obs: agent.act(obs, deterministic=True)

    return cfg.task_id or cfg.task, dict(cfg.env_kwargs), make_policy


def evaluate(run_dir: Path, interactions: int, task_env: gym.Env | None = None) -> dict[str, Any]:
    """Mean task reward and fraction of interactions whose true strategy stayed the same (after
    the first, whose change training's last interaction caused; None for one interaction),
    acting deterministically (no exploration, no learning), from the checkpoint's interaction
    (``trained_interactions``); on ``task_env``, the task instance, when given (left open)."""
    interactions = check_count("interactions", interactions)
    if not isinstance(run_dir, str | Path):
        raise ConfigError(f"run_dir must be a run's folder, got {run_dir!r}")
    if task_env is not None and not isinstance(task_env, gym.Env):
        raise ConfigError(f"task_env must be a task instance (or None), got {task_env!r}")
    _, env, agent, state = load_trained(Path(run_dir), task_env)
    wrapped = AgentFeedback(env, agent, state["game"])
    try:
        summary = run_interactions(
            wrapped, lambda _env, obs: agent.act(obs, deterministic=True), interactions, seed=None
        )
    finally:
        if task_env is None:
            wrapped.close()
    kept = [not s.strategy_changed for s in summary[1:]]
    return {
        "interactions": interactions,
        "trained_interactions": int(state["interaction"]),
        "mean_task_reward": float(np.mean([s.task_reward for s in summary])),
        "fraction_strategy_unchanged": float(np.mean(kept)) if kept else None,
    }
