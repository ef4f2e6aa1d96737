"""Why a Detour Speaker-Listener run does or does not take the detour.

Reads finished Speaker-Listener runs (their ``checkpoint.pt``, which holds the whole replay) and
prints, per block of ``--block`` interactions: how many interactions came within the visit
radius of the speaker (which keeps its code for the next interaction), the true stability, the
task reward of interactions with and without a visit, and the entropy temperature alpha. Then
what the run's return weighs at the end: the stability term paid per interaction
(b x R_stable: minus the strategy-changed flags the ego saw, one per change on v1) next to the
task term ((1 - b) x the task reward) and the detour's task cost by the stored bounds
(stabilizing against the scripted oracle).

    python benchmarks/speaker_listener_breakdown.py RUN [RUN ...] [--block 150]

Why: on this task the detour pays through the task reward only once the ego can decode a
speaker that stays put; until then only the stability term pays for it, so its size against
the detour's cost decides whether the detour is ever found.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from sili_robots.bounds import stored_bounds
from sili_robots.commands.common import positive_int
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.evaluation import load_trained
from sili_robots.metrics import kept
from sili_robots.tasks.speaker_listener import VISIT_RADIUS, SpeakerListenerEnv


def visits(run: Path) -> tuple[np.ndarray, pd.DataFrame, SpeakerListenerEnv, object]:
    """Per stored interaction: whether the ego came within the visit radius of the speaker."""
    cfg, env, agent, _ = load_trained(run)
    task = env.unwrapped
    if not isinstance(task, SpeakerListenerEnv):
        raise ConfigError(f"{run}: a Speaker-Listener run is needed, got task {cfg.task!r}")
    n = agent.buffer.n
    positions = agent.buffer.obs[:n, :, :2]  # (interactions, H, 2): the ego's position
    near = np.linalg.norm(positions - task.speaker, axis=-1) <= VISIT_RADIUS
    return near.any(axis=1), pd.read_csv(run / "metrics.csv"), task, cfg


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--block", type=positive_int, default=150)
    args = p.parse_args()
    torch.set_num_threads(1)
    for run in args.runs:
        visited, m, task, cfg = visits(run)
        m = m.iloc[: len(visited)].assign(visited=visited, stable=kept(m))
        print(f"{run.name} ({cfg.task_id}, speaker at {tuple(task.speaker)}):")
        print("  interactions   visited  true stability  reward visited / not  alpha  b")
        for start, g in m.groupby(m["interaction"] // args.block * args.block):
            on, off = g[g.visited]["task_reward"], g[~g.visited]["task_reward"]
            print(
                f"  {start:5d}-{start + len(g) - 1:<5d}  {g.visited.mean():7.2f}  "
                f"{g.stable.mean():14.2f}  {on.mean() if len(on) else float('nan'):8.1f} / "
                f"{off.mean():6.1f}  {g.alpha.mean():.3f}  {g.beta.mean():.2f}"
            )
        tail = m.tail(100)
        b = float(tail["beta"].mean())
        bounds = stored_bounds(cfg.task_id)
        cost = bounds["oracle"]["task_reward"] - bounds["stabilizing"]["task_reward"]
        stable_term = b * tail["stability_reward"].mean()
        task_term = (1 - b) * tail["task_reward"].mean()
        print(
            f"  last 100: stability term b x R_stable {stable_term:.2f} per interaction, task "
            f"term (1 - b) x R_task {task_term:.1f}"
            f"; the detour costs the task term {(1 - b) * cost:.1f} (stabilizing against oracle, "
            f"{cost:.2f} by the bounds) and can save at most b x 1 = {b:.2f} of the stability term"
        )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
