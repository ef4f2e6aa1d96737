"""The rows the figures draw, without drawing them: a sweep's or a collection's results
table, each run's variant label, the seeds' mean curve of a metric, each run's final values, and
which runs make a task's curves or its b sweep. The claims and tables read them too (no
matplotlib needed)."""

from __future__ import annotations

import json
from collections.abc import Collection
from pathlib import Path
from typing import Any

import pandas as pd

from sili_robots.errors import ConfigError
from sili_robots.labels import METHOD_NAMES, VARIANT_KEYS

#: (column, axis label) of the values a run ends at (``final_values``)
FINAL_METRICS = (("task_reward", "final task reward"), ("true_stability", "final true stability"))
#: a b sweep's line: the variant but its b (the recorded setting ``B_SETTING``)
B_SWEEP_VARIANT = tuple(k for k in VARIANT_KEYS if k != "config_beta")
B_SETTING = "agent.sili.beta"


#: ``load_results``' table's ``attrs`` key: the (run, task) of the unfinished runs it left out
LEFT_OUT = "unfinished_left_out"


def load_results(sweep_dir: Path, include_unfinished: bool = False) -> pd.DataFrame:
    """The tidy table of a sweep (rebuilt from its run directories and written to results.csv)
    or of a results collection (``sili collect``: read only, nothing written); the runs with
    rows it leaves out are in its ``attrs[LEFT_OUT]``."""
    from sili_robots.sweep.results import check_exists, results_table, run_dirs, write_tables
    from sili_robots.sweep.state import SWEEP_FILE

    check_exists(sweep_dir)
    if (Path(sweep_dir) / SWEEP_FILE).is_file():
        try:
            df, _ = write_tables(sweep_dir)
        except OSError:  # a sweep one may read but not write (or on a read-only disk)
            df = results_table(sweep_dir)
    elif run_dirs(sweep_dir):
        df = results_table(sweep_dir)
    else:
        raise ConfigError(
            f"{sweep_dir} holds no runs (no {SWEEP_FILE} and no runs/*/config.json); give a "
            "directory written by `sili sweep --out` or `sili collect`"
        )
    finished = df["finished"].astype(bool)
    left_out = df.loc[~finished, ["run", "task"]].drop_duplicates()
    if not include_unfinished:
        df = df[finished]
    if df.empty:
        raise ConfigError(
            f"{sweep_dir} has no finished runs yet (`sili runs` shows how far they are; sili "
            "plot --include-unfinished plots partial runs)"
        )
    df = _with_settings(df, sweep_dir)
    df.attrs[LEFT_OUT] = [] if include_unfinished else list(left_out.itertuples(index=False))
    return df


def _with_settings(df: pd.DataFrame, sweep_dir: Path) -> pd.DataFrame:
    """``df`` with ``settings``: what sets a run apart from the other runs of its variant
    (``sili runs``' column, e.g. ``agent.hidden=16``), so that they are not averaged as seeds;
    and ``b_settings``: the same among the runs of its variant at any b, for the b sweep."""
    from sili_robots.sweep.inventory import recorded_settings, settings_apart

    runs = df.groupby("run", sort=False)[["task", *VARIANT_KEYS]].first().reset_index()
    flat = recorded_settings(sweep_dir)  # each config.json read once for both
    apart = dict(zip(runs["run"], settings_apart(runs, flat), strict=True))
    across_b = settings_apart(runs, flat, B_SWEEP_VARIANT, ignore=(B_SETTING,))
    return df.assign(
        settings=df["run"].map(apart),
        b_settings=df["run"].map(dict(zip(runs["run"], across_b, strict=True))),
    )


def with_profile(df: pd.DataFrame) -> pd.DataFrame:
    """Tables written before profiles, b schedules and other task arguments were recorded: the
    package's settings, a constant b, and the task arguments the controller column names."""
    if "profile" not in df:
        df = df.assign(profile="package")
    if "beta_scheduled" not in df:
        df = df.assign(beta_scheduled=False)
    if "task_id" not in df:
        df = df.assign(task_id="")
    if "settings" not in df:  # a table not read by load_results: its runs as one variant each
        df = df.assign(settings="", b_settings="")
    if "task_args" not in df:  # tables before other task arguments were told apart
        from sili_robots.tasks.registry import task_arguments_key

        keys = df[["task_id", "controller"]].fillna("")
        args = {
            (t, c): task_arguments_key(t or None, {"controller": c} if c else {})
            for t, c in keys.drop_duplicates().itertuples(index=False, name=None)
        }
        df = df.assign(task_args=[args[k] for k in keys.itertuples(index=False, name=None)])
    return df.assign(task_args=df["task_args"].fillna(""))


def variant_labels(df: pd.DataFrame, profiled: Collection[str] | None = None) -> pd.Series:
    """A label per row naming its method, plus b / controller / latent where the rows of the
    same method differ in them (e.g. ``SILI b=0.2``, ``SAC [osc]``). The profile is named for
    the methods in ``profiled`` (default: those that ran in more than one profile in ``df``)
    and wherever it is not the package's."""
    df = with_profile(df)
    labels = pd.Series([METHOD_NAMES.get(m, m) for m in df["method"]], index=df.index)
    if profiled is None:
        several = df.groupby("method")["profile"].transform("nunique") > 1
    else:
        several = df["method"].isin(list(profiled))
    named = several | (df["profile"] != "package")
    labels[named] += " (" + df.loc[named, "profile"] + ")"
    for _, rows in df.groupby(["method", "profile"]):
        idx = rows.index
        if rows[["config_beta", "beta_scheduled"]].drop_duplicates().shape[0] > 1:
            labels[idx] += [
                f" b→{b:g}" if scheduled else f" b={b:g}"
                for b, scheduled in zip(rows["config_beta"], rows["beta_scheduled"], strict=True)
            ]
        if rows["controller"].fillna("").nunique() > 1:
            labels[idx] += rows["controller"].fillna("").map(lambda c: f" [{c or 'default'}]")
        if rows["task_args"].nunique() > 1:  # other task arguments than the controller
            labels[idx] += rows["task_args"].map(arguments_label)
        if rows["latent"].nunique() > 1:
            labels[idx] += rows["latent"].map(lambda k: f" ({k})")
        if rows["settings"].nunique() > 1:  # e.g. "SAC [agent.hidden=16]"
            labels[idx] += rows["settings"].map(lambda s: f" [{s}]" if s else "")
    versions = df["task_id"].fillna("")
    if versions.nunique() > 1:  # e.g. "SAC (v0)" beside "SAC (v1)"
        labels += versions.map(lambda t: f" ({t.rsplit('-', 1)[-1]})" if t else "")
    return labels


def arguments_label(task_args: str) -> str:
    """`` [outside_margin=0.2]`` for a run given other task arguments (the controller is named
    on its own), ``""`` for none."""
    args = json.loads(task_args) if task_args else {}
    args.pop("controller", None)
    return f" [{_listed(args)}]" if args else ""


def shared_arguments(rows: pd.DataFrame) -> str:
    """`` (controller=osc)``: the task arguments other than its version's defaults that every
    run of ``rows`` was given, for a figure's title (as a preview's names them; the curves'
    labels name only what tells them apart); ``""`` when they differ or are the defaults."""
    given = rows["task_args"].unique()
    if len(given) != 1 or not given[0]:
        return ""
    return f" ({_listed(json.loads(given[0]))})"


def _listed(task_args: dict[str, Any]) -> str:
    """``controller=osc, horizon=20``: task arguments in name order."""
    return ", ".join(f"{k}={v}" for k, v in sorted(task_args.items()))


def default_smoothing(n_interactions: int) -> int:
    """About 2% of the run length (at least 1): enough to read a trend, not to hide a jump."""
    return max(1, round(n_interactions / 50))


def curve(rows: pd.DataFrame, metric: str, window: int) -> pd.DataFrame:
    """Mean and std across runs (seeds) per interaction of each run's trailing moving average."""
    smoothed = (
        rows.sort_values("interaction")
        .groupby("run")[metric]
        .transform(lambda s: s.rolling(window, min_periods=1).mean())
    )
    per_run = (
        rows.assign(value=smoothed)
        .pivot_table(index="interaction", columns="run", values="value", aggfunc="first")
        .sort_index()
    )
    return pd.DataFrame(
        {
            "mean": per_run.mean(axis=1),
            "std": per_run.std(axis=1, ddof=0),
            "seeds": per_run.notna().sum(axis=1),
        }
    )


def final_values(df: pd.DataFrame, window: int = 100) -> pd.DataFrame:
    """Per run: the mean of each metric over its last ``window`` interactions."""
    df = with_profile(df)
    tail = df.sort_values("interaction").groupby("run").tail(window)
    cols = [m for m, _ in FINAL_METRICS]
    ident = tail.groupby("run")[["task", *VARIANT_KEYS, "settings", "b_settings", "seed"]].first()
    return ident.join(tail.groupby("run")[cols].mean()).reset_index()


def b_sweep_rows(df: pd.DataFrame, task: str, method: str = "sili") -> pd.DataFrame:
    """The runs of a b sweep: ``method`` on ``task`` at a constant b in the package profile, of
    the run length most of them have (so a longer run at one b is not pooled with the sweep)."""
    rows = df[
        (df["task"] == task)
        & (df["method"] == method)
        & (df["profile"] == "package")
        & ~df["beta_scheduled"].astype(bool)
    ]
    if rows.empty:
        return rows
    lengths = rows.groupby("run").size()
    keep = lengths[lengths == lengths.mode().max()].index
    return rows[rows["run"].isin(keep)]


def curve_rows(df: pd.DataFrame, task: str) -> pd.DataFrame:
    """The rows a task's learning curves draw: all of them, except the runs of a b sweep of a
    method that also has runs outside it (the paper grid's SILI next to its b sweep): those
    have their own figure against b, and six more curves would hide the methods'."""
    rows = df[df["task"] == task]
    sweep = b_sweep_rows(rows, task)
    if sweep["config_beta"].nunique() < 2:
        return rows
    others = rows[(rows["method"] == "sili") & ~rows["run"].isin(sweep["run"])]
    return rows[~rows["run"].isin(sweep["run"])] if len(others) else rows
