"""The one place that builds a run's environment and agent from its ``RunConfig``.

A task is a registered name or gymnasium id (``circle-3``, ``sili/Circle3-v1``) or a user's
own task class as ``package.module:ClassName`` (a ``RepeatedInteractionEnv`` subclass). The
method decides how the task is observed: Oracle through ``OracleObservation``, partial
observation (SILI and Stable with ``latent="partial"``) through ``StrategyFlag``.
"""

from __future__ import annotations

import inspect
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sili_robots.addons import build_addons
from sili_robots.addons.config import AddonsConfig
from sili_robots.agent import SILIAgent, method_config
from sili_robots.agent.config import AgentConfig, UnknownSetting, paths
from sili_robots.errors import ConfigError
from sili_robots.migrations import LEGACY_SETTINGS, setting_path
from sili_robots.plugins import class_path
from sili_robots.runs import CONFIG, RunConfig
from sili_robots.tasks import make_task, task_spec
from sili_robots.tasks.registry import (
    arguments_hint,
    check_argument_names,
    current_names_of_class,
    identity_conflict,
    is_class_path,
    same_argument,
    task_class,
)
from sili_robots.wrappers import OracleObservation, StrategyFlag


def canonical_task(task: str) -> str:
    """How a run records a task given by any of its names: the registered task's CLI name
    (``sili/Circle3-v1`` -> ``circle-3``), or a user's class path (checked), so runs of one
    task group together whichever name started them."""
    if is_class_path(task):
        task_class(task)
        return task
    try:
        return task_spec(task).name
    except ConfigError as err:
        raise ConfigError(
            f"{err}; or a task class of your own as package.module:ClassName"
        ) from None


def unversioned_note(task: str | type) -> str:
    """Why a packaged task's class (its path, or an instance's class) was most likely not
    meant: it trains with the class's defaults, which need not be any version's, and records
    no version; "" for any other task."""
    if isinstance(task, str):
        if not is_class_path(task):
            return ""
        task = task_class(task)
    names = current_names_of_class(task)
    if not names:
        return ""
    return (
        f"{task.__name__} built from its class trains with the class's own defaults, which need "
        "not be any task version's, and records no version (nor a version's bounds and scene); "
        f"give a task name instead, or build it with make_task(NAME): {', '.join(names)}"
    )


#: the wrappers ``gym.make`` adds, which change nothing a run records
_NEUTRAL_WRAPPERS = (gym.wrappers.OrderEnforcing, gym.wrappers.PassiveEnvChecker)


def check_recordable(env: gym.Env) -> None:
    """A run records a task instance by its name and arguments, and is rebuilt from them; a
    wrapper around it (changing what the agent sees or does) would silently be lost."""
    layer = env
    while isinstance(layer, gym.Wrapper):
        if not isinstance(layer, _NEUTRAL_WRAPPERS):
            shorter = isinstance(layer, gym.wrappers.TimeLimit)  # max_episode_steps=
            raise ConfigError(
                f"env is wrapped in {type(layer).__name__}, which a run cannot record (it is "
                "rebuilt from its task's name and arguments, and each method adds its own "
                "observation wrappers); give the task itself (env.unwrapped), "
                + (
                    "built with horizon=N for interactions of N steps"
                    if shorter
                    else "or a task class of your own that does what the wrapper does"
                )
            )
        layer = layer.env


def task_name_of(env: gym.Env) -> str:
    """How a run records an environment instance: its task's name, else its class path."""
    check_recordable(env)
    spec = env.spec if env.spec is not None else env.unwrapped.spec
    if spec is not None:
        try:
            return task_spec(spec.id).name
        except ConfigError:
            pass
    return class_path(type(env.unwrapped))


def task_version_of(env: gym.Env) -> str:
    """The task version an instance is: its gymnasium id, or its class path (as a run's
    ``task_id or task``)."""
    name = task_name_of(env)
    return name if is_class_path(name) else task_spec(name).gym_id


def same_task_version(recorded: str, given: str) -> bool:
    """Whether ``given`` (``task_version_of`` an instance) is the task a run ``recorded``; a
    class a script defined is recorded as ``__main__:Name``, which the same class imported
    from a module is (``SILI.load(path, env=...)`` exists for it)."""
    if recorded.startswith("__main__:") and is_class_path(given):
        return recorded.partition(":")[2] == given.partition(":")[2]
    return recorded == given


def same_task_arguments(env: gym.Env, recorded: dict[str, Any]) -> bool:
    """Whether the task instance ``env`` was built with the arguments a run ``recorded`` (of
    the same version): an argument given at its default is the same as one left out."""
    params = inspect.signature(type(env.unwrapped).__init__).parameters
    defaults = {n: q.default for n, q in params.items() if q.default is not inspect.Parameter.empty}
    name = task_name_of(env)
    if not is_class_path(name):
        defaults.update(gym.spec(task_spec(name).gym_id).kwargs)
    given, missing = task_kwargs_of(env), object()
    return all(
        same_argument(
            given.get(k, defaults.get(k, missing)), recorded.get(k, defaults.get(k, missing))
        )
        for k in set(given) | set(recorded)
    )


def task_kwargs_of(env: gym.Env) -> dict[str, Any]:
    """The arguments ``task_name_of(env)`` needs to build the same task again: those the
    instance was built with, less a registered version's own."""
    task = env.unwrapped
    given = getattr(task, "init_kwargs", None)
    if given is None:
        raise ConfigError(
            f"cannot record the arguments {type(task).__name__} was built with (its constructor "
            "takes *args); give its arguments by name"
        )
    name, registered = task_name_of(env), {}
    if not is_class_path(name):  # rebuilt from this package's registered version
        spec = env.spec if env.spec is not None else task.spec
        registered = {k: _as_json(k, v) for k, v in gym.spec(spec.id).kwargs.items()}
    missing = object()
    kwargs = {k: _as_json(k, v) for k, v in given.items()}
    other = {k: v for k, v in kwargs.items() if registered.get(k, missing) != v}
    key = None if is_class_path(name) else identity_conflict(name, other)
    if key is not None:  # recorded under its registered name, it could never be built again
        raise ConfigError(
            f"{name} was built with {key}={other[key]!r}, another task than its name says; "
            "build that task by its own name (sili_robots.tasks.TASKS)"
        )
    return other


def _as_json(name: str, value: Any) -> Any:
    """A task argument as config.json records it (arrays as lists), or ConfigError."""

    def plain(obj: Any) -> Any:
        if isinstance(obj, (np.ndarray, np.generic)):
            return obj.tolist()
        raise TypeError(type(obj).__name__)

    try:
        if _non_string_keys(value):  # JSON would record 1 as "1": another argument on resume
            raise TypeError
        return json.loads(json.dumps(value, default=plain))
    except (TypeError, ValueError):
        raise ConfigError(
            f"task argument {name}={value!r} cannot be recorded in config.json; allowed: "
            "numbers, strings, booleans, None, arrays and lists or dicts (with string keys) of them"
        ) from None


def _non_string_keys(value: Any) -> bool:
    """Whether a dict in ``value`` has a key that is not a string."""
    if isinstance(value, dict):
        return any(not isinstance(k, str) or _non_string_keys(v) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return any(map(_non_string_keys, value))
    return False


def default_profile(task: str, method: str) -> str:
    """The profile a run starts from when none is given: the task's for SILI (the paper grid's
    choice, ``TaskSpec.sili_profile``), the package's otherwise."""
    if method != "sili" or is_class_path(task):
        return "package"
    return task_spec(task).sili_profile


def make_env(task: str, **kwargs: Any) -> gym.Env:
    """A task by name, gymnasium id or class path; ``kwargs`` go to its constructor."""
    if is_class_path(task):
        return task_class(task)(**kwargs)
    return make_task(task, **kwargs)


def check_task_builds(task: str, kwargs: dict[str, Any], options: str | None = None) -> None:
    """Construct (not reset: no simulation starts) ``task`` with ``kwargs``, so bad task input
    stops a command before any run starts."""
    built_task(task, kwargs, options).close()


def built_task(task: str, kwargs: dict[str, Any], options: str | None = None) -> gym.Env:
    """``make_env(task, **kwargs)``, or ConfigError with the task's own message (whatever its
    constructor raises: a bad value, a simulator missing here) instead of a traceback; with
    ``options`` (where the arguments were given) an argument the task does not take is named
    first (``check_argument_names``)."""
    if options is not None:
        check_argument_names(task, kwargs, options)
    given = ", ".join(f"{k}={v!r}" for k, v in kwargs.items()) or "its default arguments"
    try:
        return make_env(task, **kwargs)
    except ConfigError as err:
        raise ConfigError(f"task {task!r} with {given}: {err}") from None
    except TypeError as err:  # e.g. a required argument not given
        raise ConfigError(
            f"task {task!r} cannot be built with {given} ({err}); {arguments_hint(task)}"
        ) from None
    except Exception as err:  # e.g. a simulator missing here: named, not a traceback
        raise ConfigError(
            f"task {task!r} cannot be built with {given}: {type(err).__name__}: {err}"
        ) from None


def default_latent(task: str) -> str:
    """The latent kind the paper uses on a task (discrete for a user's task)."""
    return "discrete" if is_class_path(task) else task_spec(task).default_latent


def observed_as(env: gym.Env, cfg: RunConfig) -> gym.Env:
    """``env`` as the method observes it."""
    if cfg.method == "oracle":
        return OracleObservation(env)
    if cfg.agent.latent == "partial" and cfg.method in ("sili", "stable"):
        return StrategyFlag(env)
    return env


def make_run_env(cfg: RunConfig, recorded_in: Path | None = None) -> gym.Env:
    """The run's task version (``task_id``, else its name) as its method observes it; recorded
    arguments the task does not take (a damaged record, a class changed since) are named.
    ``recorded_in``: the run's folder, when ``cfg`` was read from it: a refusal of the task's
    arguments then names the file that records them (an edited one, or a class changed since)."""
    task = cfg.task_id or cfg.task
    check_argument_names(task, cfg.env_kwargs, "the run's env_kwargs")
    try:
        return observed_as(make_env(task, **cfg.env_kwargs), cfg)
    except ConfigError as err:
        if recorded_in is None or not cfg.env_kwargs:
            raise
        raise ConfigError(
            f"the run in {recorded_in} records task {task} with arguments {cfg.env_kwargs} "
            f"({Path(recorded_in) / CONFIG}), which does not build here: {err}"
        ) from None


def check_agent_builds(cfg: RunConfig, task: gym.Env) -> None:
    """Build the run's agent once, on ``task`` (the run's task, unwrapped or not), under the
    memory cap training runs under: a network too large for this machine fails here, before a
    command removes the run it replaces, not after."""
    from sili_robots.memory import capped_at_available

    with capped_at_available():  # as in training: an error, not the kernel's OOM kill
        build_agent(cfg, observed_as(task.unwrapped, cfg))


def build_agent(cfg: RunConfig, env: gym.Env) -> SILIAgent:
    task = env.unwrapped
    return SILIAgent(
        cfg.agent,
        env.observation_space.shape[0],
        env.action_space.shape[0],
        task.horizon,
        task.strategy_dim,
        seed=cfg.seed,
        addons=build_addons(cfg.addons, cfg.agent),
    )


def make_run_config(
    task: str,
    method: str,
    seed: int = 0,
    interactions: int = 1000,
    *,
    latent: str | None = None,
    profile: str | None = None,
    settings: dict[str, Any] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    checkpoint_every: int = 50,
    threads: int = 1,
) -> RunConfig:
    """A run's full config: the method's preset in ``profile`` (default: the task's,
    ``default_profile``), then ``settings`` (dotted paths or earlier flat names; ``addons.*``
    for the add-ons), checked as a whole."""
    profile = profile or default_profile(task, method)
    agent_settings: dict[str, Any] = {}
    addon_settings: dict[str, Any] = {}
    for name, value in (settings or {}).items():
        path = setting_path(name)
        (addon_settings if path.startswith("addons.") else agent_settings)[path] = value
    if latent is not None and agent_settings.get("latent", latent) != latent:
        raise ConfigError(
            f"the latent kind is given twice: latent {latent!r} and setting latent "
            f"{agent_settings['latent']!r}; give it once"
        )
    try:
        cfg = RunConfig(
            task=task,
            method=method,
            seed=seed,
            interactions=interactions,
            agent=method_config(method, latent, profile, agent_settings, default_latent(task)),
            # as config.json records them (numpy numbers as Python's), so a run is built from
            # what it records
            env_kwargs={k: _as_json(k, v) for k, v in (env_kwargs or {}).items()},
            checkpoint_every=checkpoint_every,
            threads=threads,
        )
        for path, value in addon_settings.items():
            cfg.set(path, value)
    except UnknownSetting as err:  # name every setting, the agent's and the add-ons'
        allowed = [  # the method and the profile are chosen themselves, never set
            p
            for p in paths(AgentConfig) + paths(AddonsConfig, "addons.")
            if p not in ("method", "profile")
        ]
        raise ConfigError(
            f"unknown setting {err.name!r}; allowed: {', '.join(allowed)} "
            f"(or the earlier flat names {', '.join(LEGACY_SETTINGS)})"
        ) from None
    cfg.addons.validate(cfg.agent)
    cfg.metric_columns(new_run=True)  # a plug-in's columns checked before a run is written
    return cfg
