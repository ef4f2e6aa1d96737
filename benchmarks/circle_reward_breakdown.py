"""Where a Circle run's task reward goes, and what its critic believes at the circle's edge.

Reads finished Circle runs (their ``checkpoint.pt``, which holds the whole replay and the
networks) and prints, over the last ``--window`` interactions (Circle (Continuous) has no fixed
locations: only the first item, where its interactions ended and how its latent moved):

* the distance to the opponent summed over three phases of an interaction: the approach (first
  10 steps: from the start the opponent is 1 away, 0.1 per step), the middle, and the exit
  (last 10 steps, where a stabilizing ego steps out of the circle), next to the total;
* the location the opponent was held at, and the distance summed by a reference path to it: at
  each step the action on a 201 x 201 grid of the action box that comes closest to the opponent.
  The box lets the ego move faster along diagonals, so the locations differ: the top one (90
  degrees) costs 4.50, the lower two 3.54. Runs that hold different locations are compared
  against their own location's reference;
* the entropy temperature alpha at the end of the run;
* false latent changes: z^j differs from z^{j-1} while the true strategy stayed the same (and
  did not change one interaction before either, so a late catch-up is not counted), so
  interaction j is played conditioned on a strategy that is not there; their count, and the
  mean task reward of those interactions against those played with neither kind of change
  (``sili_robots.diagnostics.change_masks``), and how many true changes the latent foresaw
  (z^j changed with the strategy of interaction j) or showed one interaction late, with the
  foreseen ones split by how the interaction that caused them ended: clearly inside (final
  radius below 0.9, an exit inside on purpose) or near the edge (a slip); for continuous
  latents, how far z moved when the strategy changed against when it did not;
* the critic's min(Q1, Q2) on the last step of an interaction, standing at the circle's edge
  next to the held opponent, for radial actions that end within 0.1 of the edge, and the final
  radius of the policy's own (deterministic) action. The opponent is held by ending on or
  outside the edge (radius 1 + the task's ``outside_margin``: 1 on the -v0 tasks, 1.1 on v1),
  so a critic that knows this exactly peaks at or just past it, and where the interactions
  actually played ended (mean, spread and nearest to the centre): the margin a policy needs
  grows with that spread;
* for latent methods, the encoder's side of the same edge: the run's last interaction replayed
  with only its final position moved radially to within 0.1 of the edge (last action and
  reward rewritten to match), and the probability the encoder gives the category it predicts
  for the unmodified interaction. An encoder that has learned the rule switches category at
  the edge;
* for latent methods, what ending nearer the circle would cost: the last interaction replayed
  with its exit (last 10 steps) scaled radially so that it ends at the edge -0.10 ... +0.30
  (each step's distance outside radius 1 scaled by one factor, directions kept, actions and
  rewards rewritten to match), how far the encoder's z^{j+1} then lies from the one it gives
  the interaction as played, and the task reward of the next interaction played greedily on
  that z^{j+1} (and the played z^j) against the opponent where that ending leaves it (moved on
  inside the edge, held from it out). An encoder that has learned the rule gives the played
  z^{j+1} and reward from the edge out and a z^{j+1} that finds the moved opponent inside; one
  that changes gradually across the edge makes every ending near it cost the next
  interaction, and the policy's margin outside the circle pays for that. Next to it, how many
  interactions of the whole replay ended within 0.05 of the edge near the held location, on
  each side: the examples the encoder has to learn the edge from.

    python benchmarks/circle_reward_breakdown.py RUN [RUN ...] [--window 100]

Why: it splits a gap in task reward against Oracle into approach, hold and exit, so a change to
the method can be aimed at the phase that loses reward.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from sili_robots.agent import SILIAgent
from sili_robots.agent.latent import transitions
from sili_robots.commands.common import positive_int
from sili_robots.diagnostics import change_masks, foresight_by_exit
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.evaluation import load_trained
from sili_robots.metrics import kept_fraction
from sili_robots.tasks.circle import ARENA, STEP, CircleEnv

PHASE_STEPS = 10
RADIAL_ACTIONS = np.linspace(-1.0, 1.0, 9)
EDGE_STEPS = STEP * RADIAL_ACTIONS  # from the edge, one step of each radial action
CLEAR_INSIDE = 0.9  # a final radius below this is an exit inside on purpose, not a slip
EDGE_BAND = 0.05  # endings this close to the edge are where the encoder must tell the sides apart
EXIT_OFFSETS = np.array([-0.10, -0.05, -0.01, 0.01, 0.05, 0.10, 0.15, 0.20, 0.30, 0.40])


def edge(task: CircleEnv) -> float:
    """The radius where ending outside begins: 1 on the -v0 tasks, 1.1 on v1 (the margin)."""
    return 1.0 + task.outside_margin


def edge_radii(task: CircleEnv) -> np.ndarray:
    """Where one radial step from the edge ends: the critic's and the encoder's probes."""
    return edge(task) + EDGE_STEPS


def exit_radii(task: CircleEnv) -> np.ndarray:
    """Where the counterfactual exits end: around the task's edge, mostly outside it."""
    return edge(task) + EXIT_OFFSETS


def location_direction(task: CircleEnv, location: int) -> np.ndarray:
    """Unit vector to a location on the circle (the opponent's position when it is there)."""
    angle = task.angles[location]
    return np.array([np.cos(angle), np.sin(angle)], np.float32)


def load_run(run: Path) -> tuple[SILIAgent, CircleEnv, pd.DataFrame]:
    cfg, env, agent, _ = load_trained(run)
    task = env.unwrapped
    if not isinstance(task, CircleEnv):
        raise ConfigError(f"{run}: a Circle run is needed, got task {cfg.task!r}")
    return agent, task, pd.read_csv(run / "metrics.csv")


def phase_distances(agent: SILIAgent, window: int) -> dict[str, float]:
    n = agent.buffer.n
    dist = -agent.buffer.rew[n - window : n]  # (window, H): the task reward is -distance
    return {
        "total": float(dist.sum(1).mean()),
        "approach": float(dist[:, :PHASE_STEPS].sum(1).mean()),
        "middle": float(dist[:, PHASE_STEPS:-PHASE_STEPS].sum(1).mean()),
        "exit": float(dist[:, -PHASE_STEPS:].sum(1).mean()),
    }


def reference_cost(task: CircleEnv, location: int) -> float:
    """Distance summed over an interaction by the per-step closest-approach path."""
    grid = np.linspace(-1.0, 1.0, 201)
    actions = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    goal = location_direction(task, location)
    pos, total = task.start.astype(float), 0.0
    for _ in range(task.horizon):
        nxt = np.clip(pos + STEP * actions, -ARENA, ARENA)
        dist = np.linalg.norm(nxt - goal, axis=1)
        k = int(dist.argmin())
        pos, total = nxt[k], total + float(dist[k])
    return total


def final_radii(agent: SILIAgent) -> np.ndarray:
    """Where each interaction in the replay ended: the ego's distance from the centre."""
    return np.linalg.norm(agent.buffer.obs[: agent.buffer.n, -1, :2], axis=-1)


def edge_examples(
    agent: SILIAgent, task: CircleEnv, metrics: pd.DataFrame, location: int
) -> tuple[int, int]:
    """How many stored interactions against the opponent at ``location`` ended within
    ``EDGE_BAND`` of its edge near it (within 30 degrees): inside (each moved it on) and
    outside (each held it). They are all the encoder has to learn where the edge is."""
    n = min(len(metrics), agent.buffer.n)
    radius = final_radii(agent)[:n]
    final = agent.buffer.obs[:n, -1, :2]
    near = final @ location_direction(task, location) > radius * np.cos(np.pi / 6)
    there = near & (metrics["strategy_id"].to_numpy()[:n] == location)
    rim = edge(task)
    inside = there & (radius >= rim - EDGE_BAND) & (radius < rim)
    outside = there & (radius >= rim) & (radius < rim + EDGE_BAND)
    return int(inside.sum()), int(outside.sum())


def latent_changes(agent: SILIAgent, metrics: pd.DataFrame, window: int) -> None:
    """Print how the latent met the true changes over the last ``window``: foreseen (split by
    how the interaction that caused them ended, clearly inside or near the edge) or late, and
    its false changes with the task reward of the interactions played with them."""
    radius = final_radii(agent)[: len(metrics)]
    start = max(0, len(metrics) - window)
    c = foresight_by_exit(metrics, radius, CLEAR_INSIDE, start)
    masks = change_masks(metrics, start)
    false, settled = masks["false_alarms"], ~masks["latent_changes"] & ~masks["true_changes"]
    reward = metrics["task_reward"].to_numpy()[start:]
    r_false = float(reward[false].mean()) if false.any() else float("nan")
    print(
        f"  true changes {c['true_changes']}: the latent foresaw {c['foreseen']}, showed "
        f"{c['late']} one interaction late; foreseen after ending clearly inside "
        f"(radius < {CLEAR_INSIDE}) {c['foreseen_inside']} of {c['inside']}, near the "
        f"edge {c['foreseen_edge']} of {c['edge']}"
    )
    print(
        f"  false latent changes {c['false_alarms']}: task reward with them {r_false:.1f}, "
        f"with no change {reward[settled].mean():.1f}"
    )


def continuous_latent_changes(metrics: pd.DataFrame, window: int) -> None:
    """Print how far a continuous latent moved when the true strategy changed and when it did
    not: ``stability_reward`` of row j is -||z^{j+1} - z^j||, and a true change at row j+1 was
    caused by interaction j, so a latent that foresees it moves at row j."""
    rows = metrics.tail(window + 1)
    moved = -rows["stability_reward"].to_numpy()[:-1]
    sid = rows["strategy_id"].to_numpy()
    changed = sid[1:] != sid[:-1]
    if not changed.any() or changed.all():
        print(f"  latent distance: {changed.sum()} true changes, nothing to compare")
        return
    still = moved[~changed]
    clear = np.quantile(still, 0.99)
    print(
        f"  latent distance ||z^(j+1) - z^j||: median {np.median(moved[changed]):.2f} over "
        f"{changed.sum()} true changes, {np.median(still):.2f} with none; true changes moved "
        f"past the 99th percentile of the still ones ({clear:.2f}): "
        f"{(moved[changed] > clear).sum()} of {changed.sum()}"
    )


def edge_profile(agent: SILIAgent, task: CircleEnv, location: int) -> tuple[np.ndarray, float]:
    """min Q on the last step from the edge next to the held opponent, for radial actions."""
    out = location_direction(task, location)  # radial unit vector
    obs = np.array([*(edge(task) * out), (task.horizon - 1) / task.horizon], np.float32)
    if agent.cfg.method == "oracle":  # Oracle observes the opponent's position
        obs = np.concatenate([obs, out])
    x = torch.from_numpy(agent.policy_input(obs, agent.buffer.n)).unsqueeze(0)
    actions = torch.from_numpy(np.outer(RADIAL_ACTIONS, out).astype(np.float32))
    with torch.no_grad():
        q = agent.sac.critic(x.expand(len(actions), -1), actions).min(0).values.squeeze(-1)
        own = agent.sac.act(x, deterministic=True)[0].numpy()
    final_radius = float(np.linalg.norm(edge(task) * out + STEP * own))
    return q.numpy(), final_radius


def rewritten_last_interaction(
    agent: SILIAgent, task: CircleEnv, location: int, positions: np.ndarray, steps: int
) -> torch.Tensor:
    """The last stored interaction as transitions: row 0 as played, then one row per entry of
    ``positions`` ([rows, steps, 2]), which replaces its last ``steps`` positions (the actions
    and rewards of those steps rewritten to match)."""
    j = agent.buffer.n - 1
    rows = 1 + len(positions)
    obs, act, rew = (
        np.repeat(x[j : j + 1], rows, 0)
        for x in (agent.buffer.obs, agent.buffer.act, agent.buffer.rew)
    )
    opponent = location_direction(task, location)
    obs[1:, -steps:, :2] = positions
    act[1:, -steps:] = np.clip((obs[1:, 1:, :2] - obs[1:, :-1, :2])[:, -steps:] / STEP, -1, 1)
    rew[1:, -steps:] = -np.linalg.norm(positions - opponent, axis=-1)
    return transitions(*map(torch.from_numpy, (obs, act, rew)))


@torch.no_grad()
def encoder_edge(agent: SILIAgent, task: CircleEnv, location: int) -> np.ndarray | None:
    """P(the held category) for the last interaction with its final position moved radially."""
    if agent.model is None or agent.cfg.latent != "discrete":
        return None
    out = location_direction(task, location)
    finals = np.outer(edge_radii(task), out).astype(np.float32)[:, None]
    logits = agent.model.encode_logits(rewritten_last_interaction(agent, task, location, finals, 1))
    held = int(logits[0].argmax())
    return torch.softmax(logits[1:], -1)[:, held].numpy()


@torch.no_grad()
def greedy_interaction(agent: SILIAgent, task: CircleEnv, location: int, z: np.ndarray) -> float:
    """Task reward of one interaction played with the deterministic action on latents ``z``
    (z^j then z^{j-1}, as the policy reads them) against the opponent at ``location``."""
    obs, _ = task.reset(options={"restart": True})
    task.location = location
    total = 0.0
    for _ in range(task.horizon):
        x = torch.from_numpy(np.concatenate([obs, z]).astype(np.float32)).unsqueeze(0)
        obs, reward, _, _, _ = task.step(agent.sac.act(x, deterministic=True)[0].numpy())
        total += reward
    return total


@torch.no_grad()
def ending_cost(
    agent: SILIAgent, task: CircleEnv, location: int
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """For the last interaction's exit scaled to end at each of ``exit_radii``: how far
    z^{j+1} lies from the played one, and the next interaction's greedy task reward on it
    against the opponent where that ending leaves it (then the reward as played). None for
    runs without a latent model."""
    if agent.model is None:
        return None
    n = agent.buffer.n
    exit_path = agent.buffer.obs[n - 1, -PHASE_STEPS:, :2]
    radius = np.linalg.norm(exit_path, axis=-1, keepdims=True)
    scale = (exit_radii(task) - 1) / (radius[-1] - 1)  # of each step's distance outside radius 1
    paths = exit_path / radius * (1 + (radius - 1) * scale[:, None, None])
    traj = rewritten_last_interaction(agent, task, location, paths.astype(np.float32), PHASE_STEPS)
    z = agent.latents.grouped(agent.model.encode(traj).numpy())
    previous = [agent.Z[n - 1]] if agent.n_latents == 2 else []
    moved_on = (location + 1) % len(task.angles)  # where ending inside sends the opponent
    where = [location] + [moved_on if task.ends_inside(p[-1]) else location for p in paths]
    rewards = [
        greedy_interaction(agent, task, loc, np.concatenate([zk, *previous]))
        for zk, loc in zip(z, where, strict=True)
    ]
    return np.linalg.norm(z[1:] - z[0], axis=-1), np.array(rewards[1:]), rewards[0]


def overview(
    run: Path, agent: SILIAgent, metrics: pd.DataFrame, d: dict[str, float], window: int
) -> None:
    """The location-free part of the breakdown (Circle (Continuous) has no fixed locations)."""
    ended = final_radii(agent)[-window:]
    stability = kept_fraction(metrics.tail(window))
    print(
        f"{run.name}: distance summed: total {d['total']:.2f} = approach {d['approach']:.2f}"
        f" + middle {d['middle']:.2f} + exit {d['exit']:.2f}; alpha {agent.sac.alpha:.4f}; "
        f"true stability {stability:.2f}\n"
        f"  the interactions played ended at radius {ended.mean():.3f} +- {ended.std():.3f} "
        f"(min {ended.min():.3f})"
    )
    if agent.cfg.latent == "continuous":
        continuous_latent_changes(metrics, window)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--window", type=positive_int, default=100)
    args = p.parse_args()
    torch.set_num_threads(1)
    for run in args.runs:
        agent, task, metrics = load_run(run)
        d = phase_distances(agent, args.window)
        if task.variant == "continuous":  # no locations: where it ended and how z moved
            overview(run, agent, metrics, d, args.window)
            continue
        location = int(metrics["strategy_id"].iloc[-1])
        held = metrics["strategy_id"].tail(args.window)
        q, own = edge_profile(agent, task, location)
        best = edge_radii(task)[int(np.argmax(q))]
        print(
            f"{run.name}: distance summed: total {d['total']:.2f} = approach {d['approach']:.2f}"
            f" + middle {d['middle']:.2f} + exit {d['exit']:.2f}; alpha {agent.sac.alpha:.4f}"
        )
        if held.nunique() == 1:
            ref = reference_cost(task, location)
            print(
                f"  held location {location} in all {len(held)}: reference path {ref:.2f}, "
                f"this run {d['total'] / ref:.2f}x it"
            )
        else:
            print(f"  locations over the window: {held.astype(int).value_counts().to_dict()}")
        print(
            f"  edge at radius {edge(task):.2f}: min Q for final radius "
            f"{np.array2string(edge_radii(task), precision=3)}: "
            f"{np.array2string(q - q.max(), precision=2)} (minus its max), "
            f"argmax radius {best:.3f}, the policy ends at {own:.3f}"
        )
        ended = final_radii(agent)[-args.window :]
        print(
            f"  the interactions played ended at radius {ended.mean():.3f} +- {ended.std():.3f} "
            f"(min {ended.min():.3f})"
        )
        if (metrics["latent_category"] >= 0).any():  # a discrete latent to compare
            latent_changes(agent, metrics, args.window)
        elif agent.cfg.latent == "continuous":
            continuous_latent_changes(metrics, args.window)
        p_held = encoder_edge(agent, task, location)
        if p_held is not None:
            print(f"  encoder: P(held category) {np.array2string(p_held, precision=2)}")
        cost = ending_cost(agent, task, location) if held.nunique() == 1 else None
        if cost is not None:
            dz, rewards, played = cost
            radii, moved = (
                np.array2string(x, precision=2, floatmode="fixed", suppress_small=True)
                for x in (exit_radii(task), dz)
            )
            print(
                f"  last interaction's exit scaled to end at radius {radii}: z^(j+1) moves by "
                f"{moved} from the played one; the greedy next interaction, against the "
                f"opponent where that ending leaves it, scores "
                f"{np.array2string(rewards, precision=1, floatmode='fixed')} "
                f"(as played: {played:.2f})"
            )
            inside, outside = edge_examples(agent, task, metrics, location)
            print(
                f"  the replay's endings near this location within {EDGE_BAND} of the edge: "
                f"{inside} inside (each moved the opponent on), {outside} outside"
            )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
