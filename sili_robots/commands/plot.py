"""``sili plot SWEEP_DIR``: the paper-style figures of a sweep (PNG and PDF)."""

from __future__ import annotations

import argparse

from sili_robots.commands.common import path_arg, positive_int, writable_dir
from sili_robots.errors import ConfigError
from sili_robots.sweep.state import FIGURE_FORMATS as FORMATS
from sili_robots.sweep.state import FIGURES


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plot",
        help="figures of a sweep: learning curves per task, the b sweep, an overview",
        description="Rebuilds a sweep's SWEEP_DIR/results.csv from its run directories (a "
        "collection of `sili collect` is only read), then writes per "
        "task TASK.png/pdf (task reward, true stability, stability reward per interaction; mean "
        "± std across seeds), TASK_beta.png/pdf where SILI ran with several b, and "
        "overview.png/pdf.",
    )
    p.add_argument("sweep_dir", type=path_arg, metavar="SWEEP_DIR")
    p.add_argument("--out", type=path_arg, help="figure directory (default: SWEEP_DIR/figures)")
    p.add_argument(
        "--smooth",
        type=positive_int,
        help="moving-average window in interactions (default: 2%% of the run length)",
    )
    p.add_argument(
        "--window",
        type=positive_int,
        default=100,
        help="final values (b sweep) = mean over each run's last WINDOW interactions (default 100)",
    )
    p.add_argument(
        "--formats",
        default="png,pdf",
        help=f"comma-separated, of {', '.join(FORMATS)} (default png,pdf)",
    )
    p.add_argument(
        "--include-unfinished", action="store_true", help="also plot runs that have not finished"
    )
    p.add_argument(
        "--tasks",
        help="comma-separated tasks whose figures to draw, e.g. circle-3 (default: every task's, "
        "and the overview)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.build import canonical_task, is_class_path
    from sili_robots.plotting import plot_sweep

    formats = list(dict.fromkeys(f.strip() for f in args.formats.split(",") if f.strip()))
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ConfigError(
            f"unknown figure format {', '.join(map(repr, bad)) or repr(args.formats)}; allowed: "
            f"{', '.join(FORMATS)}"
        )
    tasks = None
    if args.tasks is not None:
        given = [t.strip() for t in args.tasks.split(",") if t.strip()]
        tasks = list(dict.fromkeys(t if is_class_path(t) else canonical_task(t) for t in given))
        if not tasks:  # "" is a slip, not "all"
            raise ConfigError(f"--tasks {args.tasks!r} names none; leave it out for every task")
    if args.out is not None:
        writable_dir(args.out, "--out")
    elif args.sweep_dir.is_dir():  # its figures folder; else plot_sweep names what it is
        writable_dir(args.sweep_dir / FIGURES, "--out (its default)")
    for path in plot_sweep(
        args.sweep_dir,
        args.out,
        smooth=args.smooth,
        window=args.window,
        formats=formats,
        include_unfinished=args.include_unfinished,
        tasks=tasks,
    ):
        print(path)
    return 0
