"""``sili runs DIR``: what a sweep or results collection holds, run counts and interactions."""

from __future__ import annotations

import argparse

from sili_robots.commands.common import path_arg


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "runs",
        help="count the runs of a sweep or collection: per task and method, and in total",
        description="One line per task and method variant (runs of it trained with other "
        "settings, e.g. --set, on lines of their own, `settings` naming the difference): runs "
        "done (and unfinished), seeds, interactions per run, mean final task reward and true "
        "stability, CPU time; then the totals.",
    )
    p.add_argument("directory", type=path_arg, metavar="DIR")
    p.add_argument("--csv", action="store_true", help="the per-variant table as CSV")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.sweep.inventory import inventory, totals_line
    from sili_robots.sweep.results import runs_of

    runs_of(args.directory)  # or why there are none
    table = inventory(args.directory)
    print(table.to_csv(index=False) if args.csv else table.to_string(index=False))
    if not args.csv:
        print(totals_line(table))
    return 0
