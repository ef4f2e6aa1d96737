"""Driving decision steps per second, resets included: libsumo (in-process) against TraCI.

The reference is the TraCI socket client driving the very same scenario and code path
(``DrivingEnv(backend="traci")``, a ``sumo`` subprocess). Both play the same seeded random
actions for the same number of interactions, one after the other in this process, and must
produce identical returns (checked). SUMO start-up is timed separately; the steps/s figures
cover ``reset()`` (loadState + re-applied vehicle settings) and ``step()`` only.

    python benchmarks/bench_driving.py [--interactions 100] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import positive_int
from sili_robots.commands.common import seed as seed_number
from sili_robots.errors import one_line_errors
from sili_robots.tasks.driving import DrivingEnv


def run(backend: str, interactions: int, seed: int) -> dict[str, float | list[float]]:
    t0 = time.perf_counter()
    env = DrivingEnv(backend=backend)
    env.reset(seed=seed)  # starts SUMO
    startup = time.perf_counter() - t0
    actions = np.random.default_rng(seed).uniform(-1, 1, (interactions, env.horizon, 1))
    returns = []
    steps = 0
    reset_time = 0.0
    t0 = time.perf_counter()
    for j in range(interactions):
        if j:
            r0 = time.perf_counter()
            env.reset()
            reset_time += time.perf_counter() - r0
        total = 0.0
        for a in actions[j].astype(np.float32):
            total += env.step(a)[1]
            steps += 1
        returns.append(total)
    elapsed = time.perf_counter() - t0
    env.close()
    return {
        "startup_s": startup,
        "steps_per_s": steps / elapsed,
        "reset_ms": 1000 * reset_time / max(interactions - 1, 1),
        "returns": returns,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--interactions", type=positive_int, default=100)
    parser.add_argument("--seed", type=seed_number, default=0)
    args = parser.parse_args()
    if args.interactions < 2:  # the first reset starts SUMO; the later ones are timed
        parser.error(f"--interactions {args.interactions}: give at least 2 (resets are timed)")
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU
    results = {b: run(b, args.interactions, args.seed) for b in ("libsumo", "traci")}
    if results["libsumo"]["returns"] != results["traci"]["returns"]:
        raise SystemExit("libsumo and TraCI runs differ: not the same scenario")
    steps = args.interactions * DrivingEnv().horizon
    print(f"Driving, {args.interactions} interactions ({steps} decision steps, 10 SUMO steps each)")
    print(f"{'backend':<10}{'start-up s':>12}{'reset ms':>10}{'decision steps/s':>18}")
    for name, r in results.items():
        print(f"{name:<10}{r['startup_s']:>12.3f}{r['reset_ms']:>10.2f}{r['steps_per_s']:>18.1f}")
    ratio = results["libsumo"]["steps_per_s"] / results["traci"]["steps_per_s"]
    print(f"libsumo / TraCI: {ratio:.1f}x (target >= 5x)")
    print(f"same returns on both: yes (mean {np.mean(results['libsumo']['returns']):.2f})")


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
