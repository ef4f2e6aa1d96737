"""Controller ablation on Sawyer-Reach: mink IK (default) vs robosuite's OSC vs joint velocity.

A fixed set of Cartesian targets: the three goals, the three points just above the height plane
over them (where the stabilizing reference ends), and 14 points drawn once (seed 0) in the box
x in [-0.25, 0.35], y in [-0.35, 0.35], z in [0.83, 1.25] m. For every controller and target a
fresh interaction starts at the home pose and, for H = 50 control steps (2.5 s), the action moves
the commanded Cartesian target toward the point at the maximum speed (0.4 m/s per axis), the
same command stream every controller receives (``sawyer_reach.action_toward``). Reported per
controller:

- reach success: end effector within 1 cm of the target at the end of the interaction;
- final error: distance at the end (median and worst, mm);
- steps to 1 cm: first step within 1 cm (median over targets that got there);
- tracking lag: mean distance between the commanded target and the end effector over the steps
  that moved the commanded target;
- time per control step: wall time of ``env.step`` (controller + 25 physics substeps), mean.

And, pressing into the table: for each goal a fresh interaction reaches it for ``PRESS_AFTER``
steps, then commands straight down at full speed for the rest (the table stops the hand; an agent
overshooting a goal does this); reported is the hand's largest sideways slide from where the
pressing began (mm, worst goal), with no sideways command.

    python benchmarks/bench_sawyer_controllers.py [--extra 14] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import non_negative_int
from sili_robots.commands.common import seed as seed_number
from sili_robots.controllers import CONTROLLER_NAMES
from sili_robots.errors import one_line_errors
from sili_robots.tasks import make_task
from sili_robots.tasks.sawyer_reach import RISE_MARGIN, action_toward
from sili_robots.tasks.sawyer_scene import GOALS, PLANE_Z

BOX_LOW = np.array([-0.25, -0.35, 0.83])
BOX_HIGH = np.array([0.35, 0.35, 1.25])
REACHED = 0.01  # m
PRESS_AFTER = 15  # steps toward a goal before pressing down
DOWN = np.array([0.0, 0.0, -1.0], np.float32)


def targets(extra: int, seed: int) -> np.ndarray:
    above = GOALS.copy()
    above[:, 2] = PLANE_Z + RISE_MARGIN
    box = np.random.default_rng(seed).uniform(BOX_LOW, BOX_HIGH, (extra, 3))
    return np.vstack([GOALS, above, box])


def run(controller: str, points: np.ndarray) -> dict[str, object]:
    env = make_task("sawyer-reach", controller=controller)
    task = env.unwrapped
    env.reset(seed=0)
    finals, first, lags, step_times = [], [], [], []
    for i, point in enumerate(points):
        if i:
            env.reset()
        hit = None
        for t in range(task.horizon):
            action = action_toward(task, point)
            before = task.controller.target.copy()
            t0 = time.perf_counter()
            env.step(action)
            step_times.append(time.perf_counter() - t0)
            ee = task.scene.ee_pos
            if not np.allclose(task.controller.target, before):  # lag only while it moves
                lags.append(float(np.linalg.norm(task.controller.target - ee)))
            if hit is None and np.linalg.norm(ee - point) < REACHED:
                hit = t + 1
        finals.append(float(np.linalg.norm(task.scene.ee_pos - point)))
        first.append(hit)
    env.close()
    finals_a = np.array(finals)
    hits = [h for h in first if h is not None]
    return {
        "success": int(np.sum(finals_a < REACHED)),
        "median_mm": 1000 * float(np.median(finals_a)),
        "worst_mm": 1000 * float(finals_a.max()),
        "steps_to_1cm": float(np.median(hits)) if hits else float("nan"),
        "lag_mm": 1000 * float(np.mean(lags)),
        "ms_per_step": 1000 * float(np.mean(step_times)),
        "failed": [i for i, f in enumerate(finals) if f >= REACHED],
    }


def press_slide(controller: str) -> float:
    """The largest sideways slide (mm, worst goal) while pressing down onto the table."""
    env = make_task("sawyer-reach", controller=controller)
    task = env.unwrapped
    env.reset(seed=0)
    slides = []
    for i, goal in enumerate(GOALS):
        if i:
            env.reset()
        for _ in range(PRESS_AFTER):
            env.step(action_toward(task, goal))
        start = task.scene.ee_pos[:2].copy()
        slide = 0.0
        for _ in range(task.horizon - PRESS_AFTER):
            env.step(DOWN)
            slide = max(slide, float(np.linalg.norm(task.scene.ee_pos[:2] - start)))
        slides.append(slide)
    env.close()
    return 1000 * max(slides)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--extra",
        type=non_negative_int,
        default=14,
        help="random workspace targets (default %(default)s)",
    )
    parser.add_argument(
        "--seed", type=seed_number, default=0, help="of the random targets (default %(default)s)"
    )
    args = parser.parse_args()
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU
    points = targets(args.extra, args.seed)
    n = len(points)
    print(f"{n} targets, H = 50 steps of 50 ms; success = within {REACHED * 100:.0f} cm at the end")
    header = (
        f"{'controller':<15} {'success':>8} {'median mm':>10} {'worst mm':>9} "
        f"{'steps to 1cm':>13} {'lag mm':>7} {'ms/step':>8} {'press slide mm':>15}"
    )
    print(header)
    results = {}
    for name in CONTROLLER_NAMES:
        r = run(name, points)
        results[name] = r
        print(
            f"{name:<15} {r['success']:>5}/{n:<2} {r['median_mm']:>10.2f} {r['worst_mm']:>9.2f} "
            f"{r['steps_to_1cm']:>13.1f} {r['lag_mm']:>7.1f} {r['ms_per_step']:>8.2f} "
            f"{press_slide(name):>15.1f}"
        )
    for name, r in results.items():
        for i in r["failed"]:
            print(f"  {name}: target {i} {np.round(points[i], 3).tolist()} not reached")
    base = results["mink"]["ms_per_step"]
    for name, r in results.items():
        print(f"time per step relative to mink: {name} {r['ms_per_step'] / base:.2f}x")


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
