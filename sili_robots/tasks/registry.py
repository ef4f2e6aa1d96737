"""The task registry: short CLI names, gymnasium ids and how to build each task.

Like robosuite's registry of environments, every task is listed once here; ``make_task`` is the
one way the rest of the package builds a task, so bad names fail here with the list of choices.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from sili_robots.errors import ConfigError


@dataclass(frozen=True)
class TaskSpec:
    """One registered task."""

    name: str  # CLI name, e.g. "circle-3"
    gym_id: str  # gymnasium id, e.g. "sili/Circle3-v0"
    entry_point: str  # "module:Class"
    kwargs: dict[str, Any] = field(default_factory=dict)
    #: the latent kind the paper uses on this task (the default for ``--method sili``)
    default_latent: str = "discrete"
    #: True when the task may need a dedicated process (e.g. libsumo: one simulation each)
    one_per_process: bool = False


TASKS: dict[str, TaskSpec] = {}


def register_task(spec: TaskSpec) -> None:
    """Add a task to the registry and to gymnasium."""
    TASKS[spec.name] = spec
    if spec.gym_id not in gym.registry:
        gym.register(id=spec.gym_id, entry_point=spec.entry_point, kwargs=dict(spec.kwargs))


def task_spec(name: str) -> TaskSpec:
    """Look a task up by CLI name or gymnasium id."""
    for spec in TASKS.values():
        if name in (spec.name, spec.gym_id):
            return spec
    raise ConfigError(f"unknown task {name!r}; allowed: {', '.join(TASKS)}")


def make_task(name: str, **kwargs: Any) -> gym.Env:
    """Build a task by CLI name or gymnasium id; ``kwargs`` go to the task's constructor."""
    spec = task_spec(name)
    return gym.make(spec.gym_id, **kwargs)


register_task(
    TaskSpec("circle-3", "sili/Circle3-v0", "sili_robots.tasks.circle:CircleEnv", {"variant": "3"})
)
register_task(
    TaskSpec("circle-8", "sili/Circle8-v0", "sili_robots.tasks.circle:CircleEnv", {"variant": "8"})
)
register_task(
    TaskSpec(
        "circle-continuous",
        "sili/CircleContinuous-v0",
        "sili_robots.tasks.circle:CircleEnv",
        {"variant": "continuous"},
        default_latent="continuous",
    )
)
register_task(
    TaskSpec(
        "circle-unequal",
        "sili/CircleUnequal-v0",
        "sili_robots.tasks.circle:CircleEnv",
        {"variant": "unequal"},
    )
)
register_task(
    TaskSpec(
        "speaker-listener",
        "sili/SpeakerListener-v0",
        "sili_robots.tasks.speaker_listener:SpeakerListenerEnv",
        default_latent="partial",
    )
)
register_task(
    TaskSpec(
        "driving",
        "sili/Driving-v0",
        "sili_robots.tasks.driving:DrivingEnv",
        default_latent="discrete",
        one_per_process=True,
    )
)
register_task(
    TaskSpec("sawyer-reach", "sili/SawyerReach-v0", "sili_robots.tasks.sawyer_reach:SawyerReachEnv")
)
