"""``sili eval``: run a trained policy without exploration and report reward and stability."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sili_robots.commands.common import (
    add_env_kwarg_arg,
    path_arg,
    positive_int,
    task_arguments_given,
)
from sili_robots.errors import ConfigError

if TYPE_CHECKING:
    from sili_robots.runs import RunConfig


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate a trained run without exploration")
    p.add_argument("run_dir", type=path_arg)
    p.add_argument(
        "--interactions",
        type=positive_int,
        default=100,
        help="interactions to play (default 100); the reward is their mean, the stability "
        "counts those after the first, whose change the training's last interaction caused",
    )
    p.add_argument(
        "--controller",
        help="play with this controller (sawyer-reach: mink, osc or joint_velocity); default: "
        "the run's own",
    )
    add_env_kwarg_arg(p, note="; replaces the run's own argument of that name")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.build import built_task
    from sili_robots.evaluation import evaluate
    from sili_robots.runs import read_config
    from sili_robots.tasks.registry import title_arguments
    from sili_robots.verdict import random_only

    cfg, given = read_config(args.run_dir), task_arguments_given(args)
    task, task_args = cfg.task_id or cfg.task, {**cfg.env_kwargs, **given}
    task_env = None
    if given:  # e.g. a policy trained with one controller, played with another
        _check_horizon(args.run_dir, task, cfg, given)
        task_env = built_task(task, task_args, "--controller, --env-kwarg")
    try:
        result = evaluate(args.run_dir, args.interactions, task_env)
    finally:
        if task_env is not None:
            task_env.close()
    trained = result["trained_interactions"]
    if trained < cfg.interactions:
        print(
            f"{args.run_dir} is unfinished: this evaluates its checkpoint at interaction "
            f"{trained} of {cfg.interactions}",
            file=sys.stderr,
        )
    if trained < cfg.agent.sac.random_interactions:  # its updates start after the last one
        print(
            f"{args.run_dir}: its policy has not trained: {random_only(cfg, trained)}",
            file=sys.stderr,
        )
    played = title_arguments(task, task_args)  # Sawyer-Reach: the controller, given or not
    print(json.dumps({"run_dir": str(args.run_dir), "played_with": played, **result}, indent=2))
    return 0


def _check_horizon(run_dir: Path, task: str, cfg: RunConfig, given: dict) -> None:
    """A trained run plays the horizon it was trained with: its networks and stored
    interactions are that long (said here in the options' words, before anything loads)."""
    from sili_robots.tasks.registry import task_defaults

    if "horizon" not in given:
        return
    try:
        own = cfg.env_kwargs.get("horizon", task_defaults(task).get("horizon"))
    except ConfigError:  # a user's task (a class path): the checkpoint's check names the sizes
        return
    if own is not None and given["horizon"] != own:
        raise ConfigError(
            f"--env-kwarg horizon={given['horizon']!r}: the run in {run_dir} was trained "
            f"with horizon {own}, and a trained run plays the horizon it was trained with"
        )
