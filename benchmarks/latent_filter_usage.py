"""What the within-interaction filter (``latent_filter``) did in runs: how many of the
opponent's moves it corrected and at which step, how often it left a right z^j (false alarms),
and what interactions after a move cost, beside the final task reward.

Runs without the filter print the same move counts and costs (no corrections), so an arm with
the filter reads against its unfiltered reference.

    python benchmarks/latent_filter_usage.py RUN [RUN ...] [--start 1600] [--window 100]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from sili_robots.commands.common import non_negative_int, positive_int
from sili_robots.diagnostics import filter_corrections
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.metrics import run_metrics
from sili_robots.runs import read_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument(
        "--start", type=non_negative_int, default=1600, help="count from this interaction"
    )
    parser.add_argument(
        "--window", type=positive_int, default=100, help="final reward over the last N"
    )
    args = parser.parse_args()
    rows = []
    for run in args.runs:
        read_config(run)  # a run directory, or a one-line error naming it
        df = run_metrics(run)  # metrics.csv, or a collected run's .csv.gz, checked
        if df is None:
            raise ConfigError(f"{run} has logged no interaction (no metrics.csv)")
        out = filter_corrections(df, args.start)
        rows.append(
            {
                "run": str(run),
                "interactions": len(df),
                f"final (last {args.window})": df["task_reward"].tail(args.window).mean(),
                **out,
            }
        )
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(pd.DataFrame(rows).round(2).to_string(index=False))


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
