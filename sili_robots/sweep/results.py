"""The sweep's tables, built from its run directories (the single source of truth).

- ``results.csv``: tidy, one row per run per interaction: the run's identity (``run``, ``task``,
  ``task_id`` (the task version, a gymnasium id), ``method``, ``profile``, ``latent``, ``seed``,
  ``controller`` (named or the task's default), ``task_args`` (the task arguments other than
  its version's defaults, as JSON; "" for none), ``config_beta`` (a schedule's last b),
  ``beta_scheduled``) + every ``metrics.csv`` column + ``true_stability`` (1 -
  strategy_changed; empty for interaction 0, which has no strategy before it) + ``finished``
  + the columns the runs' own add-ons declare (``metric_columns``).
- ``runs.csv``: one row per run: status (done / failed / incomplete / not started), interactions
  logged, final task reward and true stability, wall time, error.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import pandas as pd

from sili_robots.agent.schedule import Schedule
from sili_robots.atomic import replacing
from sili_robots.errors import ConfigError, is_number
from sili_robots.labels import shell_path
from sili_robots.metrics import ID_COLUMNS, METRIC_COLUMNS, ROW_COLUMNS, kept, run_metrics
from sili_robots.migrations import migrate_run
from sili_robots.runs import (
    CONFIG,
    DAMAGED_CONFIG,
    DAMAGED_SUMMARY,
    ERROR_FILE,
    SUMMARY,
    read_json,
    recorded_task_id,
)
from sili_robots.sweep.state import RESULTS, RUNS_DIR, RUNS_TABLE
from sili_robots.tasks.registry import task_arguments_key, title_arguments

T = TypeVar("T")

RESULT_COLUMNS = (*ID_COLUMNS, *METRIC_COLUMNS, *ROW_COLUMNS)
RUN_COLUMNS = (
    *ID_COLUMNS,
    "status",
    "interactions",
    "interactions_logged",
    "final_task_reward",
    "final_stability",
    "wall_time_s",
    "error",
)


def run_dirs(sweep_dir: Path) -> list[Path]:
    """Every run directory of the sweep (those with a config), by name."""
    root = Path(sweep_dir) / RUNS_DIR
    return sorted(p for p in root.glob("*") if (p / CONFIG).is_file())


#: what a results directory is, for messages
RESULTS_DIR_KIND = "give a directory written by `sili sweep --out` or `sili collect`"


def check_exists(directory: Path) -> None:
    """A results directory that can be read: it exists and is not a single run's."""
    if not Path(directory).exists():
        raise ConfigError(f"{directory} does not exist; {RESULTS_DIR_KIND}")
    if not Path(directory).is_dir():
        raise ConfigError(f"{directory} is a file, not a folder; {RESULTS_DIR_KIND}")
    if (Path(directory) / CONFIG).is_file():
        raise ConfigError(
            f"{directory} is a run, not a sweep or a collection; give the folder that holds its "
            f"runs/ (one run alone: its summary.json, or sili eval "
            f"{shell_path(directory)} if it kept its checkpoint)"
        )


def runs_of(directory: Path) -> list[Path]:
    """``run_dirs`` of a sweep or a collection, or ConfigError saying why there are none."""
    check_exists(directory)
    runs = run_dirs(directory)
    if not runs:
        raise ConfigError(f"{directory} holds no runs (no runs/*/config.json); {RESULTS_DIR_KIND}")
    return runs


def run_identity(run_dir: Path) -> tuple[dict, dict]:
    """A run's identity columns and its recorded config (today's layout); ConfigError naming
    its config.json when a value the tables need is missing or of another kind."""
    path = run_dir / CONFIG
    raw = read_json(path, DAMAGED_CONFIG, "run")["run"]
    try:
        cfg = migrate_run(raw)
        ident = _identity(run_dir, cfg)
        int(cfg["interactions"])
    except KeyError as err:
        raise ConfigError(f"{path} is damaged (no {err.args[0]!r}); {DAMAGED_CONFIG}") from None
    except (TypeError, ValueError, AttributeError) as err:
        raise ConfigError(f"{path} is damaged ({err}); {DAMAGED_CONFIG}") from None
    return ident, cfg


def _identity(run_dir: Path, cfg: dict) -> dict:
    agent = cfg["agent"]
    beta = agent.get("sili", {}).get("beta", 0.5)
    scheduled = isinstance(beta, dict)
    if scheduled:  # a schedule: the b it ends at
        beta = Schedule.from_dict(beta).points[-1][1]
    task_id = recorded_task_id(cfg)
    env_kwargs = cfg.get("env_kwargs", {})
    ident = {
        "run": run_dir.name,
        "task": cfg["task"],
        "task_id": task_id,
        "method": cfg["method"],
        "profile": agent.get("profile", "package"),
        "latent": agent["latent"],
        "seed": int(cfg["seed"]),
        "controller": _controller(task_id, env_kwargs),
        # the task arguments its version does not build by default ("" for none), as JSON
        "task_args": task_arguments_key(task_id, env_kwargs),
        "config_beta": float(beta),
        "beta_scheduled": scheduled,
    }
    return ident


def _controller(task_id: str | None, env_kwargs: dict) -> str:
    """The controller a run used, named or its task's default alike ("" for tasks without)."""
    return str(title_arguments(task_id, env_kwargs).get("controller", ""))


SUMMARY_NUMBERS = ("final_task_reward", "final_stability", "wall_time_s")


def finished_summary(run_dir: Path) -> dict[str, Any] | None:
    """A finished run's ``summary.json`` (None while it trains); ConfigError naming it when it
    is damaged, so no table counts a run finished on a file it cannot read."""
    path = run_dir / SUMMARY
    if not path.is_file():
        return None
    summary = read_json(path, DAMAGED_SUMMARY, *SUMMARY_NUMBERS)
    stability = summary["final_stability"]  # None after one interaction: no change
    if not (is_number(stability) or stability is None) or not all(
        is_number(summary[k]) for k in ("final_task_reward", "wall_time_s")
    ):
        raise ConfigError(
            f"{path} is damaged (a value of {', '.join(SUMMARY_NUMBERS)} is not a number); "
            f"{DAMAGED_SUMMARY}"
        )
    return summary


def each_run(sweep_dir: Path, read: Callable[[Path], T]) -> list[T]:
    """``read(run_dir)`` of every run of the sweep, in order; a ConfigError naming every run
    that cannot be read, not only the first, so a sweep's damaged runs are mended in one go."""
    done: list[T] = []
    damaged: list[str] = []
    for run_dir in run_dirs(sweep_dir):
        try:
            done.append(read(run_dir))
        except ConfigError as err:
            damaged.append(str(err))
    check_none_damaged(damaged)
    return done


def check_none_damaged(damaged: list[str]) -> None:
    """One ConfigError for every damaged run's message (each names its file and the mend)."""
    if len(damaged) > 1:
        raise ConfigError(f"{len(damaged)} runs cannot be read:\n  " + "\n  ".join(damaged))
    if damaged:
        raise ConfigError(damaged[0])


def results_table(sweep_dir: Path) -> pd.DataFrame:
    """All runs' per-interaction rows in one tidy frame (columns ``RESULT_COLUMNS``, then the
    columns of the runs' own add-ons, empty for runs without them)."""
    frames = [df for df in each_run(sweep_dir, _result_rows) if df is not None]
    if not frames:
        return pd.DataFrame(columns=list(RESULT_COLUMNS))
    own = dict.fromkeys(c for df in frames for c in df.columns if c not in RESULT_COLUMNS)
    return pd.concat(frames, ignore_index=True)[[*RESULT_COLUMNS, *own]]


def _result_rows(run_dir: Path) -> pd.DataFrame | None:
    df = run_metrics(run_dir)
    if df is None or df.empty:
        return None
    ident, _ = run_identity(run_dir)
    for key, value in ident.items():
        df[key] = value
    df["true_stability"] = kept(df)
    df["finished"] = finished_summary(run_dir) is not None
    return df


def runs_table(sweep_dir: Path) -> pd.DataFrame:
    """One row per run with its state and final numbers (from ``summary.json`` when done)."""
    return pd.DataFrame(each_run(sweep_dir, _run_row), columns=list(RUN_COLUMNS))


def _run_row(run_dir: Path) -> dict[str, Any]:
    ident, cfg = run_identity(run_dir)
    error_path = run_dir / ERROR_FILE
    metrics = run_metrics(run_dir)
    logged = 0 if metrics is None else len(metrics)
    row = {**ident, "interactions": int(cfg["interactions"]), "interactions_logged": logged}
    summary = finished_summary(run_dir)
    if summary is not None:
        row.update(status="done", **{k: summary[k] for k in SUMMARY_NUMBERS})
    elif error_path.is_file():
        text = error_path.read_text().strip().splitlines()
        row.update(status="failed", error=text[-1] if text else "")
    else:
        row.update(status="incomplete" if logged else "not started")
    return row


def write_tables(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Write ``results.csv`` and ``runs.csv`` into the sweep directory and return them."""
    results, runs = results_table(sweep_dir), runs_table(sweep_dir)
    for frame, name in ((results, RESULTS), (runs, RUNS_TABLE)):
        path = Path(sweep_dir) / name
        with replacing(path, shared=True) as tmp:  # readers never see half a table, and
            frame.to_csv(tmp, index=False)  # `sili plot` may write it while a sweep does
    return results, runs
