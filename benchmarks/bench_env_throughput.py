"""Environment throughput: steps per second of each light task, single env and vector envs.

Random actions, interaction boundaries included (resets count). The reference is gymnasium's
own ``Pendulum-v1`` (a similarly small classic-control env) run the same way in this process.
A vector env's step calls include its autoresets (gymnasium's next-step mode: one call in H + 1,
every 51st on these tasks, every 201st on Pendulum), so its rate counts them as steps.

    python benchmarks/bench_env_throughput.py [--steps 20000] [--num-envs 4]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import sili_robots  # noqa: F401  (registers the tasks)
from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import positive_int
from sili_robots.errors import one_line_errors
from sili_robots.tasks import TASKS


def single_rate(env_id: str, steps: int) -> float:
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(1000)]
    t = time.perf_counter()
    for i in range(steps):
        _, _, term, trunc, _ = env.step(actions[i % 1000])
        if term or trunc:
            env.reset()
    rate = steps / (time.perf_counter() - t)
    env.close()
    return rate


def vector_rate(env_id: str, steps: int, num_envs: int, mode: str) -> float:
    envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=mode)
    envs.reset(seed=0)
    envs.action_space.seed(0)
    batches = [envs.action_space.sample() for _ in range(250)]  # cycled, as the single env's
    n = steps // num_envs
    t = time.perf_counter()
    for i in range(n):
        envs.step(batches[i % 250])  # autoreset begins the next interaction
    rate = n * num_envs / (time.perf_counter() - t)
    envs.close()
    return rate


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--steps", type=positive_int, default=20_000)
    p.add_argument("--num-envs", type=positive_int, default=4)
    args = p.parse_args()
    if args.steps < args.num_envs:  # each vector step takes one step of every env
        p.error(f"--steps {args.steps} is fewer than --num-envs {args.num_envs}")
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU
    ids = [("Pendulum-v1 (reference)", "Pendulum-v1")]
    ids += [
        (name, spec.gym_id)
        for name, spec in TASKS.items()
        if name.startswith(("circle", "speaker"))
    ]
    print(
        f"{'task':26s} {'single':>10s} {'sync x' + str(args.num_envs):>10s} "
        f"{'async x' + str(args.num_envs):>10s}  (env steps/s)"
    )
    ref = None
    for label, env_id in ids:
        s = single_rate(env_id, args.steps)
        v = vector_rate(env_id, args.steps, args.num_envs, "sync")
        a = vector_rate(env_id, args.steps, args.num_envs, "async")
        ref = ref or s
        print(f"{label:26s} {s:10.0f} {v:10.0f} {a:10.0f}  single/Pendulum {s / ref:.2f}x")
    print(f"numpy {np.__version__}, gymnasium {gym.__version__}")


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
