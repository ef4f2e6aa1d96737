"""How well the encoder foresees the opponent's moves: pooled features alone (the reference)
against pooled features plus the last transition (``latent_last_step``), on one replay.

A SILI run cannot say this cleanly: its own latent decides where the ego goes, so two encoders
would see two replays. Here a scripted ego plays Circle (3 Goals) the way SILI runs do: for 300
interactions it wanders (random or true location, ends anywhere at radius 0.3-1.2, action noise
0.5), then it goes to the opponent and ends just outside (radius ~ N(1.07, 0.025)), except for
3% of interactions ended clearly inside (radius 0.4-0.9, a move on purpose), 3% ended at the edge
inside (0.93-1.0, a slip) and 3% played at a wrong location (a wrong latent). Each encoder
learns online from the same interactions with the agent's own update and category
refresh, then labels 1,000 more as they arrive. Counts use ``diagnostics.foresight_by_exit``,
as ``circle_reward_breakdown.py`` does for runs.

    python benchmarks/bench_encoder_foresight.py [--interactions 3000] [--seeds 0,1]
        [--updates 5]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from sili_robots.addons import build_addons
from sili_robots.agent import SILIAgent
from sili_robots.agent.matmul import machine_key
from sili_robots.build import make_run_config
from sili_robots.commands.common import positive_int
from sili_robots.diagnostics import foresight_by_exit
from sili_robots.errors import one_line_errors
from sili_robots.rollout import play_interaction
from sili_robots.sweep import parse_seeds
from sili_robots.tasks.registry import make_task

WANDER = 300  # interactions of wandering before the scripted ego holds the opponent
SETTLED = 400  # counts start here (the runs' breakdowns use 400 on as well)


def scripted_policy(task, rng: np.random.Generator, j: int) -> Callable[[np.ndarray], np.ndarray]:
    """One interaction's policy: go to a location, then to the chosen end radius."""
    if j < WANDER:
        loc = task.location if rng.random() < 0.5 else int(rng.integers(3))
        end, noise = rng.uniform(0.3, 1.2), 0.5
    else:
        loc = task.location if rng.random() < 0.97 else (task.location + rng.integers(1, 3)) % 3
        u = rng.random()
        if u < 0.03:
            end = rng.uniform(0.4, 0.9)
        elif u < 0.06:
            end = rng.uniform(0.93, 0.999)
        else:
            end = max(1.0, rng.normal(1.07, 0.025))
        noise = 0.2
    unit = np.array([np.cos(task.angles[loc]), np.sin(task.angles[loc])])
    step = [0]

    def act(obs: np.ndarray) -> np.ndarray:
        target = unit * (1.0 if step[0] < task.horizon - 3 else end)
        step[0] += 1
        a = (target - task.position) / 0.1 + rng.normal(0.0, noise, 2)
        return np.clip(a, -1.0, 1.0).astype(np.float32)

    return act


def run(last_step: bool, seed: int, interactions: int, updates: int) -> dict[str, dict]:
    env = make_task("circle-3-v0")  # where the hold ends on the circle (RESULTS.md's search)
    task = env.unwrapped
    rng = np.random.default_rng(100 + seed)  # the same replay for both encoders of a seed
    cfg = make_run_config("circle-3-v0", "sili", settings={"addons.last_step": last_step})
    addons = build_addons(cfg.addons, cfg.agent)
    agent = SILIAgent(cfg.agent, 3, 2, task.horizon, task.strategy_dim, seed=seed, addons=addons)
    obs, info = env.reset(seed=seed)
    radius = []
    for j in range(interactions + 1000):
        played = play_interaction(env, obs, info, scripted_policy(task, rng, j))
        obs, info = played.next_obs, played.next_info
        agent.observe_interaction(
            played.obs, played.act, played.rew, obs, played.strategy_id, info, refresh=False,
        )  # fmt: skip
        radius.append(float(np.linalg.norm(played.obs[-1, :2])))
        if j < interactions and (j + 1) % 100 == 0:
            agent.update_latent_model(100 * updates)
            agent.refresh_latents()
    n = agent.buffer.n
    df = pd.DataFrame(
        {
            "strategy_id": agent.buffer.strategy_id[:n],
            "latent_category": agent.Z[1 : n + 1].argmax(-1),
        }
    )
    trained = foresight_by_exit(df.iloc[:interactions], np.array(radius), start=SETTLED)
    held_out = foresight_by_exit(df, np.array(radius), start=interactions)
    return {"trained on": trained, "held out": held_out}


def line(c: dict[str, int]) -> str:
    return (
        f"inside {c['foreseen_inside']:3d}/{c['inside']:3d}  edge {c['foreseen_edge']:3d}/"
        f"{c['edge']:3d}  false alarms {c['false_alarms']:4d}"
    )


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--interactions", type=positive_int, default=3000)
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--updates", type=positive_int, default=5, help="latent updates per interaction")
    args = p.parse_args()
    torch.set_num_threads(1)
    print(f"machine: {machine_key()}", flush=True)  # the seconds' CPU
    seeds = parse_seeds(args.seeds)
    totals: dict[str, dict[str, dict[str, int]]] = {}
    for seed in seeds:
        for label, last in (("pooled (reference)", False), ("pooled + last step", True)):
            t = time.perf_counter()
            out = run(last, seed, args.interactions, args.updates)
            print(f"seed {seed}, {label} ({time.perf_counter() - t:.0f} s)")
            for part, c in out.items():
                print(f"  {part:10s} {line(c)}")
                acc = totals.setdefault(label, {}).setdefault(part, {})
                for k, v in c.items():
                    acc[k] = acc.get(k, 0) + v
    print("all seeds (moves foreseen / moves, by how the causing interaction ended):")
    for label, parts in totals.items():
        for part, c in parts.items():
            print(f"  {label:20s} {part:10s} {line(c)}")
    ref, new = totals["pooled (reference)"], totals["pooled + last step"]
    for part in ref:
        missed_ref = ref[part]["inside"] - ref[part]["foreseen_inside"]
        missed_new = new[part]["inside"] - new[part]["foreseen_inside"]
        print(
            f"  {part}: moves on purpose missed, last step / reference: {missed_new} / {missed_ref}"
        )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
