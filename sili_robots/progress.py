"""A rich progress bar for training: interactions, recent task reward and true stability."""

from __future__ import annotations

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn


class TrainingProgress:
    """Thin wrapper so the training loop does not care whether a bar is shown (none when there
    is nothing left to train: a finished run resumed). On stderr: stdout carries results (the
    JSON summary of ``sili train``), which a redirect must receive alone."""

    def __init__(self, total: int, completed: int, enabled: bool = True, label: str = "") -> None:
        self._progress = None
        if enabled and completed < total:
            self._progress = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("reward {task.fields[reward]:>8.2f}"),
                TextColumn("stable {task.fields[stable]:.2f}"),
                TimeRemainingColumn(),
                console=Console(stderr=True),
                redirect_stdout=False,  # a user's prints stay on stdout
            )
            self._task = self._progress.add_task(
                label, total=total, completed=completed, reward=float("nan"), stable=float("nan")
            )
            self._progress.start()

    @property
    def shown(self) -> bool:
        return self._progress is not None

    def advance(self, reward: float, stable: float) -> None:
        if self._progress is not None:
            self._progress.update(self._task, advance=1, reward=reward, stable=stable)

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()
