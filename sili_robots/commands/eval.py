"""``sili eval``: run a trained policy without exploration and report reward and stability."""

from __future__ import annotations

import argparse
import json
import sys

from sili_robots.commands.common import path_arg, positive_int


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
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.evaluation import evaluate
    from sili_robots.runs import read_config
    from sili_robots.verdict import random_only

    result = evaluate(args.run_dir, args.interactions)
    cfg, trained = read_config(args.run_dir), result["trained_interactions"]
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
    print(json.dumps({"run_dir": str(args.run_dir), **result}, indent=2))
    return 0
