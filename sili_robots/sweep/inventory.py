"""What a sweep or collection holds, per task and method variant (``sili runs``)."""

from __future__ import annotations

import json
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from sili_robots.labels import VARIANT_KEYS
from sili_robots.runs import MACHINE_SETTINGS, recorded_run
from sili_robots.sweep.results import run_dirs, runs_table

#: one row per (task, variant, the other settings its runs differ in)
INVENTORY_KEYS = ("task", *VARIANT_KEYS, "settings")
#: recorded settings that are not the configuration: the seed, the budget, the machine's
#: (``runs.MACHINE_SETTINGS``: threads, kernels, precision, how often saved), and the task and its
#: arguments (the variant's own columns: ``task_args``, ``controller``, ``task_id``)
NOT_SETTINGS = ("seed", "interactions", *MACHINE_SETTINGS, "task", "task_id", "env_kwargs")


def inventory(directory: Path) -> pd.DataFrame:
    """Per task and variant: done / unfinished runs, seeds, interactions per done run (min and
    max), interactions trained in all, mean final task reward and stability, CPU hours. Runs of
    one variant trained with other settings (``--set``) are rows of their own, ``settings``
    naming what sets them apart ("" where the variant's runs agree)."""
    runs = runs_table(directory)
    runs["controller"] = runs["controller"].fillna("")
    runs["task_id"] = runs["task_id"].fillna("") if "task_id" in runs else ""
    runs["settings"] = settings_apart(runs, recorded_settings(directory))
    rows = []
    for key, group in runs.groupby(list(INVENTORY_KEYS), sort=False):
        done = group[group["status"] == "done"]
        rows.append(
            {
                **dict(zip(INVENTORY_KEYS, key, strict=True)),
                "done": len(done),
                "unfinished": len(group) - len(done),
                "seeds": ",".join(str(s) for s in sorted(done["seed"])),
                "interactions": _span(done["interactions"]),
                "interactions_trained": int(group["interactions_logged"].sum()),
                "final_task_reward": round(float(done["final_task_reward"].mean()), 2)
                if len(done)
                else float("nan"),
                "final_stability": round(float(done["final_stability"].mean()), 2)
                if len(done)
                else float("nan"),
                "cpu_hours": round(float(done["wall_time_s"].sum()) / 3600, 2),
            }
        )
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    # b in numeric order (run names sort b0.8 before b0 and b1)
    order = ["task", "method", "profile", "beta_scheduled", "config_beta"]
    return table.sort_values(order, kind="stable").reset_index(drop=True)


def recorded_settings(directory: Path) -> dict[str, dict[str, Any]]:
    """Each run's recorded settings (dotted keys, without ``NOT_SETTINGS``), by run name."""
    return {d.name: _flat(recorded_run(d)) for d in run_dirs(directory)}


def settings_apart(
    runs: pd.DataFrame,
    flat: dict[str, dict[str, Any]],
    variant: Sequence[str] = VARIANT_KEYS,
    ignore: Collection[str] = (),
) -> pd.Series:
    """Per run, the settings (``key=value``, of ``recorded_settings``) in which it differs from
    other runs of its task and ``variant``, leaving out those in ``ignore``; "" when all agree."""
    out = pd.Series("", index=runs.index)
    for _, group in runs.groupby(["task", *variant], sort=False, dropna=False):
        configs = [flat[name] for name in group["run"]]
        keys = sorted({k for c in configs for k in c} - set(ignore))
        apart = [k for k in keys if len({json.dumps(c.get(k)) for c in configs}) > 1]
        for idx, config in zip(group.index, configs, strict=True):
            out[idx] = ", ".join(f"{k}={json.dumps(config.get(k))}" for k in apart)
    return out


def _flat(config: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A recorded run config as dotted keys, without ``NOT_SETTINGS``."""
    out: dict[str, Any] = {}
    for key, value in config.items():
        path = f"{prefix}{key}"
        if path in NOT_SETTINGS:
            continue
        if isinstance(value, dict) and value and "points" not in value:
            out.update(_flat(value, f"{path}."))
        else:
            out[path] = value
    return out


def _span(values: pd.Series) -> str:
    if values.empty:
        return "-"
    lo, hi = int(values.min()), int(values.max())
    return str(lo) if lo == hi else f"{lo}-{hi}"


def totals_line(table: pd.DataFrame) -> str:
    """One line: runs done, interactions trained, CPU hours of the done runs."""
    return (
        f"{int(table['done'].sum())} runs done, {int(table['unfinished'].sum())} unfinished; "
        f"{int(table['interactions_trained'].sum()):,} interactions trained; "
        f"{table['cpu_hours'].sum():.1f} CPU-hours in the done runs"
    )
