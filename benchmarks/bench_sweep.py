"""Sweep overhead: wall time of the same small sweep on each backend, against spawn.

Every run gets a fresh worker process, so what a backend adds per run is process start-up
(importing torch and the package) and scheduling. The reference is the local pool with the
``spawn`` start method; the default local pool (``forkserver`` with the training code preloaded)
and Ray (a local instance, started before timing) run the very same runs, one after the other in
this process, into separate directories, and must produce identical metrics (checked).

    python benchmarks/bench_sweep.py [--runs 8] [--interactions 10] [--workers 2]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import tempfile
import time
from pathlib import Path

import pandas as pd

from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import positive_int
from sili_robots.errors import one_line_errors
from sili_robots.sweep import LocalBackend, NullMonitor, RayBackend, SweepSpec, run_sweep

FAST = {
    "updates_per_step": 0.1,
    "hidden": 32,
    "random_interactions": 3,
}


def _sweep(backend, out: Path, runs: int, interactions: int) -> float:
    spec = SweepSpec(
        tasks=["circle-3"],
        methods=["sac"],
        seeds=list(range(runs)),
        interactions=interactions,
        agent_overrides=FAST,
    )
    t0 = time.perf_counter()
    report = run_sweep(spec, out, backend, monitor=NullMonitor(), tensorboard_scalars=False)
    elapsed = time.perf_counter() - t0
    assert report.ok, report.failed
    return elapsed


def _metrics(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "results.csv").drop(columns="wall_time")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=positive_int, default=8)
    ap.add_argument("--interactions", type=positive_int, default=10)
    ap.add_argument("--workers", type=positive_int, default=2)
    args = ap.parse_args()
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU
    backends = {
        "local spawn (reference)": LocalBackend(args.workers, start_method="spawn"),
        "local forkserver (default)": LocalBackend(args.workers),
    }
    ray = None
    if importlib.util.find_spec("ray") is not None:
        import ray

        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        t0 = time.perf_counter()
        ray.init(num_cpus=args.workers, include_dashboard=False, log_to_driver=False)
        print(f"ray.init (local instance, not timed below): {time.perf_counter() - t0:.1f} s")
        backends["ray (local instance)"] = RayBackend(workers=args.workers)
    print(
        f"{args.runs} runs x {args.interactions} interactions of circle-3 sac, "
        f"{args.workers} workers, CPU count {os.cpu_count()}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        times, tables = {}, {}
        for name, backend in backends.items():
            out = Path(tmp) / name.split()[1]
            times[name] = _sweep(backend, out, args.runs, args.interactions)
            tables[name] = _metrics(out)
        ref_name = next(iter(backends))
        for name in backends:
            pd.testing.assert_frame_equal(tables[ref_name], tables[name])
        ref = times[ref_name]
        print(f"{'backend':28s} {'wall s':>8s} {'s per run':>10s} {'vs spawn':>9s}")
        for name, t in times.items():
            print(f"{name:28s} {t:8.1f} {t / args.runs:10.2f} {ref / t:8.2f}x")
        print("identical metrics on every backend: yes")
    if ray is not None:
        ray.shutdown()


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
