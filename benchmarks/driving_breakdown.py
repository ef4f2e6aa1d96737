"""Where a Driving run's collisions come from.

Reads finished Driving runs (their ``checkpoint.pt``, which holds the whole replay) and prints,
over the last ``--window`` interactions: the ego's lane at the red line (after decision step 2,
which decides the opponent's next merge) and when the opponent cuts in (after step 5), against
the lane the opponent merged into (the true strategy), with the collision rate of each; the
decision step at which the collisions happened (the opponent cuts in at step 5; later ones are
the hazard); the latent categories used and how often the category changed; the entropy
temperature alpha; the lanes behind each latent category, as the encoder gives it and after the
package merges categories whose decoder heads predict alike.

With ``--phases N`` it prints instead, for every N interactions of the whole run: the share of
interactions with the ego in the left lane at the red line (which makes the opponent merge right,
the non-colliding hold), the share the opponent merged right, collisions, true stability, the
mean entropy temperature alpha and stability weight b: when a run settled on a lane, and whether
it was still exploring then.

    python benchmarks/driving_breakdown.py RUN [RUN ...] [--window 200] [--phases 250]

Why: a run that holds the opponent and still collides in every interaction (the stable
equilibrium of passing on the right) has to be told apart from one that fails to hold it.
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
from sili_robots.metrics import kept, kept_fraction
from sili_robots.tasks.driving import DrivingEnv

LANES = {0.0: "right", 1.0: "centre", 2.0: "left"}
RED_LINE_STEP = 2  # the observation after decision step 2: where the ego crossed the red line
CUT_IN_STEP = 5  # ... after step 5: where the ego was when the opponent cut in


def _side(y: np.ndarray) -> np.ndarray:
    """Lane of a lateral position in lane widths from the centre lane (left positive)."""
    return np.where(y > 0.5, "left", np.where(y < -0.5, "right", "centre"))


def load_run(run: Path) -> tuple[SILIAgent, pd.DataFrame]:
    """The run's agent (with its whole replay) and its metrics; the task is closed at once, as
    only the replay is read (libsumo allows one live simulation per process)."""
    cfg, env, agent, _ = load_trained(run)
    env.close()
    if not isinstance(env.unwrapped, DrivingEnv):
        raise ConfigError(f"{run}: a Driving run is needed, got task {cfg.task!r}")
    return agent, pd.read_csv(run / "metrics.csv").iloc[: agent.buffer.n]


def breakdown(run: Path, window: int) -> None:
    agent, metrics = load_run(run)
    n = agent.buffer.n
    obs, rew = agent.buffer.obs[n - window : n], agent.buffer.rew[n - window : n]
    m = metrics.iloc[n - window : n]
    hit = (rew < 0).any(axis=1)
    table = pd.DataFrame(
        {
            "ego at red line": _side(obs[:, RED_LINE_STEP, 1]),
            "ego at cut-in": _side(obs[:, CUT_IN_STEP, 1]),
            "opponent merged": m["strategy_id"].map(LANES),
            "hit": hit,
        }
    )
    keys = ["ego at red line", "ego at cut-in", "opponent merged"]
    pairs = table.groupby(keys)["hit"].agg(["size", "mean"])
    pairs.columns = ["interactions", "collision rate"]
    steps = pd.Series(rew[hit].argmin(axis=1)).value_counts().sort_index().to_dict()
    cats = m["latent_category"].value_counts().to_dict()
    print(
        f"{run.name}: last {window}: collisions {hit.mean():.2f}, true stability "
        f"{kept_fraction(m):.2f}, alpha {m['alpha'].iloc[-1]:.4f}\n"
        f"  collision decision steps {steps}; latent categories {cats}, changed in "
        f"{m['latent_changed'].mean():.2f}"
    )
    print("  " + pairs.round(2).to_string().replace("\n", "\n  "))
    raw, merged = category_strategies(agent, window)
    print(f"  category -> {{opponent lane: interactions}}: raw {_lanes(raw)}")
    print(f"  after merging {_lanes(merged)}")


def phases(run: Path, size: int) -> pd.DataFrame:
    """One row per ``size`` interactions of the whole run (see the module's docstring)."""
    agent, m = load_run(run)
    n = agent.buffer.n
    table = pd.DataFrame(
        {
            "left at red line": _side(agent.buffer.obs[:n, RED_LINE_STEP, 1]) == "left",
            "opponent merged right": m["strategy_id"].map(LANES).to_numpy() == "right",
            "collisions": (agent.buffer.rew[:n] < 0).any(axis=1),
            "true stability": kept(m).to_numpy(),
            "alpha": m["alpha"].to_numpy(),
            "b": m["beta"].to_numpy(),
        }
    )
    start = (np.arange(n) // size) * size
    out = table.groupby(start).mean()
    out.index = [f"{i}-{min(i + size, n) - 1}" for i in out.index]
    return out


def _lanes(split: dict[int, dict]) -> dict[int, dict[str, int]]:
    return {c: {LANES[float(s)]: k for s, k in per.items()} for c, per in split.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--window", type=positive_int, default=200)
    p.add_argument("--phases", type=positive_int, help="a row per this many interactions instead")
    args = p.parse_args()
    torch.set_num_threads(1)
    for run in args.runs:
        if args.phases:
            print(f"{run.name}:\n{phases(run, args.phases).round(4).to_string()}")
        else:
            breakdown(run, args.window)


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
