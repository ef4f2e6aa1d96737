"""``sili collect SOURCE... --into DIR``: keep the finished runs of sweeps in a small collection."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sili_robots.commands.common import path_arg, writable_dir
from sili_robots.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "collect",
        help="copy the finished runs of sweeps into a small results collection (no checkpoints)",
        description="Copies every finished run of each SOURCE (a sweep or another collection) "
        "into DIR/runs/NAME/ as config.json, summary.json and metrics.csv.gz: what `sili plot`, "
        "`sili runs` and `sili claims` read, small enough to commit. Unfinished runs are "
        "skipped; a run already collected is left as is unless a source holds the same config at "
        "least as long with another summary.json (an extended or retrained run), which replaces "
        "it: the longest copy is kept.",
    )
    p.add_argument("sources", type=path_arg, nargs="+", metavar="SOURCE")
    p.add_argument(
        "--into", type=path_arg, required=True, metavar="DIR", help="collection directory"
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.sweep.collect import collect
    from sili_robots.sweep.state import check_collection_dir

    same = [str(src) for src in args.sources if Path(src).resolve() == args.into.resolve()]
    if same:
        raise ConfigError(f"--into {args.into} is also a source ({same[0]}); collect elsewhere")
    check_collection_dir(args.into, "--into")  # a sweep, a run's folder or a user's is refused
    writable_dir(args.into, "--into")
    report = collect(args.sources, args.into)
    print(
        json.dumps(
            {
                "added": report.added,
                "replaced": report.replaced,
                "unchanged": len(report.unchanged),
                "unfinished": report.unfinished,
            }
        )
    )
    return 0
