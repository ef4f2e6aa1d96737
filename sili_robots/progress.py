"""Training progress: a rich bar at a terminal, a plain line now and then in a log."""

from __future__ import annotations

import datetime
import sys
import time

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Column

#: seconds between the plain lines written to a log (not a terminal)
LOG_EVERY = 60.0


def numbers_column(width: int) -> Column:
    """A column of numbers a narrow terminal must not cut: the label gives way first."""
    return Column(no_wrap=True, min_width=width)


class TrainingProgress:
    """Thin wrapper so the training loop does not care whether progress is shown (not when
    there is nothing left to train: a finished run resumed). On stderr: stdout carries results
    (the JSON summary of ``sili train``), which a redirect must receive alone. Into a log
    (``nohup``, CI, a scheduler) a bar draws only when it stops, so a log gets a plain line
    every ``LOG_EVERY`` seconds and one at the end."""

    def __init__(self, total: int, completed: int, enabled: bool = True, label: str = "") -> None:
        self._progress = None
        self._plain = False
        if not enabled or completed >= total:
            return
        console = Console(stderr=True)
        self.total, self.done, self.label = total, completed, label
        self.reward = self.stable = float("nan")
        self._t0 = self._last = time.monotonic()
        self._started_at = completed
        if not (console.is_interactive or console.is_jupyter):  # a notebook draws the bar
            self._plain = True
            return
        digits = len(str(total))
        self._progress = Progress(
            TextColumn(
                "[bold]{task.description}",
                table_column=Column(no_wrap=True, overflow="ellipsis"),
            ),
            BarColumn(),
            MofNCompleteColumn(table_column=numbers_column(2 * digits + 1)),
            TextColumn("reward {task.fields[reward]:>8.2f}", table_column=numbers_column(15)),
            TextColumn("stable {task.fields[stable]:.2f}", table_column=numbers_column(11)),
            TimeRemainingColumn(table_column=numbers_column(7)),
            console=console,
            redirect_stdout=False,  # a user's prints stay on stdout
        )
        self._task = self._progress.add_task(
            label, total=total, completed=completed, reward=float("nan"), stable=float("nan")
        )
        self._progress.start()

    @property
    def shown(self) -> bool:
        return self._progress is not None or self._plain

    def advance(self, reward: float, stable: float) -> None:
        if self._progress is not None:
            self._progress.update(self._task, advance=1, reward=reward, stable=stable)
        elif self._plain:
            self.done, self.reward, self.stable = self.done + 1, reward, stable
            if time.monotonic() - self._last >= LOG_EVERY:
                self._line()

    def _line(self) -> None:
        self._last = now = time.monotonic()
        elapsed = now - self._t0
        rate = (self.done - self._started_at) / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else None
        eta = "?" if left is None else str(datetime.timedelta(seconds=round(left)))
        print(
            f"{self.label}: {self.done}/{self.total} interactions, reward {self.reward:.2f}, "
            f"stable {self.stable:.2f}, {datetime.timedelta(seconds=round(elapsed))} elapsed, "
            f"{eta} left",
            file=sys.stderr,
            flush=True,
        )

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()
        elif self._plain:
            self._line()
            self._plain = False
