"""``sili grid``: run the paper's experiment grid block by block, resumably, collecting results."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sili_robots.commands.common import counted, float_in, path_arg, positive_int

if TYPE_CHECKING:
    from sili_robots.sweep import SweepSpec

#: where the grid at its budgets trains and collects
SWEEP_DIR, COLLECTION = Path("sweeps/paper-grid"), Path("results/paper-grid")


def add_parser(sub: argparse._SubParsersAction) -> None:
    from sili_robots.paper_grid import BLOCKS, TASKS

    p = sub.add_parser(
        "grid",
        help="the paper's experiment grid: run it (resumably) and collect its finished runs",
        description="Runs the grid's blocks in order (each block on each task is one sweep "
        "invocation into SWEEP_DIR, so an interrupted grid resumes where it stopped) and after "
        "each invocation copies the finished runs into the collection (`sili collect`). Runs "
        "already in the collection count as done, so a fresh clone does not train them again. "
        f"Blocks: {', '.join(b.name for b in BLOCKS)}.",
    )
    p.add_argument("--blocks", help="comma-separated blocks to run (default: all, in order)")
    p.add_argument("--tasks", help=f"comma-separated tasks (default: all of {', '.join(TASKS)})")
    p.add_argument(
        "--sweep-dir",
        type=path_arg,
        help="working sweep directory with checkpoints (default: sweeps/paper-grid)",
    )
    p.add_argument(
        "--into",
        type=path_arg,
        help="results collection (default: results/paper-grid)",
    )
    p.add_argument(
        "--fraction",
        type=lambda text: float_in(text, 0.0, 1.0, low_open=True),
        default=1.0,
        help="every budget times this, in (0, 1] (e.g. 0.01: a rehearsal of the whole grid in "
        "minutes), into a --sweep-dir and --into of its own; the claims judge full budgets only",
    )
    p.add_argument("--workers", type=positive_int, help="parallel runs (default: the CPU count)")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="list each invocation with how many of its runs are done; run none",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.commands.common import writable_dir
    from sili_robots.errors import ConfigError
    from sili_robots.paper_grid import BLOCKS, TASKS, block
    from sili_robots.sweep import LocalBackend, plan, run_sweep
    from sili_robots.sweep.collect import collect
    from sili_robots.sweep.spec import parse_list
    from sili_robots.sweep.state import check_collection_dir, check_sweep_dir, run_path

    elsewhere = _default_folders(args)
    if elsewhere and not args.dry_run:  # days of training, not a resume
        raise ConfigError(
            f"neither {SWEEP_DIR} nor {COLLECTION} exists here ({Path.cwd()}): run from the "
            "repository root to resume the grid and reuse its collected runs, or give "
            "--sweep-dir and --into to train it afresh there"
        )
    if args.fraction < 1.0:
        _check_own_folders(args)
    if args.sweep_dir.resolve() == args.into.resolve():
        raise ConfigError(
            f"--sweep-dir and --into are both {args.into}: the grid trains in one and collects "
            "the finished runs into the other; give two folders"
        )
    check_sweep_dir(args.sweep_dir, "--sweep-dir")  # before any run, in a dry run too
    check_collection_dir(args.into, "--into")
    for path, option in ((args.sweep_dir, "--sweep-dir"), (args.into, "--into")):
        if not args.dry_run:  # a listing reads only
            writable_dir(path, option)
    for option, text, allowed in (
        ("--blocks", args.blocks, BLOCKS),
        ("--tasks", args.tasks, TASKS),
    ):
        if text is not None and not parse_list(text):  # "" is a slip, not "all"
            names = ", ".join(getattr(a, "name", a) for a in allowed)
            raise ConfigError(
                f"{option} {text!r} names none; allowed: {names} (leave it out for all)"
            )
    blocks = [block(b) for b in parse_list(args.blocks)] if args.blocks else list(BLOCKS)
    if args.fraction < 1.0:
        blocks = [b.scaled(args.fraction) for b in blocks]
    tasks = tuple(parse_list(args.tasks)) if args.tasks else TASKS
    bad = [t for t in tasks if t not in TASKS]
    if bad:
        raise ConfigError(f"unknown grid task {bad[0]!r}; allowed: {', '.join(TASKS)}")
    if not any(b.specs(tasks) for b in blocks):
        raise ConfigError(
            f"blocks {', '.join(b.name for b in blocks)} run nothing on {', '.join(tasks)}; "
            "choose other blocks or tasks (sili grid --dry-run lists them all)"
        )
    dirs = (args.sweep_dir, args.into)  # a run is done in either (a fresh clone has no sweep)
    failed: dict[str, str] = {}  # run -> its error, as the sweep reports it
    planned = done = planned_interactions = done_interactions = 0
    steps = [(b, s) for b in blocks for s in b.specs(tasks)]
    steps = [(b, recorded(args.sweep_dir, s, args.into)) for b, s in steps]
    if not args.dry_run:  # before any run: a sweep never mixes two budgets under one name
        runs = [r for _, s in steps for r in plan([s])]
        _check_budgets(
            args,
            [r for r in runs if not _finished(run_path(args.into, r.name), r.config.interactions)],
        )
    for b, spec in steps:
        label = f"{b.name} on {spec.tasks[0]} ({counted(spec.interactions, 'interaction')})"
        runs = plan([spec])
        if args.dry_run:
            n_done = sum(
                any(_finished(run_path(d, r.name), spec.interactions) for d in dirs) for r in runs
            )
            print(f"{label}: {counted(len(runs), 'run')}, {n_done} done")
            planned, done = planned + len(runs), done + n_done
            planned_interactions += len(runs) * spec.interactions
            done_interactions += n_done * spec.interactions
            continue
        collected = [
            r.name for r in runs if _finished(run_path(args.into, r.name), spec.interactions)
        ]
        if len(collected) == len(runs):  # nothing to train (its settings may have moved on)
            print(
                f"grid: {label}: all {counted(len(runs), 'run')} collected",
                file=sys.stderr,
                flush=True,
            )
            continue
        print(f"grid: {label}", file=sys.stderr, flush=True)  # stdout: JSON lines alone
        if collected:  # back into the sweep, so it does not train them again
            collect([args.into], args.sweep_dir, names=collected)
        backend = LocalBackend(args.workers or os.cpu_count() or 1)
        report = run_sweep(spec, args.sweep_dir, backend, progress=False)
        failed.update(report.failed)
        got = collect([args.sweep_dir], args.into)
        line = {"block": b.name, "task": spec.tasks[0], "collected": got.added}
        print(json.dumps({**line, "replaced": got.replaced} if got.replaced else line))
    if args.dry_run:
        where = f"in {args.sweep_dir} or {args.into}"
        if elsewhere:
            where += ": neither exists here; run from the repository root, or give them"
        print(
            f"{done} of {counted(planned, 'run')} done, "
            f"{done_interactions:,} of {planned_interactions:,} interactions ({where})"
        )
    if failed:
        print(json.dumps({"failed": failed}))
    return 1 if failed else 0


def _default_folders(args: argparse.Namespace) -> bool:
    """Fill in the default folders; True when both were left out and neither exists here (a
    grid started outside the repository would train everything again)."""
    left_out = args.sweep_dir is None and args.into is None
    args.sweep_dir = SWEEP_DIR if args.sweep_dir is None else args.sweep_dir
    args.into = COLLECTION if args.into is None else args.into
    return left_out and not (SWEEP_DIR.exists() or COLLECTION.exists())


def _check_own_folders(args: argparse.Namespace) -> None:
    """A rehearsal (``--fraction``) never goes into the grid's own folders, here or in the
    repository this package is installed from: their runs have the same names."""
    from sili_robots.errors import ConfigError

    repository = Path(__file__).resolve().parents[2]
    grid = {
        p.resolve()
        for base in (Path.cwd(), repository)
        for p in (base / SWEEP_DIR, base / COLLECTION)
    }
    for path, option in ((args.sweep_dir, "--sweep-dir"), (args.into, "--into")):
        if path.resolve() in grid:
            raise ConfigError(
                f"--fraction {args.fraction:g} goes into a {option} of its own, not {path}: "
                f"{SWEEP_DIR} and {COLLECTION} hold the grid at its full budgets, in runs of "
                "the same names"
            )


def _check_budgets(args: argparse.Namespace, runs: list) -> None:
    """ConfigError when the sweep directory holds a planned run at another budget (e.g. a
    rehearsal at another ``--fraction``), before anything trains."""
    from sili_robots.errors import ConfigError
    from sili_robots.runs import CONFIG, recorded_run
    from sili_robots.sweep.state import run_path

    for r in runs:
        path = run_path(args.sweep_dir, r.name)
        if not (path / CONFIG).is_file():
            continue
        held = recorded_run(path).get("interactions")
        if held is not None and held != r.config.interactions:
            raise ConfigError(
                f"{args.sweep_dir} holds {r.name} at {held} interactions where this grid "
                f"(--fraction {args.fraction:g}) plans {r.config.interactions}: give the "
                "--fraction it ran with, or a --sweep-dir and --into of its own"
            )


def _finished(run_dir: Path, interactions: int) -> bool:
    """Done at the block's budget (a collection may hold a shorter run of the same name)."""
    from sili_robots.runs import DAMAGED_SUMMARY, SUMMARY, read_json

    summary = run_dir / SUMMARY
    if not summary.is_file():
        return False
    return read_json(summary, DAMAGED_SUMMARY, "interactions")["interactions"] == interactions


def recorded(sweep_dir: Path, spec: SweepSpec, collection: Path | None = None) -> SweepSpec:
    """The invocation as ``sweep_dir`` recorded it when this block already ran on this task, so
    a resumed grid keeps the defaults, kernels and task versions its runs started with; when
    ``sweep_dir`` has no record (a fresh clone), as its runs in ``collection`` were planned."""
    from sili_robots.errors import ConfigError
    from sili_robots.sweep.state import recorded_specs

    try:
        specs = recorded_specs(sweep_dir)
    except ConfigError:  # nothing recorded yet
        specs = []

    def key(s: SweepSpec) -> tuple:
        return (s.tasks, s.methods, s.seeds, s.interactions, s.betas, s.profile)

    found = next((r for r in specs if key(r) == key(spec)), None)
    if found is not None:
        return found
    return spec if collection is None else as_collected(collection, spec)


def as_collected(collection: Path, spec: SweepSpec) -> SweepSpec:
    """``spec`` with the settings recorded when it was first planned (kernel library, changed
    defaults, task version) read from one of its runs in ``collection``: another machine would
    plan its own kernel library, and the collected runs would no longer be the same runs."""
    from dataclasses import replace

    from sili_robots.agent.config import get_path
    from sili_robots.runs import CONFIG, read_config
    from sili_robots.sweep import plan
    from sili_robots.sweep.state import run_path

    for r in plan([spec]):
        run_dir = run_path(collection, r.name)
        if (run_dir / CONFIG).is_file():
            config = read_config(run_dir)  # ConfigError naming a damaged one
            overrides = {k: get_path(config.agent, k) for k in spec.agent_overrides}
            task_ids = {**spec.task_ids, config.task: config.task_id}
            return replace(spec, agent_overrides=overrides, task_ids=task_ids)
    return spec
