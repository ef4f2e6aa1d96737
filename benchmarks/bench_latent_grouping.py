"""Latent-model quality on a run's own data: usage bonus and behaviour grouping of categories.

Takes the replay of a finished run with discrete latents (its checkpoint), trains fresh latent
models on it with the agent's own update (uniform (j-1, j) pairs, ``latent_batch`` 32), then
labels every interaction with the agent's own ``refresh_latents``. For each usage bonus it
reports the raw categories and the categories grouped by decoder behaviour, side by side with
the previous defaults (bonus 0.03, no grouping) as the reference:

- purity: fraction of interactions whose predicted category's majority strategy is their own;
- change agreement: fraction of consecutive interactions where "the category changed" equals
  "the true strategy changed" (what makes the stability reward honest);
- categories: how many categories (or groups) are in use.

    python benchmarks/bench_latent_grouping.py RUN_DIR [--steps 2000] [--seeds 0,1]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from sili_robots.agent.config import check as check_settings
from sili_robots.agent.matmul import machine_key
from sili_robots.build import build_agent, make_run_env
from sili_robots.commands.common import positive_int
from sili_robots.diagnostics import change_agreement, purity
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.runs import load_checkpoint, read_config
from sili_robots.sweep import parse_seeds

REFERENCE_BONUS = 0.03  # the previous default, trained and labelled without grouping


def labels(run_dir: Path, bonus: float, threshold: float, steps: int, seed: int) -> np.ndarray:
    """Predicted category of z^{j+1} for every stored interaction j, from a fresh model."""
    cfg = read_config(run_dir)
    cfg.set("model.usage_bonus", bonus)
    cfg.set("model.merge_threshold", threshold)
    cfg.seed = seed
    agent = build_agent(cfg, make_run_env(cfg))
    agent.buffer.load_state_dict(load_checkpoint(run_dir)["agent"]["buffer"])
    agent.Z = np.zeros((agent.buffer.n + 1, agent.zdim), np.float32)  # no cached latents yet
    agent.update_latent_model(steps)
    agent.refresh_latents()
    return agent.Z[1 : agent.buffer.n + 1].argmax(-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--steps", type=positive_int, default=2000)
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--bonus", type=float, default=0.1)
    parser.add_argument("--threshold", type=float, default=0.5)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"machine: {machine_key()}", flush=True)  # the seconds' CPU
    cfg = read_config(args.run_dir)
    if cfg.agent.latent != "discrete":
        raise ConfigError(f"{args.run_dir} has {cfg.agent.latent!r} latents; need discrete")
    stored = load_checkpoint(args.run_dir)
    if stored is None:
        raise ConfigError(f"{args.run_dir} has no checkpoint")
    truth = stored["agent"]["buffer"]
    n = int(truth["n"])
    true = np.asarray(truth["strategy_id"]).astype(int)
    variants = [
        ("reference: bonus 0.03, raw", REFERENCE_BONUS, 0.0),
        (f"bonus {args.bonus:g}, raw", args.bonus, 0.0),
        (f"bonus {args.bonus:g}, grouped at {args.threshold:g}", args.bonus, args.threshold),
    ]
    for _, bonus, threshold in variants:  # every fit's settings, before the first (minutes)
        cfg.set("model.usage_bonus", bonus)
        cfg.set("model.merge_threshold", threshold)
        check_settings(cfg.agent, "")
    print(f"{args.run_dir}: {n} interactions, {args.steps} latent-model updates per fit")
    print(f"{'variant':38s} {'seed':>4s} {'purity':>7s} {'change agr.':>11s} {'categories':>10s}")
    rows: dict[str, list[tuple[float, float]]] = {}
    for seed in parse_seeds(args.seeds):
        for name, bonus, threshold in variants:
            t0 = time.perf_counter()
            torch.manual_seed(seed)
            pred = labels(args.run_dir, bonus, threshold, args.steps, seed)[:-1]
            p, c = purity(pred, true[1:]), change_agreement(pred, true[1:])
            rows.setdefault(name, []).append((p, c))
            print(
                f"{name:38s} {seed:4d} {p:7.2f} {c:11.2f} {len(np.unique(pred)):10d}"
                f"   ({time.perf_counter() - t0:.0f} s)"
            )
    ref_p, ref_c = np.mean(rows[variants[0][0]], axis=0)
    print("\nmean over seeds (ratio to the reference):")
    for name, vals in rows.items():
        p, c = np.mean(vals, axis=0)
        print(
            f"{name:38s} purity {p:.2f} ({p / ref_p:.2f}x)  change agr. {c:.2f} ({c / ref_c:.2f}x)"
        )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
