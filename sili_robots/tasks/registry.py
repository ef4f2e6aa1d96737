"""The task registry: short CLI names, gymnasium ids and how to build each task.

Like robosuite's registry of environments, every task is listed once here; ``make_task`` is the
one way the rest of the package builds a task, so bad names fail here with the list of choices.

Versions follow gymnasium's convention: a change to a task's dynamics gets a new version id and
the earlier ids stay registered, unchanged, so results recorded on them can be reproduced. The
CLI names (``circle-3``, ...) build the current version (``TASKS``); an earlier version is built
by its gymnasium id (``sili/Circle3-v0``) or by its CLI name with the version appended
(``circle-3-v0``), both listed in ``EARLIER_VERSIONS``. ``docs/tasks.md`` says what each version
changed and why.
"""

from __future__ import annotations

import functools
import inspect
import json
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator

from sili_robots.errors import ConfigError
from sili_robots.plugins import class_path, load_class
from sili_robots.tasks.base import RepeatedInteractionEnv


@dataclass(frozen=True)
class TaskSpec:
    """One registered task version."""

    name: str  # CLI name, e.g. "circle-3" (the current version) or "circle-3-v0" (an earlier one)
    gym_id: str  # gymnasium id, e.g. "sili/Circle3-v1"
    entry_point: str  # "module:Class"
    kwargs: dict[str, Any] = field(default_factory=dict)
    #: the latent kind the paper uses on this task (the default for ``--method sili``)
    default_latent: str = "discrete"
    #: the settings ``--method sili`` starts from here when no profile is given: the package's,
    #: unless the paper grid found the paper's better on this task (``sili_robots/claims.py``)
    sili_profile: str = "package"
    #: the CLI name of the task family (the same for every version); set by ``register_task``
    family: str = ""

    @property
    def version(self) -> int:
        return int(self.gym_id.rsplit("-v", 1)[1])


#: the current version of every task, by CLI name
TASKS: dict[str, TaskSpec] = {}
#: earlier versions, by their own CLI name (``circle-3-v0``)
EARLIER_VERSIONS: dict[str, TaskSpec] = {}


def register_task(spec: TaskSpec, current: bool = True) -> TaskSpec:
    """Add a task version to the registry and to gymnasium.

    ``current=False`` registers an earlier version: it keeps ``spec.name`` as its family and is
    listed as ``NAME-vK``.
    """
    family = spec.family or spec.name
    if current:
        spec = replace(spec, family=family)
        TASKS[spec.name] = spec
    else:
        spec = replace(spec, name=f"{family}-v{spec.version}", family=family)
        EARLIER_VERSIONS[spec.name] = spec
    if spec.gym_id not in gym.registry:
        # the base class checks every reset and step itself; gymnasium's checker, which checks
        # the first ones, is left out: a refused first reset (a bad option) broke it for good
        gym.register(
            id=spec.gym_id,
            entry_point=spec.entry_point,
            kwargs=dict(spec.kwargs),
            disable_env_checker=True,
        )
    return spec


def all_versions() -> list[TaskSpec]:
    """Every registered version: the current tasks, then the earlier versions."""
    return [*TASKS.values(), *EARLIER_VERSIONS.values()]


def task_spec(name: str) -> TaskSpec:
    """Look a task up by CLI name (``circle-3``, ``circle-3-v0``), the current version's name
    with its version (``circle-3-v1``) or gymnasium id."""
    for spec in all_versions():
        if name in (spec.name, spec.gym_id, f"{spec.family}-v{spec.version}"):
            return spec
    raise ConfigError(
        f"unknown task {name!r}; allowed: {', '.join(TASKS)} "
        f"(earlier versions: {', '.join(EARLIER_VERSIONS)}){_own_class_hint(name)}"
    )


def _own_class_hint(name: str) -> str:
    """For a user's gymnasium id of a repeated-interaction task: give it as its class instead
    (a run records its class, which every process, a sweep's too, can import)."""
    if name not in gym.registry:
        return ""
    entry = gym.registry[name].entry_point
    try:
        path = entry if isinstance(entry, str) else class_path(entry)
        load_class(path, RepeatedInteractionEnv, "task")
    except (ConfigError, AttributeError):
        return ""  # not one (Pendulum-v1), not importable as named, or no class (a partial)
    return f"; the gymnasium id {name} is your own task: give its class, {path}"


def current_names_of_class(cls: type) -> list[str]:
    """The CLI names whose current version builds ``cls`` (none for a user's own class)."""
    path = class_path(cls)
    return [spec.name for spec in TASKS.values() if spec.entry_point == path]


def first_version(name: str) -> TaskSpec:
    """The oldest registered version of the task ``name`` belongs to.

    Run configs and sweep records written before task versions were recorded name only the task;
    they ran its first version, which this returns.
    """
    family = task_spec(name).family
    return min((s for s in all_versions() if s.family == family), key=lambda s: s.version)


def task_defaults(task_id: str) -> dict[str, Any]:
    """The arguments the registered version ``task_id`` is built with by default: its own, then
    its constructor's defaults."""
    return dict(_defaults(task_spec(task_id).gym_id))


@functools.cache
def _defaults(gym_id: str) -> dict[str, Any]:
    spec = task_spec(gym_id)
    params = inspect.signature(_task_class(spec)).parameters
    defaults = {k: p.default for k, p in params.items() if p.default is not p.empty}
    return {**defaults, **spec.kwargs}


def task_arguments_key(task_id: str | None, env_kwargs: dict[str, Any]) -> str:
    """``other_task_arguments`` as one comparable string for tables: sorted JSON, "" for none."""
    other = other_task_arguments(task_id, env_kwargs)
    return json.dumps(other, sort_keys=True) if other else ""


def other_task_arguments(task_id: str | None, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The recorded task arguments that build other dynamics than the registered version
    ``task_id`` does by default: what its stored reference bounds were not measured with.
    ``controller="mink"`` on Sawyer-Reach is the default, ``controller="osc"`` is not, and
    Driving's ``backend`` runs the same simulation; everything counts for an unregistered task."""
    if not env_kwargs:
        return {}
    try:
        spec = task_spec(str(task_id))
    except ConfigError:
        return dict(env_kwargs)
    same = _task_class(spec).same_dynamics_arguments
    return {k: v for k, v in _not_at_defaults(spec, env_kwargs).items() if k not in same}


def title_arguments(task: str | None, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The task arguments an output names (titles, ``sili eval``'s JSON, a sweep's controller
    column): the version's ``named_in_titles`` at their values (Sawyer-Reach's
    ``controller="mink"`` when none is given), then the others given. A user's class: the given
    ones."""
    try:
        spec = task_spec(str(task))
    except ConfigError:
        return dict(env_kwargs)
    defaults = _defaults(spec.gym_id)
    named = {k: defaults[k] for k in _task_class(spec).named_in_titles if k in defaults}
    return {**named, **env_kwargs}


def _task_class(spec: TaskSpec) -> type:
    return load_env_creator(spec.entry_point)


def without_defaults(task: str, task_id: str | None, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` without the arguments given at the registered version's default (the run
    ``task_id`` builds, or the first version of ``task`` for a run recorded before versions):
    ``controller="mink"`` on Sawyer-Reach builds the run no argument builds. A user's class keeps
    them all (its defaults may change)."""
    try:
        spec = task_spec(task_id) if task_id else first_version(task)
    except ConfigError:
        return dict(env_kwargs)
    return _not_at_defaults(spec, env_kwargs)


def _not_at_defaults(spec: TaskSpec, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    defaults, missing = _defaults(spec.gym_id), object()
    return {k: v for k, v in env_kwargs.items() if not same_argument(defaults.get(k, missing), v)}


def same_argument(default: Any, value: Any) -> bool:
    """A default and a value as config.json records it (tuples and arrays as lists)."""
    try:
        return bool(np.array_equal(np.asarray(default), np.asarray(value)))
    except (TypeError, ValueError):
        return default == value


def identity_conflict(name: str, kwargs: dict[str, Any]) -> str | None:
    """The first of ``kwargs`` that would make the task ``name`` another task (its identity
    arguments, Circle's ``variant``, are fixed by the name), or None: a run recorded under the
    name must build again as that task (``make_task``, and a given instance when recorded)."""
    spec = task_spec(name)
    fixed = _task_class(spec).identity_arguments
    return next(
        (
            k
            for k in sorted(kwargs)
            if k in fixed and not same_argument(spec.kwargs.get(k), kwargs[k])
        ),
        None,
    )


def check_identity(name: str, kwargs: dict[str, Any]) -> None:
    """ConfigError when ``kwargs`` would build another task under ``name`` (``identity_conflict``),
    naming the names that build it."""
    spec = task_spec(name)
    key = identity_conflict(spec.gym_id, kwargs)
    if key is not None:
        others = [
            s.name
            for s in all_versions()
            if s.entry_point == spec.entry_point and s.version == spec.version and s != spec
        ]
        fixed, given = spec.kwargs.get(key), kwargs[key]
        kind = ""  # `--env-kwarg variant=3` reads a number: the same text, another type
        if str(given) == str(fixed) and type(given) is not type(fixed):
            kind = f" ({type(given).__name__} {given!r}, not {type(fixed).__name__} {fixed!r})"
        raise ConfigError(
            f"{spec.name} fixes {key}={fixed!r} (it is what the task is), so "
            f"{key}={given!r}{kind} is not allowed; drop it, or build another {key} by its "
            f"name: {', '.join(others)}"
        )


def task_class(path: str) -> type[RepeatedInteractionEnv]:
    """A user's task class from ``package.module:ClassName``."""
    return load_class(path, RepeatedInteractionEnv, "task", instead="a registered task or ")


def is_class_path(task: str) -> bool:
    return ":" in task and "/" not in task


def _task_parameters(task: str) -> dict[str, inspect.Parameter]:
    path = task if is_class_path(task) else task_spec(task).entry_point
    return dict(inspect.signature(task_class(path).__init__).parameters)


def task_arguments(task: str) -> list[str]:
    """The constructor arguments a task takes (``--env-kwarg``, ``--controller``), by name."""
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return [n for n, q in _task_parameters(task).items() if n != "self" and q.kind in kinds]


@functools.cache
def task_accepts(task: str, argument: str) -> bool:
    """Whether the task's constructor takes ``argument`` (e.g. ``controller``): by name, or
    through ``**kwargs`` (a user's task class may pass them on)."""
    params = _task_parameters(task).values()
    return argument in task_arguments(task) or any(q.kind == q.VAR_KEYWORD for q in params)


def check_argument_names(task: str, names: Iterable[str], options: str) -> None:
    """ConfigError naming the arguments ``task`` does not take and those it does (``options``:
    where they were given, e.g. ``--env-kwarg``)."""
    unknown = [k for k in names if not task_accepts(task, k)]
    if unknown:
        raise ConfigError(
            f"task {task!r} takes no argument {', '.join(unknown)} ({options}); "
            f"{arguments_hint(task)}"
        )


def arguments_hint(task: str) -> str:
    """ "its arguments: ..." for an error: those a user may give (a registered name fixes its
    identity arguments, Circle's ``variant``, which are said to be fixed, not offered)."""
    fixed = [] if is_class_path(task) else sorted(_task_class(task_spec(task)).identity_arguments)
    settable = [n for n in task_arguments(task) if n not in fixed]
    return f"its arguments: {', '.join(settable) or 'none'}" + "".join(
        f" ({k} is fixed by the name)" for k in fixed
    )


def make_task(name: str, **kwargs: Any) -> gym.Env:
    """Build a task by CLI name or gymnasium id; ``kwargs`` go to the task's constructor."""
    spec = task_spec(name)
    check_identity(spec.gym_id, kwargs)
    with warnings.catch_warnings():
        if spec.name in EARLIER_VERSIONS:  # asked for by its version: no "out of date" warning
            warnings.filterwarnings("ignore", ".*The environment .* is out of date", Warning)
        own = {*inspect.signature(gym.make).parameters, "render_mode"}  # gymnasium's, passed on
        check_argument_names(spec.name, [k for k in kwargs if k not in own], "make_task")
        return gym.make(spec.gym_id, **kwargs)


def _register(
    name: str,
    entry_point: str,
    versions: dict[int, dict[str, Any]],
    camel: str,
    **options: Any,
) -> None:
    """Register every version of one task; the highest is the current one."""
    newest = max(versions)
    for version, kwargs in sorted(versions.items()):
        spec = TaskSpec(name, f"sili/{camel}-v{version}", entry_point, kwargs, **options)
        register_task(spec, current=version == newest)


_CIRCLE = "sili_robots.tasks.circle:CircleEnv"
#: Circle v1: ending on the opponent is inside; outside starts one step (0.1) beyond the circle
_CIRCLE_V1 = {"outside_margin": 0.1}
for _variant, _camel in (("3", "Circle3"), ("8", "Circle8"), ("continuous", "CircleContinuous")):
    _register(
        f"circle-{_variant}",
        _CIRCLE,
        {0: {"variant": _variant}, 1: {"variant": _variant, **_CIRCLE_V1}},
        _camel,
        default_latent="continuous" if _variant == "continuous" else "discrete",
    )
_register(
    "circle-unequal",
    _CIRCLE,
    {
        0: {"variant": "unequal"},
        # v1 also: a near location is left for either other location at random
        1: {"variant": "unequal", **_CIRCLE_V1, "near_moves": "random"},
    },
    "CircleUnequal",
)
_register(
    "speaker-listener",
    "sili_robots.tasks.speaker_listener:SpeakerListenerEnv",
    {
        0: {},
        # v1: the appendix's per-interaction change rule and a speaker the detour can afford
        1: {"change_rule": "interaction", "speaker": (0.0, -0.8)},
    },
    "SpeakerListener",
    default_latent="partial",
)
_register(
    "driving",
    "sili_robots.tasks.driving:DrivingEnv",
    {0: {}},
    "Driving",
    # the paper grid, 5 seeds of each: score 0.68 in the paper profile against 0.49 (RESULTS.md)
    sili_profile="paper",
)
_register(
    "sawyer-reach",
    "sili_robots.tasks.sawyer_reach:SawyerReachEnv",
    {
        0: {},
        # v1: the arm starts below the plane, so holding the goal takes a rise at the end
        1: {"start_z": 0.9},
    },
    "SawyerReach",
)
