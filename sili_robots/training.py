"""The training loop: play interactions, learn after each, log, checkpoint, resume."""

from __future__ import annotations

import json
import time
from collections import deque
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from sili_robots.agent import SILIAgent
from sili_robots.atomic import write_text
from sili_robots.build import build_agent, make_run_env
from sili_robots.diagnostics import latent_diagnostics
from sili_robots.errors import ConfigError
from sili_robots.evaluation import fitting
from sili_robots.memory import capped_at_available
from sili_robots.metrics import METRICS, MetricsWriter, check_history, kept_fraction, read_metrics
from sili_robots.progress import TrainingProgress
from sili_robots.rollout import play_interaction
from sili_robots.runs import (
    SUMMARY,
    RunConfig,
    check_resumable,
    load_checkpoint,
    read_config,
    record_continuation,
    save_checkpoint,
    set_target,
    write_config,
)
from sili_robots.stopping import StopBetweenInteractions
from sili_robots.tasks.base import resume_game
from sili_robots.tasks.registry import title_arguments


def run_label(cfg: RunConfig) -> str:
    """What the progress line calls a run: its task and the arguments outputs name
    (``title_arguments``: Sawyer-Reach's controller, given or not), its method and seed."""
    named = title_arguments(cfg.task_id or cfg.task, cfg.env_kwargs)
    given = "".join(f" {k}={v}" for k, v in named.items())
    return f"{cfg.task}{given} {cfg.method} seed {cfg.seed}"


def train(
    cfg: RunConfig,
    run_dir: Path,
    resume: bool = False,
    progress: bool = True,
    env: gym.Env | None = None,
    stop_file: Path | None = None,
) -> Path:
    """Train ``cfg`` into ``run_dir``; with ``resume`` continue from its last checkpoint.
    ``env``: the task instance to train on, as the method observes it (default: built from
    ``cfg``; a given one is left open). ``stop_file``: once it exists, the run stops after the
    interaction it is in, saved, as at a stop signal (a sweep's worker on another machine)."""
    run_dir = Path(run_dir)
    state = load_checkpoint(run_dir) if resume else None
    if state is not None:
        check_history(run_dir, int(state["interaction"]), cfg.metric_columns(), cfg.addons.plugins)
    torch.set_num_threads(cfg.threads)
    own_env = env is None
    env = make_run_env(cfg, run_dir if resume else None) if env is None else env
    try:
        agent, obs, info, start, metrics = _start_or_resume(
            cfg, run_dir, env, state, None if own_env else env
        )
    except BaseException:
        if own_env:
            env.close()
        raise
    recent = _recent_window(run_dir, start)
    elapsed0 = float(state["wall_time"]) if state else 0.0
    t0 = time.perf_counter()
    bar = TrainingProgress(cfg.interactions, start, enabled=progress, label=run_label(cfg))
    # only add-ons that need each step as it is played make the loop report steps
    watch = None
    if agent.watches_steps:
        watch = lambda s, a, r, s2, _info: agent.observe_step(s, a, r, s2)  # noqa: E731
    try:
        with StopBetweenInteractions() as stop, capped_at_available():
            if stop_file is not None and stop_file.exists():  # asked while the run was set up
                raise KeyboardInterrupt(f"{stop_file} asked the run to stop")
            for j in range(start, cfg.interactions):
                if j < cfg.agent.sac.random_interactions:
                    policy = lambda _o: agent.random_action()  # noqa: E731
                else:
                    policy = agent.act
                played = play_interaction(env, obs, info, policy, watch)
                obs, info = played.next_obs, played.next_info
                stats = agent.observe_interaction(
                    played.obs,
                    played.act,
                    played.rew,
                    obs,
                    played.strategy_id,
                    info,
                )
                losses = agent.update(j, rl=j + 1 >= cfg.agent.sac.random_interactions)
                recent.append((played.task_reward, played.strategy_changed if j else None))
                metrics.write(
                    {
                        "filter_step": -1,  # the latent filter's, when it runs
                        **stats.extra,  # the add-ons' declared columns (metric_columns) ...
                        "interaction": j,  # ... never in place of these
                        "task_reward": played.task_reward,
                        "stability_reward": stats.stability_reward,
                        "strategy_changed": int(played.strategy_changed),
                        "strategy_id": played.strategy_id,
                        "latent_category": stats.latent_category,
                        "latent_changed": int(stats.latent_changed),
                        "beta": agent.beta,
                        "wall_time": elapsed0 + time.perf_counter() - t0,
                        **losses,
                    }
                )
                stayed = [not c for _, c in recent if c is not None]  # 0 has nothing to keep
                bar.advance(np.mean([r for r, _ in recent]), np.mean(stayed) if stayed else np.nan)
                done = j + 1
                stopping = stop.requested  # read once: a stop after this acts at the next end
                asked = stop_file is not None and stop_file.exists()
                if (
                    done % cfg.checkpoint_every == 0
                    or done == cfg.interactions
                    or stopping
                    or asked
                ):
                    metrics.sync()
                    save_checkpoint(
                        run_dir,
                        {
                            "interaction": done,
                            # a copy into another run (task, method or seed) is refused
                            "task": cfg.task_id or cfg.task,
                            "method": cfg.method,
                            "seed": cfg.seed,
                            "run": cfg.to_dict(),  # and one of other settings
                            "agent": agent.state_dict(),
                            "game": env.unwrapped.game_state(),
                            "wall_time": elapsed0 + time.perf_counter() - t0,
                        },
                    )
                if stopping and done < cfg.interactions:
                    stop.deliver()  # it came during the interaction, which is checkpointed
                if asked and done < cfg.interactions:
                    raise KeyboardInterrupt(f"{stop_file} asked the run to stop")
            # finished: a stop held through the last interaction acts after this, at the end
            # of the block, and leaves the run done, not to be resumed
            write_summary(run_dir)
    finally:
        bar.close()
        try:
            metrics.close()  # after a refused write it fails again: the row is still unwritten
        finally:
            if own_env:
                env.close()
    return run_dir


def _start_or_resume(
    cfg: RunConfig,
    run_dir: Path,
    env: gym.Env,
    state: dict[str, Any] | None,
    given_env: gym.Env | None,
) -> tuple[SILIAgent, Any, dict[str, Any], int, MetricsWriter]:
    """The agent, the game's current observation and info, the first interaction to play and
    the metrics writer, from scratch or from ``state``; a resumed run changes only once its
    checkpoint has loaded (``given_env``: the user's task instance, named if it does not fit)."""
    agent = build_agent(cfg, env)
    if state is None:
        (run_dir / SUMMARY).unlink(missing_ok=True)
        write_config(run_dir, cfg)
        obs, info = env.reset(seed=cfg.seed)
        agent.begin_game(info)
        return agent, obs, info, 0, MetricsWriter(run_dir, cfg.metric_columns())
    with fitting(run_dir, cfg, given_env):
        agent.load_state_dict(state["agent"])
    obs, info = resume_game(env, state["game"])
    extend(run_dir, cfg.interactions)
    (run_dir / SUMMARY).unlink(missing_ok=True)  # unfinished until it writes a new one
    start = int(state["interaction"])
    record_continuation(run_dir, cfg, start)
    return agent, obs, info, start, MetricsWriter(run_dir, cfg.metric_columns(), keep_rows=start)


def _recent_window(run_dir: Path, start: int) -> deque[tuple[float, bool | None]]:
    """The progress line's last 100 (task reward, strategy changed), as an uninterrupted run
    holds them at ``start``: a resumed run's line then reads as its summary will."""
    window: deque[tuple[float, bool | None]] = deque(maxlen=100)
    if start:
        rows = read_metrics(run_dir / METRICS)
        for row in rows[rows["interaction"] < start].tail(100).itertuples():
            changed = bool(row.strategy_changed) if row.interaction else None
            window.append((float(row.task_reward), changed))
    return window


def write_summary(run_dir: Path, window: int = 100) -> dict[str, Any]:
    """Final task reward and true stability over the last ``window`` interactions."""
    df = read_metrics(Path(run_dir) / METRICS)
    tail = df.tail(window)
    summary = {
        "interactions": len(df),
        "final_task_reward": float(tail["task_reward"].mean()),
        "final_stability": kept_fraction(tail),
        "window": len(tail),  # the interactions averaged: fewer in a short run
        "wall_time_s": float(df["wall_time"].iloc[-1]) if len(df) else 0.0,
        **latent_diagnostics(df, window),
    }
    # a mean of no rows is NaN, which strict JSON readers (jq, other languages) refuse
    summary = {k: None if isinstance(v, float) and np.isnan(v) else v for k, v in summary.items()}
    write_text(Path(run_dir) / SUMMARY, json.dumps(summary, indent=2, allow_nan=False))
    return summary


def check_extension(run_dir: Path, interactions: int) -> int:
    """The run's recorded target; ConfigError for a target below it: a run can only be
    extended."""
    recorded = read_config(run_dir).interactions
    if interactions < recorded:
        raise ConfigError(
            f"--interactions {interactions} would shorten {run_dir}, which is set to "
            f"{recorded}; a run can only be extended (allowed: >= {recorded})"
        )
    return recorded


def extend(run_dir: Path, interactions: int) -> None:
    """Raise a run's target to ``interactions``; resuming it then continues from its last
    checkpoint exactly as a run started with that target would have (nothing else in the run
    depends on the target). The run is unfinished from here on (its summary goes first, so a
    stop before it trains leaves it resumable, not done and short); the rest of its record
    (versions, machine) stays as written when it began."""
    if interactions != check_extension(run_dir, interactions):
        (Path(run_dir) / SUMMARY).unlink(missing_ok=True)
        set_target(run_dir, interactions)


def resume(run_dir: Path, progress: bool = True, interactions: int | None = None) -> Path:
    """Continue a run from its last checkpoint, extended to ``interactions`` when given (the
    run changes only once its checkpoint and history are known to resume)."""
    check_resumable(run_dir)
    cfg = read_config(run_dir)
    if interactions is not None:
        check_extension(run_dir, interactions)
        cfg.interactions = interactions
    return train(cfg, run_dir, resume=True, progress=progress)
