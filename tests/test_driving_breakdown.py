"""The Driving breakdown's phases on a short real run: each block's collisions and true stability
are the run's own (its replay's rewards and its metrics), and b and alpha are the logged ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from benchmark_scripts import load_script
from fast_settings import FAST_ARGS

from sili_robots.cli import main


def test_phases_of_a_real_run(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["train", "--task", "driving", "--method", "sili", "--interactions", "10"]
    args += ["--seed", "0", "--out", str(out), "--no-progress", *FAST_ARGS]
    args += ["--beta-schedule", "4:0,5:0.5"]
    assert main(args) == 0
    table = load_script("driving_breakdown").phases(out, 4)
    metrics = pd.read_csv(out / "metrics.csv")
    assert list(table.index) == ["0-3", "4-7", "8-9"]
    blocks = metrics.interaction // 4
    np.testing.assert_allclose(
        table["collisions"], (metrics.task_reward < 0).groupby(blocks).mean()
    )
    kept = (1.0 - metrics.strategy_changed).where(metrics.interaction > 0)  # 0 keeps nothing
    stable = kept.groupby(blocks).mean()
    np.testing.assert_allclose(table["true stability"], stable)
    np.testing.assert_allclose(table["b"], [0.0, 0.375, 0.5])
    assert table["left at red line"].between(0, 1).all()
