"""Sweep scaling: interactions per second of the same runs on one worker and on two.

Each worker is a process with one torch thread, so on a 2-core machine two workers should train
nearly twice the interactions per second of one; what falls short is the cores' shared caches
and memory bandwidth. The runs are the default SILI agent on Circle (3 Goals), a few random
interactions first, then learning ones, as a real sweep's runs are. The worker launcher starts
once before timing, and each arm runs twice, in both orders (1, 2, 2, 1 workers).

    python benchmarks/bench_sweep_scaling.py [--runs 2] [--interactions 30]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import positive_int
from sili_robots.errors import one_line_errors
from sili_robots.sweep import LocalBackend, NullMonitor, SweepSpec, run_sweep


def rate(workers: int, runs: int, interactions: int, out: Path) -> float:
    """Interactions per second of the whole sweep, start-up of its workers included."""
    spec = SweepSpec(
        tasks=["circle-3"],
        methods=["sili"],
        seeds=list(range(runs)),
        interactions=interactions,
        agent_overrides={"random_interactions": 5},
    )
    start = time.perf_counter()
    run_sweep(spec, out, LocalBackend(workers=workers), monitor=NullMonitor())
    return runs * interactions / (time.perf_counter() - start)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=positive_int, default=2)
    ap.add_argument("--interactions", type=positive_int, default=30)
    args = ap.parse_args()
    print(f"machine: {machine_key()}", flush=True)  # its instruction-set caps too
    rates: dict[int, list[float]] = {1: [], 2: []}
    with tempfile.TemporaryDirectory() as tmp:
        # untimed: the process that starts workers (preloading torch) starts once, for both
        rate(1, 1, 1, Path(tmp) / "warm-up")
        for i, workers in enumerate((1, 2, 2, 1)):  # each order once: drift cancels
            rates[workers].append(rate(workers, args.runs, args.interactions, Path(tmp) / str(i)))
    one, two = (sum(r) / len(r) for r in (rates[1], rates[2]))
    print(f"{args.runs} SILI runs x {args.interactions} interactions (circle-3, default agent)")
    print(f"1 worker:  {one:.3f} interactions/s (mean of {rates[1][0]:.3f}, {rates[1][1]:.3f})")
    print(
        f"2 workers: {two:.3f} interactions/s (mean of {rates[2][0]:.3f}, {rates[2][1]:.3f}), "
        f"{two / one:.2f}x one worker"
    )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
