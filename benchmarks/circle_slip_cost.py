"""What a slip costs a Circle run's policy, with and without the within-interaction filter.

A slip: the ego ends an interaction just inside the circle, the opponent moves on to the next
location, and the encoder, which reads that ending as a hold, gives the next interaction the
latent of the held location. From a run's checkpoint this plays the next interaction on that
latent (z^{j+1} of the run's last interaction, which ended outside) against the opponent held
and moved on, ``--plays`` times with the sampled action and once with the deterministic one:
first with the policy acting on z^{j+1} throughout (the paper's agent), then with the filter
(``latent_filter``, started from the checkpoint with ``--eps`` and ``--noise`` whatever the run's
own settings, so a run trained without it can be probed). Each play is reported as its task
reward and the step at which the filter first left z^{j+1} (-1: never).

    python benchmarks/circle_slip_cost.py RUN [RUN ...] [--eps 0.01] [--noise 0.25] [--plays 5]

Why: the margin a policy keeps outside the circle is priced by what a slip costs it
(benchmarks/RESULTS.md); the filter is meant to cut that cost to a few steps.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from sili_robots.addons.config import AddonsConfig
from sili_robots.addons.filter_math import first_departure
from sili_robots.addons.latent_filter import LatentFilter
from sili_robots.agent import SILIAgent
from sili_robots.agent.config import check as check_ranges
from sili_robots.commands.common import positive_int
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.evaluation import load_trained
from sili_robots.tasks.circle import CircleEnv


@torch.no_grad()
def play(
    agent: SILIAgent, task: CircleEnv, location: int, deterministic: bool
) -> tuple[float, int]:
    """Task reward of one interaction on the agent's next latent against the opponent at
    ``location``, and the step at which the filter (if running) first left that latent."""
    obs, _ = task.reset(options={"restart": True})
    task.location = location
    agent.begin_interaction()
    total = 0.0
    for _ in range(task.horizon):
        action = agent.act(obs, deterministic=deterministic)
        next_obs, reward, _, _, _ = task.step(action)
        agent.observe_step(obs, action, reward, next_obs)
        obs, total = next_obs, total + reward
    filters = [a for a in agent.addons if isinstance(a, LatentFilter)]
    return total, first_departure(filters[0].acted) if filters else -1


def with_filter(agent: SILIAgent, eps: float, noise: float) -> SILIAgent:
    """The agent with the filter running from now on (eps, noise), on its current model."""
    agent.detach_addon(LatentFilter)
    latent_filter = LatentFilter(eps, start=0, noise=noise)
    agent.attach_addon(latent_filter)  # no saved state: starts as a run with it would now
    return agent


def slip_costs(
    run: Path, eps: float, noise: float, plays: int
) -> dict[str, dict[str, list[tuple[float, int]]]]:
    """{"no filter" | "filter": {"held" | "moved on": [(reward, step), ...]}}; the last entry of
    each list is the deterministic play."""
    out = {}
    for label in ("no filter", "filter"):
        _, env, agent, state = load_trained(run)
        game = state["game"]
        task = env.unwrapped
        if label == "filter":
            with_filter(agent, eps, noise)
        else:
            agent.detach_addon(LatentFilter)
        held = int(game["fields"]["location"])
        where = {"held": held, "moved on": (held + 1) % len(task.angles)}
        out[label] = {
            name: [play(agent, task, loc, False) for _ in range(plays)]
            + [play(agent, task, loc, True)]
            for name, loc in where.items()
        }
        env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--eps", type=float, default=0.01, help="the filter's prior eps")
    parser.add_argument("--noise", type=float, default=0.25, help="latent_filter_noise")
    parser.add_argument("--plays", type=positive_int, default=5, help="sampled plays per case")
    args = parser.parse_args()
    settings = AddonsConfig().filter  # the run settings' own ranges (NaN and eps >= 1 too)
    settings.eps, settings.noise = args.eps, args.noise
    try:
        check_ranges(settings, "addons.filter.")
    except ConfigError as err:
        raise ConfigError(f"--eps / --noise: {err}") from None
    torch.set_num_threads(1)
    for run in args.runs:
        print(f"{run} (filter: eps {args.eps}, noise {args.noise}; last: deterministic)")
        for label, cases in slip_costs(run, args.eps, args.noise, args.plays).items():
            for name, rows in cases.items():
                rewards = np.array([r for r, _ in rows])
                steps = " ".join(str(s) for _, s in rows)
                print(
                    f"  {label:9s} {name:8s} mean {rewards.mean():7.2f}  "
                    f"plays {' '.join(f'{r:.1f}' for r in rewards)}  left z at {steps}"
                )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
