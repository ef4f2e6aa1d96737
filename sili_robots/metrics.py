"""A run's history: ``metrics.csv``, one row per interaction, and what its readers make of it.

Written append-only while a run trains (``MetricsWriter``) and checked before a resume
(``check_history``); read by every table, figure and verdict (``read_metrics``), whose true
stability is the fraction of interactions the opponent kept its strategy (``kept_fraction``).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Collection
from pathlib import Path
from typing import Any

from sili_robots.atomic import replacing
from sili_robots.errors import ConfigError, first_line, writing

METRICS = "metrics.csv"
COMPRESSED_METRICS = f"{METRICS}.gz"  # a run kept small (``sili collect``)
DAMAGED_METRICS = (
    "restore it, or train the run again (sili train --overwrite; in a sweep, delete the run's "
    "folder and resume; in a collection, collect it again)"
)

#: the columns every reader of a run's history needs, numbers all
READ_COLUMNS = ("interaction", "task_reward", "strategy_changed")
#: the columns written on every row (the losses are blank before their first update, and
#: filter_step without a latent filter): a blank one is a row cut short
FILLED_COLUMNS = (
    "interaction",
    "task_reward",
    "stability_reward",
    "strategy_changed",
    "strategy_id",
    "latent_category",
    "latent_changed",
    "beta",
)
METRIC_COLUMNS = (
    *FILLED_COLUMNS,
    "latent_loss",
    "critic_loss",
    "actor_loss",
    "alpha",
    "wall_time",
    "filter_step",
)
#: what a sweep's ``results.csv`` adds to each run's rows (``sweep/results.py``): its identity
#: before them, and after them whether the strategy stayed and the run finished
ID_COLUMNS = (
    "run",
    "task",
    "task_id",
    "method",
    "profile",
    "latent",
    "seed",
    "controller",
    "task_args",
    "config_beta",
    "beta_scheduled",
)
ROW_COLUMNS = ("true_stability", "finished")


def kept(rows: Any) -> Any:
    """Per interaction of metrics ``rows`` (a DataFrame): 1 where the true strategy stayed, 0
    where it changed, NaN for the game's first (interaction 0), which has no strategy before it
    to keep (as ``sili bounds`` counts)."""
    return (1.0 - rows["strategy_changed"]).where(rows["interaction"] > 0)


def kept_fraction(rows: Any) -> float | None:
    """True stability of metrics ``rows``: the mean of ``kept``; None when no row is left."""
    stayed = kept(rows).dropna()
    return float(stayed.mean()) if len(stayed) else None


#: the true stability at which a run holds the opponent (verdicts, claims and benchmarks)
HOLDING = 0.9


def first_stable(stability: Any, window: int = 50) -> int | None:
    """Where the first ``window``-interaction window of ``stability`` (an array, one value per
    interaction; a NaN spoils its windows) with mean >= ``HOLDING`` starts; None: none does."""
    import numpy as np

    stability = np.asarray(stability, float)
    if len(stability) < window:
        return None
    sums = np.convolve(stability, np.ones(window), mode="valid")  # whole counts: 90 of 100
    hits = np.flatnonzero(sums >= HOLDING * window - 1e-9)  # holds, as kept_fraction says
    return int(hits[0]) if len(hits) else None


def read_metrics(path: Path) -> Any:
    """A run's per-interaction rows (``metrics.csv`` or its gzipped copy) as a DataFrame;
    ConfigError naming the file when it is damaged (cut, overwritten, not a run's history)."""
    import pandas as pd

    try:
        df = pd.read_csv(path, float_precision="round_trip")  # the values written, to the bit
        missing = [c for c in READ_COLUMNS if c not in df.columns]
        if missing:
            raise ValueError(f"no column {', '.join(missing)}")
        filled = [c for c in FILLED_COLUMNS if c in df.columns]
        if len(df) and (df[filled].iloc[-1].isna().any() or _cut_at_end(path)):
            # a last row cut short (a run stopped mid-write, also past its filled columns):
            # resume drops it; read again, so the columns' types are the rows' own
            df = pd.read_csv(path, float_precision="round_trip", nrows=len(df) - 1)
        for column in READ_COLUMNS:
            pd.to_numeric(df[column])
        for column in filled:
            blank = df[column].isna()
            if blank.any():  # line numbers as an editor shows them: the header is line 1
                raise ValueError(f"line {int(blank.to_numpy().argmax()) + 2} has no {column}")
    except (ValueError, TypeError, EOFError, OSError) as err:  # pandas' errors are ValueErrors
        raise ConfigError(f"{path} is damaged ({first_line(err)}); {DAMAGED_METRICS}") from None
    return df


def metrics_file(run_dir: Path) -> Path | None:
    """A run's ``metrics.csv``, or the gzipped copy a results collection keeps (None: neither)."""
    for path in (run_dir / METRICS, run_dir / COMPRESSED_METRICS):
        if path.is_file():
            return path
    return None


def run_metrics(run_dir: Path) -> Any:
    """The run's per-interaction rows (``read_metrics`` of ``metrics_file``); None when it
    logged none."""
    path = metrics_file(Path(run_dir))
    return None if path is None else read_metrics(path)


def check_history(
    run_dir: Path,
    interactions: int,
    columns: Collection[str] = METRIC_COLUMNS,
    plugins: str = "",
) -> None:
    """Refuse to resume a run whose ``metrics.csv`` lacks rows its checkpoint has trained (the
    file lost or cut short): the run would go on with a hole in its record. ``columns``: those
    the run writes (``RunConfig.metric_columns``), ``plugins`` its own add-ons."""
    path = Path(run_dir) / METRICS
    rows = 0
    if path.is_file():
        cut = None  # the line of a trained row cut short (it would be kept as it is)
        try:
            with path.open(newline="") as f:
                reader = csv.DictReader(f)
                for row in reader:
                    rows += 1
                    short = None in row.values() or None in row  # too few fields, or too many
                    if short and cut is None and rows <= interactions:
                        cut = reader.line_num
                found = set(reader.fieldnames or ())
                unknown = found - set(columns)
            if cut is None and 0 < rows <= interactions and not _ends_a_line(path):
                cut = reader.line_num  # the last row lost its end
        except (UnicodeDecodeError, csv.Error) as err:
            found, unknown = set(), {first_line(err)}
        if cut is not None:
            raise ConfigError(
                f"{path} is damaged (line {cut} is cut short, a row of the {interactions} "
                f"interactions its checkpoint has trained); {DAMAGED_METRICS}"
            )
        if unknown and plugins and set(METRIC_COLUMNS) <= found:  # an add-on's columns
            raise ConfigError(
                f"{path} has columns {', '.join(sorted(unknown))} that no add-on of the run "
                f"({plugins}) declares in its metric_columns now; declare them again to "
                "resume it"
            )
        if unknown:  # it would not take the run's next rows
            raise ConfigError(
                f"{path} is damaged (not a run's history: {', '.join(sorted(unknown))}); "
                f"{DAMAGED_METRICS}"
            )
    if rows < interactions:
        state = f"holds {rows} rows" if path.is_file() else "is missing"
        raise ConfigError(
            f"{run_dir}: its checkpoint is at interaction {interactions} but its {METRICS} "
            f"{state}; resuming would leave a hole in its record: restore {METRICS}, or train "
            "it again (sili train --overwrite; in a sweep, delete the run's folder and resume)"
        )


def _cut_at_end(path: Path) -> bool:
    """A plain ``metrics.csv`` whose last row lost its end (a gzipped copy is written whole)."""
    return path.suffix != ".gz" and not _ends_a_line(path)


def _ends_a_line(path: Path) -> bool:
    with path.open("rb") as f:
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


class MetricsWriter:
    """Append-only CSV of ``columns`` (``RunConfig.metric_columns``); on resume, rows past the
    checkpoint are dropped first."""

    def __init__(
        self, run_dir: Path, columns: tuple[str, ...] = METRIC_COLUMNS, keep_rows: int | None = None
    ) -> None:
        self.path = Path(run_dir) / METRICS
        self.columns = columns
        if keep_rows is not None and self.path.exists():
            with self.path.open() as f:
                rows = list(csv.DictReader(f))[:keep_rows]
            self._rewrite(rows)
        else:
            self._rewrite([])
        self._file = self.path.open("a", newline="")
        self._writer = csv.DictWriter(self._file, self.columns)

    def _rewrite(self, rows: list[dict[str, str]]) -> None:
        with replacing(self.path) as tmp, tmp.open("w", newline="") as f:
            w = csv.DictWriter(f, self.columns)
            w.writeheader()
            w.writerows(rows)

    def write(self, row: dict[str, Any]) -> None:
        with writing(self.path):
            self._writer.writerow({k: row.get(k, "") for k in self.columns})
            self._file.flush()

    def sync(self) -> None:
        """On disk, before a checkpoint that counts these rows is: after a crash of the machine
        the history still holds every interaction the checkpoint has trained."""
        with writing(self.path):
            os.fsync(self._file.fileno())

    def close(self) -> None:
        with writing(self.path):
            self._file.close()
