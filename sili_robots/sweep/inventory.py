"""What a sweep or collection holds, per task and method variant (``sili runs``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from sili_robots.labels import VARIANT_KEYS
from sili_robots.sweep.results import runs_table

#: one row per (task, variant)
INVENTORY_KEYS = ("task", *VARIANT_KEYS)


def inventory(directory: Path) -> pd.DataFrame:
    """Per task and variant: done / unfinished runs, seeds, interactions per done run (min and
    max), interactions trained in all, mean final task reward and stability, CPU hours."""
    runs = runs_table(directory)
    runs["controller"] = runs["controller"].fillna("")
    runs["task_id"] = runs["task_id"].fillna("") if "task_id" in runs else ""
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
    return pd.DataFrame(rows)


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
