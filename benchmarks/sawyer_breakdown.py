"""Where a Sawyer-Reach run's end effector goes, against what the task rewards.

Reads finished Sawyer-Reach runs (their ``checkpoint.pt``, which holds the whole replay) and
prints, per block of ``--block`` interactions: the share of interactions that end above the
height plane (the opponent keeps its goal only then), the true stability, the end effector's
closest approach to the true goal and to any goal, how far it travelled from the start, the
goal it came closest to against the true one, the goal signal (how much the interaction's
task reward would have differed between the three goals: all the previous interaction tells the
latent model about the goal), the latent categories used and how often the
category changed, and the entropy temperature alpha. Then, for the last block, the goals behind
each raw encoder category (before categories are merged), which tells an encoder that does not
separate the goals from a merge that joined categories that did.

    python benchmarks/sawyer_breakdown.py RUN [RUN ...] [--block 250]

Why: a run that stays near the start (standing still, 0.21 m from every goal, below the plane)
has to be told apart from one that reaches a goal and fails to rise, or rises and fails to
reach: each points to a different missing piece.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from sili_robots.agent.agent import SILIAgent
from sili_robots.commands.common import positive_int
from sili_robots.diagnostics import category_strategies
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.evaluation import load_trained
from sili_robots.metrics import kept
from sili_robots.tasks.sawyer_reach import SawyerReachEnv
from sili_robots.tasks.sawyer_scene import GOALS


def load_run(run: Path) -> tuple[SILIAgent, SawyerReachEnv, pd.DataFrame]:
    """The run's agent (with its whole replay), its task and its metrics, loaded once."""
    cfg, env, agent, _ = load_trained(run)
    task = env.unwrapped
    if not isinstance(task, SawyerReachEnv):
        raise ConfigError(f"{run}: a Sawyer-Reach run is needed, got task {cfg.task!r}")
    return agent, task, pd.read_csv(run / "metrics.csv").iloc[: agent.buffer.n]


def trajectories(agent: SILIAgent, task: SawyerReachEnv, m: pd.DataFrame) -> pd.DataFrame:
    """Per stored interaction: end height, closest approaches, travel, the goal it went for."""
    n = agent.buffer.n
    ee = agent.buffer.obs[:n, :, :3].astype(np.float64)  # (interactions, H + 1, 3)
    goal = agent.buffer.strategy_id[:n].astype(int)
    to_goals = np.linalg.norm(ee[:, :, None, :] - GOALS[None, None], axis=-1)  # (n, H+1, 3)
    closest = to_goals.min(axis=1)  # (n, 3): closest approach to each goal
    returns = -to_goals[:, 1:].sum(axis=1)  # (n, 3): the task reward under each goal
    replayed = returns[np.arange(n), goal]
    if not np.allclose(replayed, m["task_reward"], atol=1e-3):
        raise ConfigError("the replay does not match metrics.csv; was the run extended?")
    return pd.DataFrame(
        {
            "interaction": np.arange(n),
            "goal": goal,
            "above plane": ee[:, -1, 2] > task.plane_z,
            "stable": kept(m).to_numpy(),
            "to true goal": closest[np.arange(n), goal],
            "to any goal": closest.min(axis=1),
            "went for true": closest.argmin(axis=1) == goal,
            "goal signal": returns.max(axis=1) - returns.min(axis=1),
            "travel": np.linalg.norm(ee - task.start, axis=-1).max(axis=1),
            "end z": ee[:, -1, 2],
            "category": m["latent_category"].to_numpy(),
            "changed": m["latent_changed"].to_numpy(),
            "alpha": m["alpha"].to_numpy(),
            "reward": m["task_reward"].to_numpy(),
        }
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--block", type=positive_int, default=250)
    args = p.parse_args()
    torch.set_num_threads(1)
    for run in args.runs:
        agent, task, metrics = load_run(run)
        print(f"{run.name} (plane z = {task.plane_z:.2f} m, start z = {task.start[2]:.2f} m):")
        t = trajectories(agent, task, metrics)
        print(
            "  interactions  above plane  stable  to true / any goal (m)  went for true  "
            "goal signal  travel (m)  end z (m)  categories  changed  alpha   reward"
        )
        for start, g in t.groupby(t["interaction"] // args.block * args.block):
            print(
                f"  {start:5d}-{start + len(g) - 1:<5d}  {g['above plane'].mean():11.2f}  "
                f"{g.stable.mean():6.2f}  {g['to true goal'].mean():10.3f} / "
                f"{g['to any goal'].mean():.3f}  {g['went for true'].mean():13.2f}  "
                f"{g['goal signal'].mean():11.2f}  {g.travel.mean():10.3f}  "
                f"{g['end z'].mean():9.3f}  "
                f"{g.category.nunique():10d}  {g.changed.mean():7.2f}  "
                f"{g.alpha.mean():.4f}  {g.reward.mean():7.2f}"
            )
        raw, merged = category_strategies(agent, args.block)
        if raw:
            print(f"  category -> {{goal: interactions}}, last {args.block}: raw {raw}")
            print(f"  after merging {merged}")


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
