"""What a sweep is: tasks x methods x seeds x b values x controllers, expanded into run configs.

Every run gets a name made only from what distinguishes it (task, controller, method, the latent
kind it learns when not the one it learns by default, b for the methods where b is free, seed),
so the same run has the same name in every sweep and a re-invoked sweep finds its earlier runs.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from sili_robots.agent import BETA_METHODS, LATENT_KINDS, METHODS, PROFILES, Schedule
from sili_robots.agent.matmul import default_matmul
from sili_robots.agent.methods import LATENT_METHODS, PRESETS
from sili_robots.build import (
    canonical_task,
    check_task_builds,
    default_latent,
    default_profile,
    make_run_config,
)
from sili_robots.errors import (
    ConfigError,
    check_choice,
    check_count,
    check_names,
    check_seed,
    is_number,
)
from sili_robots.labels import file_stem
from sili_robots.migrations import setting_path
from sili_robots.runs import RunConfig
from sili_robots.tasks import TASKS, TaskSpec, task_spec
from sili_robots.tasks.registry import (
    check_argument_names,
    first_version,
    is_class_path,
    same_argument,
    task_accepts,
    task_defaults,
)


@dataclass
class SweepSpec:
    """The axes of a sweep and the settings every run shares."""

    tasks: list[str]
    methods: list[str]
    seeds: list[int]
    interactions: int
    betas: list[float] | None = None  # None: each method's own b
    #: (interaction, b) knots of a b schedule for every sili/smirl run (instead of ``betas``)
    beta_schedule: list[tuple[int, float]] | None = None
    #: (interaction, target entropy), (interaction, gamma) and (interaction, SAC learning rate)
    #: knots for every run
    target_entropy_schedule: list[tuple[int, float]] | None = None
    gamma_schedule: list[tuple[int, float]] | None = None
    lr_schedule: list[tuple[int, float]] | None = None
    controllers: list[str] | None = None  # None: each task's default
    latent: str | None = None  # None: each task's default latent kind
    #: the settings every run starts from: ``package`` or ``paper`` (agent/methods.py); None:
    #: SILI starts from each task's (``sili_profiles``), the other methods from the package's
    profile: str | None = None
    agent_overrides: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    checkpoint_every: int = 50
    #: task name -> the gymnasium id (task version) its runs build; filled when planned
    task_ids: dict[str, str] = field(default_factory=dict)
    #: SILI's default b when the sweep was planned (a number, or a schedule's dict), so
    #: ``--resume`` keeps it when the default moves on
    sili_beta: float | dict[str, Any] | None = None
    #: task name -> the profile SILI starts from there when ``profile`` is None, recorded when
    #: planned so ``--resume`` keeps it when a task's default moves on
    sili_profiles: dict[str, str] = field(default_factory=dict)
    #: whether the paper profile's continuous latents are the encoder's raw output (False for
    #: sweeps recorded before: they ran with tanh, ``model.squash``, and resume so)
    paper_raw_latents: bool = True
    #: the agent settings this machine's timing chose (of ``TIMED``; those not given): a run
    #: already on disk keeps its own (``runner.as_made``); None: worked out when planned
    timed: list[str] | None = None

    def __post_init__(self) -> None:
        _check_fields(self)
        # the kernel library is resolved once, when the sweep is planned, and recorded with it
        # (as a run's config.json records it), so ``--resume`` keeps it on any machine; so are
        # the defaults that have changed since sweeps were first recorded
        given = {setting_path(k) for k in self.agent_overrides}
        if self.timed is None:  # recorded before: every setting was given (from_dict)
            self.timed = [k for k in TIMED if k not in given]
        recorded = {"matmul": default_matmul(), **_current(CHANGED_DEFAULTS)}
        if not self.paper_raw_latents:
            recorded["model.squash"] = True
        self.agent_overrides = {
            **{k: v for k, v in recorded.items() if k not in given},
            **self.agent_overrides,
        }
        # likewise each task's version, so ``--resume`` keeps it when a name moves on
        self.task_ids = {**_task_ids(self.tasks, task_spec), **self.task_ids}
        if self.profile is None:
            now = {t: default_profile(t, "sili") for t in self.tasks}
            self.sili_profiles = {**now, **self.sili_profiles}
        if self.sili_beta is None:
            b = PRESETS["sili"].defaults["sili.beta"]
            self.sili_beta = b.to_dict() if isinstance(b, Schedule) else float(b)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SweepSpec:
        """Read a recorded invocation; one recorded before ``matmul`` existed ran on aten, one
        recorded before task versions ran each task's first version, one recorded before SILI's
        default b was a schedule ran at b = 0.5, one recorded before profiles ran the package's,
        one recorded before a default in ``CHANGED_DEFAULTS`` changed ran at the earlier value,
        one recorded before ``paper_raw_latents`` squashed continuous latents by tanh, and one
        recorded before ``timed`` holds its runs to every setting it records."""
        given = {setting_path(k) for k in data.get("agent_overrides", {})}
        older = {"matmul": "aten", **CHANGED_DEFAULTS}
        overrides = {
            **{k: v for k, v in older.items() if k not in given},
            **data.get("agent_overrides", {}),
        }
        task_ids = data.get("task_ids")
        if task_ids is None:
            task_ids = _task_ids(data.get("tasks", []), first_version)
        data = {"sili_beta": 0.5, "profile": "package", "paper_raw_latents": False, **data}
        data = {**data, "agent_overrides": overrides, "task_ids": task_ids}
        return cls(**data)

    def default_beta(self) -> float | Schedule:
        """SILI's b for the runs that give none: the default recorded with the sweep."""
        b = self.sili_beta
        return Schedule.from_dict(b) if isinstance(b, dict) else float(b)


#: the agent settings chosen per machine by a timing (agent/matmul.py) when not given
TIMED = ("matmul", "sac.precision")
#: agent defaults that changed after sweeps were first recorded -> the value before the change
#: (a recorded sweep without the setting planned its runs with that value)
CHANGED_DEFAULTS: dict[str, Any] = {
    "model.updates_per_interaction": 20,
    "sac.precision": "float32",  # now chosen per machine
}


def _current(paths: dict[str, Any]) -> dict[str, Any]:
    """Today's default of each setting path."""
    from sili_robots.agent.config import AgentConfig, get_path

    return {path: get_path(AgentConfig(), path) for path in paths}


def _task_ids(tasks: list[str], version: Callable[[str], TaskSpec]) -> dict[str, str]:
    """``{task: version(task).gym_id}`` for the known tasks (unknown ones fail in ``validate``)."""
    out = {}
    for task in tasks:
        with contextlib.suppress(ConfigError):
            out[task] = version(task).gym_id
    return out


@dataclass(frozen=True)
class PlannedRun:
    """One run of a sweep: its stable name and its fully resolved config."""

    name: str
    config: RunConfig
    #: the names earlier versions gave the same run (they named the sweep's ``--latent`` also
    #: for methods that take none or take it as another kind, and a swept ``--controller`` also
    #: when it is the task's default); a sweep resumes it under ``name``
    former_names: tuple[str, ...] = ()
    #: the settings of ``config`` (dotted) this machine's timing chose, not the user
    timed: tuple[str, ...] = ()


#: the most seeds one sweep takes (far beyond any study; more is a slip such as 0-99999999)
MAX_SEEDS = 10_000


def parse_seeds(text: str) -> list[int]:
    """``"0-4"``, ``"0,2,7"`` or a mix (``"0-2,5"``) -> sorted unique seeds."""
    seeds: set[int] = set()
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, dash, hi = part.partition("-")
        try:
            a, b = (int(lo), int(hi)) if dash and lo else (int(part), int(part))
        except ValueError:
            raise ConfigError(
                f"bad seed {part!r}; give integers and ranges, e.g. 0-4 or 0,2,7"
            ) from None
        if b < a:
            raise ConfigError(f"seed range {part!r} is empty; write LOW-HIGH with LOW <= HIGH")
        for end in (a, b):
            check_seed(end)
        too_many = ConfigError(
            f"seeds {text!r} are more than {MAX_SEEDS:,} runs per variant; give fewer"
        )
        if b - a + 1 > MAX_SEEDS:  # before a set of billions fills the memory
            raise too_many
        seeds.update(range(a, b + 1))
        if len(seeds) > MAX_SEEDS:
            raise too_many
    if not seeds:
        raise ConfigError(f"no seeds in {text!r}; give e.g. 0-4 or 0,2,7")
    return sorted(seeds)


def parse_list(text: str) -> list[str]:
    """Comma-separated names, duplicates dropped, order kept."""
    return list(dict.fromkeys(p.strip() for p in text.split(",") if p.strip()))


def parse_betas(text: str) -> list[float]:
    out: list[float] = []
    for part in parse_list(text):
        try:
            value = float(part)
        except ValueError:
            raise ConfigError(
                f"bad b value {part!r}; give numbers in [0, 1], e.g. 0,0.5,1"
            ) from None
        if not 0.0 <= value <= 1.0:
            raise ConfigError(f"b value {value} is outside the allowed range [0, 1]")
        out.append(value)
    if not out:
        raise ConfigError(f"no b values in {text!r}; give e.g. 0,0.2,0.4")
    return list(dict.fromkeys(out))


def check_task_arguments(spec: SweepSpec) -> None:
    """Every task of a new sweep takes every ``--env-kwarg`` by name, and is built once with
    them and each controller (a user's task class always), so a bad value stops the sweep
    before any run instead of failing every run of it (a recorded sweep resumes as it ran: such
    runs fail one by one)."""
    for task in spec.tasks:  # names first, on every task, then values
        check_argument_names(task, spec.env_kwargs, "--env-kwarg")
    for task in spec.tasks:
        for kwargs in task_kwargs_of_runs(spec, task):
            if kwargs or is_class_path(task):  # a registered task builds with its defaults
                check_task_builds(task, kwargs)


def task_kwargs_of_runs(spec: SweepSpec, task: str) -> list[dict[str, Any]]:
    """The task arguments ``task``'s runs are built with: the sweep's, once per controller on
    the tasks that take one."""
    if spec.controllers is None or not task_accepts(task, "controller"):
        return [dict(spec.env_kwargs)]
    return [dict(spec.env_kwargs, controller=c) for c in spec.controllers]


def format_beta(beta: float) -> str:
    return f"{beta:g}"


def run_name(
    task: str,
    method: str,
    seed: int,
    *,
    beta: float | str | None = None,
    controller: str | None = None,
    latent: str | None = None,
    profile: str = "package",
) -> str:
    """``task[-controller]__method[-profile][-latent][-bB]__sSEED``, e.g.
    ``circle-3__sili-b0.5__s0`` (``-bschedule`` when b follows a schedule; ``-paper`` in the
    paper profile; a task class ``mylab.tasks:MyEnv`` as ``mylab-tasks-MyEnv``)."""
    head = file_stem(task) if controller is None else f"{file_stem(task)}-{controller}"
    mid = method if profile == "package" else f"{method}-{profile}"
    if latent is not None:
        mid += f"-{latent}"
    if beta is not None:
        mid += f"-b{beta if isinstance(beta, str) else format_beta(beta)}"
    return f"{head}__{mid}__s{seed}"


#: settings a sweep sets through its own options, not ``--set``
SWEEP_OPTIONS = {
    "sili.beta": "--beta or --beta-schedule",
    "method": "--methods",
    "latent": "--latent",
}
#: the sweep's schedule fields -> the setting each schedules, and its option
SWEEP_SCHEDULES = {
    "beta_schedule": ("sili.beta", "--beta-schedule"),
    "target_entropy_schedule": ("sac.target_entropy", "--target-entropy-schedule"),
    "gamma_schedule": ("sac.gamma", "--discount-schedule"),
    "lr_schedule": ("sac.lr", "--lr-schedule"),
}


def schedule_overrides(spec: SweepSpec, method: str) -> dict[str, Any]:
    """The sweep's schedules as settings of one method's runs (b only where b is free)."""
    out: dict[str, Any] = {}
    for key, (path, _) in SWEEP_SCHEDULES.items():
        points = getattr(spec, key)
        if points is not None and (key != "beta_schedule" or method in BETA_METHODS):
            out[path] = Schedule(tuple(tuple(p) for p in points))
    return out


def validate(spec: SweepSpec) -> None:
    """Reject bad axes up front with the allowed values (tasks' own arguments: a new sweep from
    the CLI builds each task first, ``check_task_arguments``; through the Python API a bad one
    fails the runs that build it)."""
    if not spec.tasks:
        raise ConfigError(f"no tasks given; allowed: {', '.join(TASKS)}")
    if not spec.methods:
        raise ConfigError(f"no methods given; allowed: {', '.join(METHODS)}")
    named: dict[str, str] = {}  # file name of its runs and figures -> task
    for task in spec.tasks:
        name = canonical_task(task)  # a class path is loaded here: a bad one stops the sweep
        stem = file_stem(name)
        if stem in named:
            raise ConfigError(
                f"tasks {named[stem]!r} and {task!r} are the same task or share the file name "
                f"{stem!r} of their runs; give one of them"
            )
        named[stem] = task
    for method in spec.methods:
        check_choice("method", method, METHODS)
    if spec.profile is not None:
        check_choice("profile", spec.profile, PROFILES)
    if spec.latent is not None:
        check_choice("latent kind", spec.latent, LATENT_KINDS)
    if spec.interactions < 1:
        raise ConfigError(f"interactions must be >= 1, got {spec.interactions}")
    if spec.checkpoint_every < 1:
        raise ConfigError(f"checkpoint_every must be >= 1, got {spec.checkpoint_every}")
    given = {setting_path(k): k for k in spec.agent_overrides}
    for path, options in SWEEP_OPTIONS.items():
        if path in given:
            raise ConfigError(
                f"agent setting {given[path]!r} cannot be overridden in a sweep; use the "
                f"sweep's {options}"
            )
    if spec.betas is not None and spec.beta_schedule is not None:
        raise ConfigError("give one of --beta and --beta-schedule, not both")
    for key, (path, option) in SWEEP_SCHEDULES.items():
        if getattr(spec, key) is not None and path in given:
            raise ConfigError(f"give one of --set {given[path]} and {option}, not both")
    if "controller" in spec.env_kwargs:
        raise ConfigError("give controllers with --controller, not as a task argument")
    for option, given in (("--beta", spec.betas), ("--beta-schedule", spec.beta_schedule)):
        if given is not None and not set(spec.methods) & set(BETA_METHODS):
            raise ConfigError(
                f"{option} applies to methods {', '.join(BETA_METHODS)} only, none of which is "
                f"in the sweep ({', '.join(spec.methods)})"
            )
    if spec.controllers is not None and not any(task_accepts(t, "controller") for t in spec.tasks):
        with_ctrl = [t for t in TASKS if task_accepts(t, "controller")]
        raise ConfigError(
            f"--controller applies to tasks {', '.join(with_ctrl)} only, none of which is in "
            f"the sweep ({', '.join(spec.tasks)})"
        )


def _plain(value: Any) -> Any:
    """``value`` as JSON keeps it (numpy's numbers and arrays as Python's), for ``sweep.json``."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _axis(spec: SweepSpec, name: str, what: str, check: Callable[[Any], Any]) -> None:
    """The axis ``name`` as a non-empty list of ``check``-ed values (a string is one value, not
    a list of letters), or ConfigError naming it."""
    given = getattr(spec, name)
    if given is None and name not in ("tasks", "methods", "seeds"):
        return
    if isinstance(given, str | bytes | dict) or not isinstance(given, Iterable):
        raise ConfigError(f"SweepSpec {name} must be a non-empty list of {what}, got {given!r}")
    given = list(given)
    if not given and name not in ("tasks", "methods"):  # (none of those: validate lists them)
        raise ConfigError(f"SweepSpec {name} must be a non-empty list of {what}, got []")
    values = [check(_plain(v)) for v in given]
    twice = [v for i, v in enumerate(values) if v in values[:i]]
    if twice and name in ("methods", "seeds", "controllers"):  # (equal b values are one b)
        raise ConfigError(f"SweepSpec {name} gives {twice[0]!r} twice; give each once")
    setattr(spec, name, values)


def _name(value: Any) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"a name must be a string, got {value!r}")
    return value


def _number(value: Any) -> float:
    if not is_number(value):
        raise ConfigError(f"b must be a number, got {value!r}")
    return float(value)


def _check_fields(spec: SweepSpec) -> None:
    """Each field of the type it is recorded as, before it is planned (numpy's numbers are
    taken as Python's; ``sweep.json`` keeps them)."""
    _axis(spec, "tasks", "task names", _name)
    _axis(spec, "methods", "method names", _name)
    _axis(spec, "seeds", "seeds", check_seed)
    _axis(spec, "betas", "b values", _number)
    _axis(spec, "controllers", "controller names", _name)
    spec.interactions = check_count("interactions", _plain(spec.interactions))
    spec.checkpoint_every = check_count("checkpoint_every", _plain(spec.checkpoint_every))
    for name in ("latent", "profile"):
        if getattr(spec, name) is not None:
            _name(getattr(spec, name))
    for name in ("agent_overrides", "env_kwargs"):
        setattr(spec, name, _plain(check_names(f"SweepSpec {name}", getattr(spec, name))))
    for name in SWEEP_SCHEDULES:
        points = getattr(spec, name)
        if points is None:
            continue
        pairs = _plain(points) if isinstance(points, list | tuple) else None
        if not pairs or not all(
            isinstance(p, list) and len(p) == 2 and all(is_number(x) for x in p) for p in pairs
        ):
            raise ConfigError(
                f"SweepSpec {name} must be a list of (interaction, value) pairs, got {points!r}"
            )
        setattr(spec, name, [tuple(p) for p in pairs])


def _controller_names(
    task: str, task_id: str | None, controller: str | None
) -> tuple[str | None, str | None]:
    """(the controller a run is named by, the one earlier versions named it by when swept). A
    registered task's default is named by neither now: that run is the one without
    ``--controller`` (``runs.run_differences``); a user's class names every swept one."""
    if task_id is None or not task_accepts(task, "controller"):
        return controller, controller
    default = task_defaults(task_id).get("controller")
    if controller is None:
        return None, default
    return (None if same_argument(default, controller) else controller), controller


def _latent_of(latent: str | None, method: str) -> str | None:
    """The sweep's latent kind as ``method`` takes it: none for the methods without a latent;
    LILI, which always learns one, discrete where the sweep says partial (as it always ran)."""
    if method not in LATENT_METHODS:
        return None
    return "discrete" if method == "lili" and latent == "partial" else latent


def expand(spec: SweepSpec) -> list[PlannedRun]:
    """Every run of the sweep, in a stable order (task, controller, method, b, seed)."""
    validate(spec)
    runs: list[PlannedRun] = []
    for task in spec.tasks:
        name = canonical_task(task)
        task_default_latent = default_latent(name)
        latent = spec.latent or task_default_latent
        # a registered task's runs build the version recorded with the sweep; a user's class
        # has no versions (task_id None: the run builds the class path)
        task_id = None if is_class_path(name) else spec.task_ids.get(task, task_spec(task).gym_id)
        for env_kwargs in task_kwargs_of_runs(spec, name):
            # only a swept one: validate() refuses a controller among the sweep's task arguments
            controller, former_controller = _controller_names(
                name, task_id, env_kwargs.get("controller")
            )
            for method in spec.methods:
                profile = spec.profile or (
                    spec.sili_profiles.get(task, "package") if method == "sili" else "package"
                )
                betas: list[float | None] = [None]
                if method in BETA_METHODS:
                    betas = list(spec.betas) if spec.betas is not None else [None]
                for beta in betas:
                    settings = dict(spec.agent_overrides)
                    if beta is not None:
                        settings["sili.beta"] = beta
                    elif method == "sili" and profile == "package":
                        settings["sili.beta"] = spec.default_beta()
                    settings.update(schedule_overrides(spec, method))
                    base = make_run_config(
                        name,
                        method,
                        latent=_latent_of(spec.latent, method),
                        profile=profile,
                        settings=settings,
                        env_kwargs=env_kwargs,
                    )
                    b = base.agent.sili.beta
                    label = "schedule" if isinstance(b, Schedule) else b
                    taken = _latent_of(latent, method)  # what the run learns, not what was asked
                    named = None if taken == _latent_of(task_default_latent, method) else taken
                    for seed in spec.seeds:
                        naming = functools.partial(
                            run_name,
                            name,
                            method,
                            seed,
                            beta=label if method in BETA_METHODS else None,
                            profile=profile,
                        )
                        run = naming(latent=named, controller=controller)
                        asked = None if latent == task_default_latent else latent
                        formers = (
                            naming(latent=asked, controller=controller),
                            naming(latent=named, controller=former_controller),
                            naming(latent=asked, controller=former_controller),
                        )
                        former = tuple(dict.fromkeys(n for n in formers if n != run))
                        cfg = replace(
                            base,
                            task_id=task_id,
                            seed=seed,
                            interactions=spec.interactions,
                            checkpoint_every=spec.checkpoint_every,
                        )
                        timed = tuple(f"agent.{k}" for k in spec.timed or ())
                        runs.append(PlannedRun(run, cfg, former, timed))
    names = [r.name for r in runs]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:  # e.g. two b values that print alike (format_beta keeps 6 digits)
        raise ConfigError(
            f"two runs of this sweep would be named {clash[0]}; give values that differ in "
            "their first 6 significant digits"
        )
    return runs
