"""The Sawyer-Reach breakdown on a short real run: the replay it reads reproduces the run's task
rewards, and the opponent kept its goal exactly after the interactions that ended above the
plane (the task's rule, seen from the replay)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from benchmark_scripts import load_script
from fast_settings import FAST_ARGS

from sili_robots.cli import main
from sili_robots.diagnostics import category_strategies
from sili_robots.errors import ConfigError


def _load():
    return load_script("sawyer_breakdown")


def test_breakdown_reads_the_replay_of_a_real_run(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["train", "--task", "sawyer-reach", "--method", "sili", "--interactions", "12"]
    args += ["--seed", "0", "--out", str(out), "--no-progress", *FAST_ARGS]
    assert main(args) == 0
    breakdown = _load()
    agent, task, metrics = breakdown.load_run(out)
    table = breakdown.trajectories(agent, task, metrics)  # raises if the replay's rewards disagree
    assert len(table) == 12
    # interaction j's strategy_changed says whether the goal changed after interaction j - 1
    above = table["above plane"].to_numpy()[:-1]
    kept = table["stable"].to_numpy()[1:].astype(bool)
    assert np.array_equal(above, kept)
    assert (table["travel"] > 0).all() and (table["goal signal"] >= 0).all()
    # every one of the last 8 interactions is counted once, under its true goal, before and
    # after merging; merging only joins categories
    raw, merged = category_strategies(agent, 8)
    goals = pd.Series(table["goal"].to_numpy()[-8:]).value_counts().to_dict()
    for split in (raw, merged):
        total = pd.DataFrame(list(split.values())).fillna(0).sum().to_dict()
        assert total == {g: float(k) for g, k in goals.items()}
    assert len(merged) <= len(raw)


def test_breakdown_refuses_another_task(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "2"]
    assert main([*args, "--seed", "0", "--out", str(out), "--no-progress", *FAST_ARGS]) == 0
    with pytest.raises(ConfigError, match="Sawyer-Reach run is needed"):
        _load().load_run(out)
