"""TensorBoard scalars for a run, written from its ``metrics.csv`` as the rows appear.

The training loop writes one CSV row per interaction; a thread in the worker tails that file and
mirrors each row into ``RUN_DIR/tb/`` (step = interaction), so TensorBoard shows runs live
without the training loop knowing about it. A (re)started run rewrites ``tb/`` from the CSV,
which the training loop has already trimmed to its checkpoint, so both always agree; until it
has, ``tb/`` is left as it was (a resume refused before it trains changes nothing).
TensorBoard is optional: without the ``tensorboard`` package nothing is written.
"""

from __future__ import annotations

import contextlib
import csv
import importlib.util
import io
import math
import os
import shutil
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sili_robots.metrics import METRIC_COLUMNS, METRICS
from sili_robots.runs import TB_DIR

#: metrics.csv column -> TensorBoard tag (true stability is derived: 1 - strategy_changed)
TAGS = {
    "task_reward": "reward/task",
    "stability_reward": "reward/stability",
    "strategy_changed": "stability/strategy_changed",
    "latent_changed": "stability/latent_changed",
    "beta": "train/beta",
    "latent_loss": "loss/latent",
    "critic_loss": "loss/critic",
    "actor_loss": "loss/actor",
    "alpha": "train/alpha",
}
TRUE_STABILITY_TAG = "stability/true"


def available() -> bool:
    """Whether TensorBoard's writer can be used (the optional ``tensorboard`` package)."""
    return importlib.util.find_spec("tensorboard") is not None


def _scalars(row: dict[str, str]) -> dict[str, float]:
    out = {}
    for column, tag in TAGS.items():
        text = row.get(column, "")
        if text not in ("", None):
            value = float(text)
            if math.isfinite(value):
                out[tag] = value
    if "stability/strategy_changed" in out and row.get("interaction") != "0":
        out[TRUE_STABILITY_TAG] = 1.0 - out["stability/strategy_changed"]  # 0 keeps nothing
    return out


class MetricsTail:
    """Mirror ``metrics.csv`` into TensorBoard event files, polling every ``interval`` seconds.

    Waits until the training loop has (re)created the CSV (a new file, see
    ``metrics.MetricsWriter``) so rows a resume is about to drop are never mirrored.
    """

    def __init__(self, run_dir: Path, interval: float = 2.0) -> None:
        self.run_dir = Path(run_dir)
        self.interval = interval
        self._path = self.run_dir / METRICS
        self._old_inode = self._inode()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="tensorboard-tail", daemon=True)
        self._writer: Any = None  # a SummaryWriter from the first rows on
        self._file: io.TextIOBase | None = None
        self._pending = ""
        self.rows_written = 0
        self.failed = False

    def _inode(self) -> int | None:
        try:
            return os.stat(self._path).st_ino
        except FileNotFoundError:
            return None

    def start(self) -> None:
        from torch.utils.tensorboard import SummaryWriter  # noqa: F401  (fails here if absent)

        self._thread.start()

    def stop(self) -> None:
        """Mirror what is left and close (the run is over, however it ended)."""
        self._stop.set()
        self._thread.join()
        self._safe_poll()
        if self._file is not None:
            self._file.close()
        if self._writer is not None:
            self._writer.close()

    def _loop(self) -> None:
        while not self._stop.wait(self.interval) and self._safe_poll():
            pass

    def _safe_poll(self) -> bool:
        """Poll; on an error warn once and stop mirroring (the run itself goes on)."""
        if self.failed:
            return False
        try:
            self.poll()
        except Exception as err:
            self.failed = True
            name = self.run_dir.name
            warnings.warn(f"TensorBoard scalars stopped for {name}: {err}", stacklevel=2)
        return not self.failed

    def poll(self) -> None:
        if self._file is None:
            inode = self._inode()
            if inode is None or inode == self._old_inode:
                return  # training has not (re)created the CSV yet (or never did)
            from torch.utils.tensorboard import SummaryWriter

            # only now: a run refused or failed before it trains keeps its scalars
            shutil.rmtree(self.run_dir / TB_DIR, ignore_errors=True)
            self._writer = SummaryWriter(str(self.run_dir / TB_DIR))
            self._file = self._path.open(newline="")
            self._file.readline()  # header
        chunk = self._pending + self._file.read()
        lines = chunk.split("\n")
        self._pending = lines.pop()  # an incomplete last line waits for the next poll
        for values in csv.reader(line.rstrip("\r") for line in lines if line.strip()):
            row = dict(zip(METRIC_COLUMNS, values, strict=False))
            step = int(row["interaction"])
            for tag, value in _scalars(row).items():
                self._writer.add_scalar(tag, value, step)
            self.rows_written += 1
        self._writer.flush()


@contextlib.contextmanager
def mirrored(run_dir: Path, enabled: bool) -> Iterator[None]:
    """Mirror the run's metrics into TensorBoard while it trains (``enabled``); a TensorBoard
    problem only turns the scalars off (with a warning), it never fails the run."""
    tail = None
    if enabled:
        try:
            tail = MetricsTail(run_dir)
            tail.start()
        except Exception as err:
            warnings.warn(f"TensorBoard scalars off for {Path(run_dir).name}: {err}", stacklevel=2)
            tail = None
    try:
        yield
    finally:
        if tail is not None:
            tail.stop()
