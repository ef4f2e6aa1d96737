"""``sili plot SWEEP_DIR``: the paper-style figures of a sweep (PNG and PDF)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sili_robots.commands.common import counted, path_arg, positive_int, writable_dir
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
    from sili_robots.plot_data import LEFT_OUT, load_results
    from sili_robots.plotting import plot_results

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
    elif args.sweep_dir.is_dir():  # its figures folder; else load_results names what it is
        writable_dir(args.sweep_dir / FIGURES, "--out (its default)")
    results = load_results(args.sweep_dir, args.include_unfinished)
    written = plot_results(
        results,
        args.sweep_dir,
        args.out,
        smooth=args.smooth,
        window=args.window,
        formats=formats,
        tasks=tasks,
    )
    for path in written:
        print(path)
    _note_left_out(results.attrs[LEFT_OUT], tasks)
    _note_earlier_b_sweeps(written)
    return 0


def _note_left_out(left_out: list[tuple[str, str]], tasks: list[str] | None) -> None:
    """Unfinished runs are drawn only with --include-unfinished: named, so that a figure without
    a method or a seed is explained."""
    left = [run for run, task in left_out if tasks is None or task in tasks]
    if left:
        names = ", ".join(left[:3]) + (f" and {len(left) - 3} more" if len(left) > 3 else "")
        print(
            f"sili plot: note: left out {counted(len(left), 'unfinished run')} ({names}): "
            "--include-unfinished draws them",
            file=sys.stderr,
        )


def _note_earlier_b_sweeps(written: list[Path]) -> None:
    """A task's b-sweep figure from an earlier plot, beside a task figure drawn now without one
    (its runs at other b unfinished or gone), no longer matches it."""
    for path in written:
        earlier = path.with_name(f"{path.stem}_beta{path.suffix}")
        if path.stem != "overview" and earlier not in written and earlier.is_file():
            print(
                f"sili plot: note: {earlier} is an earlier plot's: this one draws no b sweep "
                f"for {path.stem}",
                file=sys.stderr,
            )
