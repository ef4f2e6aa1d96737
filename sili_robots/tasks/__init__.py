"""Tasks: repeated-interaction gymnasium environments, registered on import."""

from sili_robots.tasks.base import RepeatedInteractionEnv
from sili_robots.tasks.registry import TASKS, TaskSpec, make_task, register_task, task_spec

__all__ = ["TASKS", "RepeatedInteractionEnv", "TaskSpec", "make_task", "register_task", "task_spec"]
