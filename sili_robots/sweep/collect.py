"""Results collections: the finished runs of one or more sweeps, small enough to keep in git.

A collection has a sweep's layout (``DIR/runs/NAME/``) with, per finished run, only what the
tables and figures need: ``config.json``, ``summary.json`` and ``metrics.csv.gz``; no
checkpoints, TensorBoard files or uncompressed tables. ``sili plot``, ``sili runs`` and ``sili
claims`` read a collection as they read a sweep, so every figure and table is rebuilt from it
without retraining.

The gzip stream is written with no timestamp and the metrics with 7 significant digits (the
float32 the agent computes), so collecting the same run twice gives the same bytes.
"""

from __future__ import annotations

import gzip
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sili_robots.atomic import write_bytes
from sili_robots.errors import ConfigError
from sili_robots.metrics import (
    COMPRESSED_METRICS,
    DAMAGED_METRICS,
    METRICS,
    metrics_file,
    read_metrics,
)
from sili_robots.runs import (
    CHECKPOINT,
    CONFIG,
    DAMAGED_SUMMARY,
    ERROR_FILE,
    SUMMARY,
    read_json,
    recorded_run,
    run_differences,
    shown_value,
)
from sili_robots.sweep.results import (
    check_none_damaged,
    finished_summary,
    run_identity,
    runs_of,
)
from sili_robots.sweep.state import RUNS_DIR


@dataclass
class CollectReport:
    """Run names by what ``collect`` did with them."""

    added: list[str] = field(default_factory=list)
    replaced: list[str] = field(default_factory=list)  # a shorter (or damaged) copy before
    unchanged: list[str] = field(default_factory=list)
    unfinished: list[str] = field(default_factory=list)


def compressed_metrics(source: Path) -> bytes:
    """The run's metrics as reproducible gzipped CSV bytes."""
    df = read_metrics(source)
    text = df.to_csv(index=False, float_format="%.7g")
    return gzip.compress(text.encode(), compresslevel=9, mtime=0)


def collect(sources: list[Path], dest: Path, names: Collection[str] | None = None) -> CollectReport:
    """Copy every finished run of the ``sources`` (sweeps or collections) into ``dest``, or only
    those in ``names`` (a collection copied back into a lost sweep directory: ``sili grid``).

    Of one run (the same config but its length) the longest is kept, whichever version of the
    package trained it: an extended run replaces its shorter copy. Two different runs under one
    name, in ``dest`` or among the sources, are an error found before anything is copied, so a
    collection never mixes two versions of a run."""
    report = CollectReport()
    chosen: dict[str, tuple[Path, dict, int]] = {}  # name -> source run, identity, length
    unfinished: dict[str, None] = {}  # (in order, once each)
    damaged: list[str] = []  # all named at once, after every source is read
    for source in sources:
        for run_dir in runs_of(source):
            name = run_dir.name
            if names is not None and name not in names:
                continue
            if not (run_dir / SUMMARY).is_file() or metrics_file(run_dir) is None:
                unfinished[name] = None
                continue
            try:
                length = _length(run_dir)
                _check_sound(run_dir, length)  # a damaged copy never replaces a sound one
            except ConfigError as err:
                damaged.append(str(err))
                continue
            ident = _identity(run_dir)
            target = Path(dest) / RUNS_DIR / name
            if name in chosen:
                _check_same_run(name, chosen[name][0], chosen[name][1], run_dir, ident)
            if (target / CONFIG).is_file() and _readable(target):  # else: copied again
                _check_same_run(name, target, _identity(target), run_dir, ident)
            if name not in chosen or length > chosen[name][2]:
                chosen[name] = (run_dir, ident, length)
    check_none_damaged(damaged)  # before anything is copied
    # a run unfinished in one source and finished in another is collected, not unfinished
    report.unfinished = [name for name in unfinished if name not in chosen]
    for name, (run_dir, _, length) in chosen.items():
        target = Path(dest) / RUNS_DIR / name
        finished = (target / SUMMARY).is_file() and metrics_file(target) is not None
        finished = finished and _readable(target)
        held = _length(target) if finished else 0  # the length dest holds it at, finished
        same = finished and (target / SUMMARY).read_bytes() == (run_dir / SUMMARY).read_bytes()
        if same and not _sound(target, held):  # damaged there: copied again
            same, held = False, 0
        if same or held > length or _rows_trained(target) > length:  # (a sweep's training)
            report.unchanged.append(name)
            continue
        superseded = held < length
        was_there = (target / CONFIG).is_file()
        metrics = metrics_file(run_dir)
        target.mkdir(parents=True, exist_ok=True)
        gz = metrics.name == COMPRESSED_METRICS
        data = metrics.read_bytes() if gz else compressed_metrics(metrics)
        # the summary last, each file whole: an interrupted copy is redone next time
        write_bytes(target / COMPRESSED_METRICS, data)
        write_bytes(target / CONFIG, (run_dir / CONFIG).read_bytes())
        if superseded:  # a shorter training in its place (a sweep's): read before the copy
            for leftover in (METRICS, CHECKPOINT, ERROR_FILE):
                (target / leftover).unlink(missing_ok=True)
        write_bytes(target / SUMMARY, (run_dir / SUMMARY).read_bytes())
        (report.replaced if was_there else report.added).append(name)
    return report


def _identity(run_dir: Path) -> dict[str, Any]:
    """What makes a run the run it is: its config in today's layout, without its length or how
    often it was saved (which changes no number it logs)."""
    run = recorded_run(run_dir)
    run.pop("interactions")
    run.pop("checkpoint_every", None)
    return run


def _rows_trained(run_dir: Path) -> int:
    """How many interactions a training in ``run_dir`` has logged (0 without one)."""
    path = run_dir / METRICS
    if not path.is_file():
        return 0
    with path.open() as f:
        return max(sum(1 for _ in f) - 1, 0)  # the header


def _length(run_dir: Path) -> int:
    """The run's length from its summary, whose numbers must read too (every table reads them)."""
    path = run_dir / SUMMARY
    finished_summary(run_dir)
    length = read_json(path, DAMAGED_SUMMARY, "interactions")["interactions"]
    if not isinstance(length, int) or isinstance(length, bool) or length < 1:
        raise ConfigError(
            f"{path} is damaged (interactions {length!r} is not a count); {DAMAGED_SUMMARY}"
        )
    return length


def _check_sound(run_dir: Path, length: int) -> None:
    """ConfigError naming the run's metrics unless they read back with its ``length`` rows,
    and its config unless the tables can read it, before anything is copied."""
    path = metrics_file(run_dir)
    rows = len(read_metrics(path))
    if rows < length:
        raise ConfigError(
            f"{path} is damaged (it holds {rows} rows, its {SUMMARY} says {length}); "
            f"{DAMAGED_METRICS}"
        )
    run_identity(run_dir)


def _readable(run_dir: Path) -> bool:
    """Whether a collected copy's config and (when it has one) summary read back: a damaged
    copy is copied again, not compared."""
    try:
        run_identity(run_dir)
        if (run_dir / SUMMARY).is_file():
            _length(run_dir)
    except ConfigError:
        return False
    return True


def _sound(run_dir: Path, length: int) -> bool:
    try:
        _check_sound(run_dir, length)
    except ConfigError:
        return False
    return True


def _check_same_run(name: str, there: Path, ident: dict, run_dir: Path, mine: dict) -> None:
    found = run_differences(ident, mine)
    diffs = [f"{k}: {shown_value(k, a)} there, {shown_value(k, b)} here" for k, a, b in found]
    if diffs:
        more = f" and {len(diffs) - 3} more" if len(diffs) > 3 else ""
        raise ConfigError(
            f"{there} holds a different run named {name} ({'; '.join(diffs[:3])}{more}; "
            f"here: {run_dir}); a collection holds one run of a name: collect the other into "
            "another folder (--into)"
        )
