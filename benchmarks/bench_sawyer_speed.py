"""Sawyer-Reach environment steps per second against robosuite's stock Sawyer environment.

Reference: ``robosuite.make("Lift", robots="Sawyer")`` with its default controller (BASIC
composite, OSC_POSE arm), control_freq 20, no renderer, no offscreen renderer, no camera
observations. Ours: ``make_task("sawyer-reach", controller=...)`` for every controller, through
gymnasium as users get it. Both at 20 Hz with robosuite's 2 ms physics step (25 substeps per
control step), seeded uniform random actions. Ours reset at the end of every 50-step interaction
and those resets are inside the timing; Lift is reset once before timing (its reset, a hard
reset that rebuilds the simulation, is timed separately) and runs fewer steps than its horizon.
Also the raw MuJoCo rate for the same 25 substeps (``mj_step(model, data, 25)`` in a loop,
nothing else) on our scene and on Lift's model: the physics-only ceiling no controller can beat.

Everything runs in this one process. Timed blocks are interleaved in rounds (Lift, then each of
ours, then the raw loops, again and again) and each environment keeps its fastest block, so a
burst of load from other work on the machine does not land on one side only.

    python benchmarks/bench_sawyer_speed.py [--rounds 5] [--block 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import copy
import logging
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import positive_int
from sili_robots.commands.common import seed as seed_number
from sili_robots.controllers import CONTROLLER_NAMES, robosuite_logging
from sili_robots.controllers.robosuite_logging import quiet_robosuite_import
from sili_robots.errors import one_line_errors
from sili_robots.tasks import make_task, task_spec
from sili_robots.tasks.sawyer_scene import N_SUBSTEPS, SawyerScene

Block = Callable[[int], None]
#: robosuite Lift's episode length (its default), which the timed steps of all rounds stay under
LIFT_HORIZON = 1000


def lift_blocks(seed: int) -> tuple[Block, Block, float]:
    """(env steps, raw physics steps, seconds per reset) on robosuite's stock Lift, Sawyer."""
    quiet_robosuite_import()
    import robosuite

    # its controller loader logs each config file it reads, at INFO: the table is the output
    logging.getLogger(robosuite_logging.LOGGER).setLevel(logging.WARNING)
    env = robosuite.make(
        "Lift",
        robots="Sawyer",
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        control_freq=20,
        horizon=LIFT_HORIZON,
    )
    arm = env.robots[0].part_controllers["right"]
    assert arm.name == "OSC_POSE", arm.name
    assert round(env.control_timestep / env.model_timestep) == N_SUBSTEPS
    low, high = env.action_spec
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    for _ in range(3):
        env.reset()
    reset_s = (time.perf_counter() - t0) / 3
    taken = 0

    def block(n: int) -> None:
        nonlocal taken
        taken += n
        assert taken < env.horizon, "Lift would hit its horizon; use fewer rounds or steps"
        for _ in range(n):
            env.step(rng.uniform(low, high))

    # the raw loop steps a copy of the reset state, so it never moves the timed Lift's robot
    raw_data = copy.copy(env.sim.data._data)  # MjData's copy: a new buffer, same state
    return block, raw_block(env.sim.model._model, raw_data), reset_s


def raw_block(model: mujoco.MjModel, data: mujoco.MjData) -> Block:
    def block(n: int) -> None:
        for _ in range(n):
            mujoco.mj_step(model, data, N_SUBSTEPS)

    return block


TASK_ID = task_spec("sawyer-reach").gym_id  # the current version, named in the output


def ours_block(controller: str, seed: int) -> tuple[Block, float]:
    env = make_task(TASK_ID, controller=controller)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    t0 = time.perf_counter()
    for _ in range(20):
        env.reset()
    reset_s = (time.perf_counter() - t0) / 20

    def block(n: int) -> None:
        env.reset()
        for _ in range(n):
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                env.reset()

    return block, reset_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=positive_int, default=5)
    parser.add_argument("--block", type=positive_int, default=300, help="steps per timed block")
    parser.add_argument("--seed", type=seed_number, default=0)
    args = parser.parse_args()
    lift_steps = args.block // 3  # the reference and OSC, slower, time a third of a block
    if lift_steps < 1:
        parser.error(f"--block {args.block}: give at least 3 (Lift and OSC time a third of it)")
    if lift_steps * args.rounds >= LIFT_HORIZON:  # (it is never reset between rounds)
        parser.error(
            f"--block {args.block} --rounds {args.rounds}: Lift would play {lift_steps} x "
            f"{args.rounds} steps, which must stay under its horizon of {LIFT_HORIZON}; give fewer"
        )
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU

    lift, lift_raw, lift_reset = lift_blocks(args.seed)
    resets = {"robosuite Lift": lift_reset}
    scene = SawyerScene("position")
    scene.reset()
    # (label, block, steps per block): slow environments get shorter blocks
    entries: list[tuple[str, Block, int]] = [
        ("robosuite Lift, Sawyer, OSC_POSE (reference)", lift, lift_steps)
    ]
    for name in CONTROLLER_NAMES:
        steps = lift_steps if name == "osc" else args.block
        block, resets[f"SawyerReach {name}"] = ours_block(name, args.seed)
        entries.append((f"{TASK_ID}, controller={name}", block, steps))
    entries.append(
        ("raw mj_step x25, Sawyer-Reach scene", raw_block(scene.model, scene.data), args.block)
    )
    entries.append(("raw mj_step x25, Lift model", lift_raw, args.block))

    best = {label: float("inf") for label, _, _ in entries}
    for _ in range(args.rounds):
        for label, block, steps in entries:
            t0 = time.perf_counter()
            block(steps)
            best[label] = min(best[label], (time.perf_counter() - t0) / steps)

    ref = 1.0 / best[entries[0][0]]
    print(
        f"control steps per second ({N_SUBSTEPS} physics substeps of 2 ms, 20 Hz); "
        f"best of {args.rounds} interleaved rounds"
    )
    print(f"{'environment':<50} {'steps/s':>9} {'x Lift':>7}")
    for label, _, _ in entries:
        rate = 1.0 / best[label]
        print(f"{label:<50} {rate:9.1f} {rate / ref:6.1f}x")
    print("reset: " + ", ".join(f"{k} {1000 * v:.1f} ms" for k, v in resets.items()))


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
