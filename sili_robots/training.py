"""The training loop: play interactions, learn after each, log, checkpoint, resume."""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from sili_robots.agent import SILIAgent
from sili_robots.diagnostics import latent_diagnostics
from sili_robots.errors import ConfigError
from sili_robots.progress import TrainingProgress
from sili_robots.runs import (
    SUMMARY,
    MetricsWriter,
    RunConfig,
    load_checkpoint,
    read_config,
    save_checkpoint,
    write_config,
)
from sili_robots.tasks import make_task
from sili_robots.tasks.base import resume_game


def run_env_kwargs(cfg: RunConfig) -> dict[str, Any]:
    """The task as this method sees it: Oracle observes z; partial observation sees the flag."""
    kwargs = dict(cfg.env_kwargs)
    if cfg.method == "oracle":
        kwargs["oracle"] = True
    if cfg.agent.latent == "partial" and cfg.method in ("sili", "stable"):
        kwargs["strategy_flag"] = True
    return kwargs


def make_run_env(cfg: RunConfig) -> gym.Env:
    return make_task(cfg.task_id or cfg.task, **run_env_kwargs(cfg))


def build_agent(cfg: RunConfig, env: gym.Env) -> SILIAgent:
    task = env.unwrapped
    return SILIAgent(
        cfg.agent,
        env.observation_space.shape[0],
        env.action_space.shape[0],
        task.horizon,
        task.strategy_dim,
        seed=cfg.seed,
    )


def play_interaction(
    env: gym.Env,
    obs: np.ndarray,
    info: dict[str, Any],
    policy,
    on_step: Callable[[np.ndarray, np.ndarray, float, np.ndarray], None] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, Any], bool]:
    """Play one interaction from (obs, info); returns its arrays, the next interaction's first
    observation and info (after ``reset``), and whether the true strategy changed in it.
    ``on_step(s, a, r, s')`` sees each step as it is played (the agent's latent filter)."""
    task = env.unwrapped
    h = task.horizon
    obs_seq = np.zeros((h + 1, obs.shape[0]), np.float32)
    act_seq = np.zeros((h, env.action_space.shape[0]), np.float32)
    rew_seq = np.zeros(h, np.float32)
    obs_seq[0] = obs
    changed = bool(info["strategy_changed"])
    strategy = np.asarray(info["strategy"], np.float32)
    strategy_id = float(info["strategy_id"])
    for t in range(h):
        a = policy(obs)
        prev = obs
        obs, r, _, _, info = env.step(a)
        if on_step is not None:
            on_step(prev, a, r, obs)
        obs_seq[t + 1], act_seq[t], rew_seq[t] = obs, a, r
        changed |= bool(info["strategy_changed"])
    next_obs, next_info = env.reset()
    data = {
        "obs": obs_seq,
        "act": act_seq,
        "rew": rew_seq,
        "strategy": strategy,
        "strategy_id": strategy_id,
    }
    return data, next_obs, next_info, changed


def train(cfg: RunConfig, run_dir: Path, resume: bool = False, progress: bool = True) -> Path:
    """Train ``cfg`` into ``run_dir``; with ``resume`` continue from its last checkpoint."""
    run_dir = Path(run_dir)
    torch.set_num_threads(1)
    env = make_run_env(cfg)
    agent = build_agent(cfg, env)
    state = load_checkpoint(run_dir) if resume else None
    if state is None:
        write_config(run_dir, cfg)
        obs, info = env.reset(seed=cfg.seed)
        agent.begin_game(info)
        start, metrics = 0, MetricsWriter(run_dir)
    else:
        agent.load_state_dict(state["agent"])
        obs, info = resume_game(env, state["game"])
        start = int(state["interaction"])
        metrics = MetricsWriter(run_dir, keep_rows=start)
    recent: deque[tuple[float, bool]] = deque(maxlen=100)
    elapsed0 = float(state["wall_time"]) if state else 0.0
    t0 = time.perf_counter()
    bar = TrainingProgress(
        cfg.interactions, start, enabled=progress, label=f"{cfg.task} {cfg.method} seed {cfg.seed}"
    )
    try:
        for j in range(start, cfg.interactions):
            if j < cfg.agent.random_interactions:
                policy = lambda _o: agent.random_action()  # noqa: E731
            else:
                policy = agent.act
            data, obs, info, changed = play_interaction(env, obs, info, policy, agent.observe_step)
            stats = agent.observe_interaction(
                data["obs"],
                data["act"],
                data["rew"],
                obs,
                data["strategy_id"],
                data["strategy"],
                info,
            )
            losses = agent.update(j, rl=j + 1 >= cfg.agent.random_interactions)
            task_reward = float(data["rew"].sum())
            recent.append((task_reward, changed))
            metrics.write(
                {
                    "interaction": j,
                    "task_reward": task_reward,
                    "stability_reward": stats.stability_reward,
                    "strategy_changed": int(changed),
                    "strategy_id": data["strategy_id"],
                    "latent_category": stats.latent_category,
                    "latent_changed": int(stats.latent_changed),
                    "beta": cfg.agent.beta_at(j),
                    "wall_time": elapsed0 + time.perf_counter() - t0,
                    "filter_step": stats.filter_step,
                    **losses,
                }
            )
            bar.advance(np.mean([r for r, _ in recent]), 1 - np.mean([c for _, c in recent]))
            done = j + 1
            if done % cfg.checkpoint_every == 0 or done == cfg.interactions:
                save_checkpoint(
                    run_dir,
                    {
                        "interaction": done,
                        "agent": agent.state_dict(),
                        "game": env.unwrapped.game_state(),
                        "wall_time": elapsed0 + time.perf_counter() - t0,
                    },
                )
    finally:
        bar.close()
        metrics.close()
        env.close()
    write_summary(run_dir)
    return run_dir


def write_summary(run_dir: Path, window: int = 100) -> dict[str, Any]:
    """Final task reward and true stability over the last ``window`` interactions."""
    import pandas as pd

    df = pd.read_csv(Path(run_dir) / "metrics.csv")
    tail = df.tail(window)
    summary = {
        "interactions": len(df),
        "final_task_reward": float(tail["task_reward"].mean()),
        "final_stability": float(1.0 - tail["strategy_changed"].mean()),
        "window": window,
        "wall_time_s": float(df["wall_time"].iloc[-1]) if len(df) else 0.0,
        **latent_diagnostics(df, window),
    }
    (Path(run_dir) / SUMMARY).write_text(json.dumps(summary, indent=2))
    return summary


def extend(run_dir: Path, interactions: int) -> None:
    """Raise a run's target to ``interactions``; resuming it then continues from its last
    checkpoint exactly as a run started with that target would have (nothing else in the run
    depends on the target)."""
    cfg = read_config(run_dir)
    if interactions < cfg.interactions:
        raise ConfigError(
            f"--interactions {interactions} would shorten {run_dir}, which is set to "
            f"{cfg.interactions}; a run can only be extended (allowed: >= {cfg.interactions})"
        )
    if interactions != cfg.interactions:
        cfg.interactions = interactions
        write_config(Path(run_dir), cfg)


def resume(run_dir: Path, progress: bool = True) -> Path:
    return train(read_config(run_dir), run_dir, resume=True, progress=progress)
