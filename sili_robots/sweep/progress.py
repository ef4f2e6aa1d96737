"""The sweep's live display: runs done / running / failed / pending, interactions, ETA.

Progress is counted in interactions (rows of each run's ``metrics.csv``), so runs of different
lengths weigh what they cost and the ETA follows the recent rate across all workers. Every run
that ends also gets one printed line, with a finished run's verdict (``sili_robots.verdict``);
that is what a log (no terminal) keeps.
"""

from __future__ import annotations

import time
from pathlib import Path

from rich.console import Console, Group
from rich.live import Live
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Column
from rich.text import Text

from sili_robots.metrics import METRICS
from sili_robots.progress import numbers_column
from sili_robots.runs import CHECKPOINT
from sili_robots.sweep.state import run_state
from sili_robots.sweep.worker import Job, Outcome


def logged_interactions(run_dir: Path) -> int:
    """Rows in a run's ``metrics.csv`` (0 when there is none yet)."""
    try:
        data = (Path(run_dir) / METRICS).read_bytes()
    except FileNotFoundError:
        return 0
    return max(data.count(b"\n") - 1, 0)


class SweepProgress:
    """A :class:`~sili_robots.sweep.backend.Monitor` drawing with rich (or just logging)."""

    def __init__(
        self,
        jobs: list[Job],
        interactions: dict[str, int],
        already_done: int,
        enabled: bool = True,
        console: Console | None = None,
    ) -> None:
        self.console = console or Console(stderr=True)
        self.total_runs = len(jobs) + already_done
        self.done = self.already_done = already_done
        self.failed = 0
        self.running: dict[str, Job] = {}
        self._jobs = {job.name: job for job in jobs}
        self._planned = {job.name: interactions[job.name] for job in jobs}
        self._logged = {job.name: logged_interactions(Path(job.run_dir)) for job in jobs}
        self._total_interactions = sum(interactions.values())
        self._finished_interactions = sum(interactions.values()) - sum(self._planned.values())
        self._last_tick = 0.0
        self._t0 = time.perf_counter()
        self._progress: Progress | None = None
        self._live: Live | None = None
        self._run_tasks: dict[str, TaskID] = {}
        if enabled:
            self._progress = Progress(
                TextColumn(
                    "{task.description}",
                    table_column=Column(no_wrap=True, overflow="ellipsis", max_width=40),
                ),
                BarColumn(bar_width=24),
                # numbers a narrow terminal must not cut: the name gives way first
                MofNCompleteColumn(
                    table_column=numbers_column(2 * len(str(self._total_interactions)) + 1)
                ),
                TimeElapsedColumn(table_column=numbers_column(7)),
                TextColumn("ETA"),
                TimeRemainingColumn(table_column=numbers_column(7)),
                console=self.console,
            )
            self._overall = self._progress.add_task(
                "[bold]all runs (interactions)",
                total=self._total_interactions,
                completed=self._completed(),
            )
            self._live = Live(self, console=self.console, refresh_per_second=4)

    def __rich__(self) -> Group:
        """What the live display shows: the run counts, then the progress bars."""
        return Group(Text.from_markup(self._counts()), self._progress)

    # ------------------------------------------------------------------ monitor
    def started(self, job: Job) -> None:
        self.running[job.name] = job
        if self._progress is not None:
            self._run_tasks[job.name] = self._progress.add_task(
                f"  {job.name}",
                total=self._planned[job.name],
                completed=self._logged[job.name],
            )
        self._refresh(force=True)

    def finished(self, outcome: Outcome) -> None:
        self.running.pop(outcome.name, None)  # first: the display thread reads the counts
        if outcome.status == "done":
            self.done += 1
            self._logged[outcome.name] = self._planned[outcome.name]
            resumed = " (resumed)" if outcome.resumed else ""
            line = f"[green]done[/] {escape(outcome.name)}{resumed} in {outcome.wall_time_s:.1f} s"
            self._log(line + (f": {escape(outcome.verdict)}" if outcome.verdict else ""))
        else:
            self.failed += 1
            job = self._jobs[outcome.name]
            logged = logged_interactions(Path(job.run_dir))
            self._logged[outcome.name] = min(logged, self._planned[outcome.name])
            # what it will not run no longer counts towards the sweep's total
            self._total_interactions -= self._planned[outcome.name] - self._logged[outcome.name]
            if self._progress is not None:
                self._progress.update(self._overall, total=self._total_interactions)
            error = escape(str(outcome.error))
            self._log(f"[red]failed[/] {escape(outcome.name)}: {error}")
        task = self._run_tasks.pop(outcome.name, None)
        if task is not None and self._progress is not None:
            self._progress.remove_task(task)
        self._refresh(force=True)

    def retrying(self, job: Job, reason: str) -> None:
        self.running.pop(job.name, None)
        task = self._run_tasks.pop(job.name, None)
        if task is not None and self._progress is not None:
            self._progress.remove_task(task)
        self._log(f"[yellow]retrying[/] {escape(job.name)}: {escape(reason)}")

    def _log(self, text: str) -> None:
        self.console.print(text, soft_wrap=True, highlight=False)

    def tick(self) -> None:
        self._refresh()

    # ------------------------------------------------------------------ display
    @property
    def pending(self) -> int:
        return self.total_runs - self.done - self.failed - len(self.running)

    def _counts(self) -> str:
        return (
            f"runs: [green]{self.done} done[/] · [cyan]{len(self.running)} running[/] · "
            f"[red]{self.failed} failed[/] · {self.pending} pending (of {self.total_runs})"
        )

    def _completed(self) -> int:
        return self._finished_interactions + sum(self._logged.values())

    def _refresh(self, force: bool = False) -> None:
        now = time.perf_counter()
        if not force and now - self._last_tick < 1.0:
            return
        self._last_tick = now
        for name, job in self.running.items():
            self._logged[name] = min(logged_interactions(Path(job.run_dir)), self._planned[name])
            if self._progress is not None and name in self._run_tasks:
                self._progress.update(self._run_tasks[name], completed=self._logged[name])
        if self._progress is not None:
            self._progress.update(self._overall, completed=self._completed())

    def __enter__(self) -> SweepProgress:
        if self._live is not None:
            self._live.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._refresh(force=True)
            self._live.stop()
            if not self.console.is_terminal:  # a log: end the display's last line (as
                self.console.line()  # rich's Progress.stop does), before the closing one
        for name, job in list(self.running.items()):  # one that ended as the sweep stopped
            if run_state(Path(job.run_dir)) == "done":  # (its outcome not reported) is done
                del self.running[name]
                self.done += 1
        stopped = _stopped_midway([Path(job.run_dir) for job in self.running.values()])
        not_run = self.total_runs - self.done - self.failed
        earlier = f" ({self.already_done} of them earlier)" if self.already_done else ""
        self._log(
            f"sweep: {self.done} done{earlier}, {self.failed} failed, {not_run} not run{stopped}, "
            f"{time.perf_counter() - self._t0:.1f} s"
        )


def _stopped_midway(run_dirs: list[Path]) -> str:
    """The stopped runs, as a resume will find them: one stopped before its first checkpoint
    (e.g. while its worker was starting) trains again from the start."""
    if not run_dirs:
        return ""
    resumable = sum((run_dir / CHECKPOINT).is_file() for run_dir in run_dirs)
    if resumable == len(run_dirs):
        return f" ({resumable} stopped midway, resumable)"
    again = len(run_dirs) - resumable
    before = "it starts" if again == 1 else "they start"
    return (
        f" ({len(run_dirs)} stopped midway: {resumable} resumable, {again} before a first "
        f"checkpoint, {before} again)"
    )
