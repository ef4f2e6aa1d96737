"""Per-task tables of the paper grid, as in RESULTS.md, from a results collection alone.

    python benchmarks/grid_tables.py results/paper-grid [--tasks circle-8 driving]

One row per (method, profile, b, budget), methods in the paper's order, the b sweep last and
by b: each seed's task reward and true stability over its last 100 interactions, the mean and
score (0 = standing still, 1 = the scripted oracle), the first 50-interaction window of true
stability >= 0.9, the mean reward over the second half of the run, and the wall time per run
(one thread per run, two runs at a time). A row of shorter runs than the table's names their
length; SILI names its profile where the task's runs have both, and which one ``--method sili``
starts from there (the claims' SILI).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from sili_robots.claims import grid_names, run_finals
from sili_robots.errors import one_line_errors
from sili_robots.paper_grid import SEEDS, TASKS, block
from sili_robots.plot_data import load_results
from sili_robots.tasks import task_spec

NAMES = {  # in the paper's order
    "sili": "SILI",
    "oracle": "Oracle",
    "lili": "LILI",
    "sac": "SAC",
    "stable": "Stable",
    "smirl": "SMiRL",
}


def _seeds(values: pd.Series, fmt: str) -> str:
    return ", ".join(fmt.format(v) for v in values)


def _wall_minutes(source: Path, runs: pd.Series) -> str:
    minutes = []
    for run in runs:
        summary = source / "runs" / run / "summary.json"
        if summary.is_file():
            minutes.append(json.loads(summary.read_text())["wall_time_s"] / 60)
    if not minutes:
        return "-"
    low, high = f"{min(minutes):.0f}", f"{max(minutes):.0f}"
    return f"{low} min" if low == high else f"{low}-{high} min"


def _order(b_sweep: bool, method: str, profile: str, beta: float, logged: int) -> tuple:
    """Methods in the paper's order, the package profile first, the b sweep last by b."""
    rank = list(NAMES).index(method) if method in NAMES else len(NAMES)
    return (b_sweep, rank, profile != "package", beta, -logged)


def _label(
    task: str,
    *,
    b_sweep: bool,
    method: str,
    profile: str,
    beta: float,
    logged: int,
    full: int,
    profiles: set[str],
    seeds: list[int],
) -> str:
    """``SILI, paper profile, the task's default (seeds 0-4)``, ``Stable (1,000)``."""
    name = NAMES.get(method, method)
    if b_sweep:
        name += f" b={beta:g}"
    elif method == "sili" and len(profiles) > 1:
        name += f", {profile} profile"
        if profile == task_spec(task).sili_profile:
            name += ", the task's default"
    elif profile != "package":
        name += f" ({profile})"
    notes = [f"{logged:,}"] if logged != full else []
    if seeds != list(SEEDS):
        consecutive = seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2
        notes.append(
            f"seeds {seeds[0]}-{seeds[-1]}" if consecutive else f"seeds {_seeds(seeds, '{}')}"
        )
    return f"{name} ({', '.join(notes)})" if notes else name


def task_table(df: pd.DataFrame, source: Path, task: str) -> str:
    runs = df[df.task == task]
    finals = run_finals(runs)
    half = {
        run: float(g.sort_values("interaction")["task_reward"].iloc[len(g) // 2 :].mean())
        for run, g in runs.groupby("run")
    }
    finals["second_half"] = finals.run.map(half)
    lines = [
        f"**{task}** ({runs.task_id.iloc[0]}, {int(finals.logged.max()):,} interactions)",
        "",
        "| method | task reward (seeds) | mean | score | true stability (seeds) | first stable "
        "| mean reward, second half (seeds) | wall time per run |",
        "|---|---|---|---|---|---|---|---|",
    ]
    finals["b_sweep"] = finals.run.isin(grid_names(block("b-sweep"), task, "sili"))
    keys = ["b_sweep", "method", "profile", "config_beta", "logged"]
    full = int(finals.logged.max())
    profiles = set(finals.loc[(finals.method == "sili") & ~finals.b_sweep, "profile"])
    groups = sorted(finals.groupby(keys), key=lambda kg: _order(*kg[0]))
    for (b_sweep, method, profile, beta, logged), g in groups:
        g = g.sort_values("seed")
        name = _label(task, b_sweep=b_sweep, method=method, profile=profile, beta=beta,
                      logged=logged, full=full, profiles=profiles, seeds=list(g.seed))  # fmt: skip
        first = ", ".join("never" if pd.isna(v) else str(int(v)) for v in g.first_stable)
        lines.append(
            f"| {name} | {_seeds(g.task_reward, '{:.2f}')} | {g.task_reward.mean():.2f} "
            f"| {g.score.mean():.2f} | {_seeds(g.stability, '{:.2f}')} | {first} "
            f"| {_seeds(g.second_half, '{:.1f}')} | {_wall_minutes(source, g.run)} |"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("source", type=Path)
    p.add_argument("--tasks", nargs="+", choices=list(TASKS), default=list(TASKS))
    args = p.parse_args()
    df = load_results(args.source)
    found = [task for task in args.tasks if (df.task == task).any()]
    if not found:
        p.error(
            f"{args.source} has no runs of {', '.join(args.tasks)}; its tasks: "
            f"{', '.join(sorted(df.task.unique()))}"
        )
    for task in found:
        print(task_table(df, args.source, task), end="\n\n")
    missing = [task for task in args.tasks if task not in found]
    if missing:  # a partial collection: said, not skipped in silence
        print(f"no runs of {', '.join(missing)} in {args.source}", file=sys.stderr)


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
