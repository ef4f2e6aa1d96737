"""``sili rollout``: play a scripted policy on a task and print its mean task reward and how
often the opponent kept its strategy, both after the game's first interaction (as ``sili
bounds`` counts: the first has no interaction of this policy before it)."""

from __future__ import annotations

import argparse

import numpy as np

from sili_robots.build import built_task
from sili_robots.commands.common import (
    add_task_args,
    positive_int,
    seed,
    task_arguments_given,
    task_name,
)
from sili_robots.policies import SCRIPTED_KINDS, scripted_policy
from sili_robots.policies.scripted import KIND_DESCRIPTIONS
from sili_robots.rollout import run_interactions
from sili_robots.tasks.registry import title_arguments


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rollout", help="play a scripted policy on a task")
    p.add_argument(
        "task",
        type=task_name,
        help="task name, e.g. circle-3, or package.module:ClassName (random and still policies)",
    )
    p.add_argument(
        "--policy",
        default="stabilizing",
        choices=SCRIPTED_KINDS,
        help="the scripted policy (default stabilizing; blind and tracking not on driving): "
        + "; ".join(f"{k}: {d}" for k, d in KIND_DESCRIPTIONS.items()),
    )
    p.add_argument(
        "--interactions", type=positive_int, default=20, help="interactions to play (default 20)"
    )
    p.add_argument("--seed", type=seed, default=0, help="the game's seed (default 0)")
    add_task_args(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    env_kwargs = task_arguments_given(args)
    env = built_task(args.task, env_kwargs, "--controller, --env-kwarg")
    try:
        summary = run_interactions(
            env, scripted_policy(env, args.policy), args.interactions, seed=args.seed
        )
    finally:
        env.close()
    given = "".join(f" {k}={v!r}" for k, v in title_arguments(args.task, env_kwargs).items())
    print(f"task={args.task}{given} policy={args.policy} interactions={args.interactions}")
    if len(summary) == 1:
        print(f"task reward of the one interaction: {summary[0].task_reward:.3f}")
        return 0
    later = summary[1:]  # the first has no interaction of this policy before it
    rewards = np.array([s.task_reward for s in later])
    stable = np.array([not s.strategy_changed for s in later])
    print(f"mean task reward per interaction (after the first): {rewards.mean():.3f}")
    print(
        "fraction of interactions with the true strategy unchanged (after the first): "
        f"{stable.mean():.3f}"
    )
    return 0
