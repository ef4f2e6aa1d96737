"""``sili eval``: run a trained policy without exploration and report reward and stability."""

from __future__ import annotations

import argparse
import json
import sys

from sili_robots.commands.common import (
    add_env_kwarg_arg,
    path_arg,
    positive_int,
    task_arguments_given,
)


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
    from sili_robots.evaluation import check_played_horizon, evaluate
    from sili_robots.runs import read_config
    from sili_robots.tasks.registry import title_arguments
    from sili_robots.verdict import random_only

    cfg, given = read_config(args.run_dir), task_arguments_given(args)
    task, task_args = cfg.task_id or cfg.task, {**cfg.env_kwargs, **given}
    task_env = None
    if given:  # e.g. a policy trained with one controller, played with another
        check_played_horizon(args.run_dir, cfg, given, "--env-kwarg")
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
    # Sawyer-Reach: the controller, given or not, and the run's own: an ablation's rows say both
    played = title_arguments(task, task_args)
    arguments = {"trained_with": title_arguments(task, cfg.env_kwargs), "played_with": played}
    print(json.dumps({"run_dir": str(args.run_dir), **arguments, **result}, indent=2))
    return 0
