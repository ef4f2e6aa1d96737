"""What a sweep backend does and how it reports: run jobs, tell a monitor as runs start and end."""

from __future__ import annotations

import signal
from collections.abc import Sequence
from typing import Protocol

from sili_robots.sweep.worker import Job, Outcome

#: how long a worker asked to stop (its run's stop file, or SIGTERM) may take to finish and
#: checkpoint its interaction before it is killed (by the sweep, either backend) or exits (an
#: orphan whose sweep is gone)
STOP_GRACE_S = 30.0


class Monitor(Protocol):
    """Receives a backend's events; ``tick`` is called about once a second while runs go on."""

    def started(self, job: Job) -> None: ...

    def finished(self, outcome: Outcome) -> None: ...

    def retrying(self, job: Job, reason: str) -> None: ...

    def tick(self) -> None: ...


class Backend(Protocol):
    def run(self, jobs: Sequence[Job], monitor: Monitor) -> list[Outcome]: ...


class NullMonitor:
    """A monitor that ignores everything (for API use without a display)."""

    def started(self, job: Job) -> None:
        pass

    def finished(self, outcome: Outcome) -> None:
        pass

    def retrying(self, job: Job, reason: str) -> None:
        pass

    def tick(self) -> None:
        pass


def describe_exit(exitcode: int | None) -> str:
    """How a worker process ended, in words (``-9`` -> killed by SIGKILL)."""
    if exitcode is None:
        return "worker did not exit"
    if exitcode < 0:
        try:
            return f"worker killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"worker killed by signal {-exitcode}"
    return f"worker exited with code {exitcode} without a result"
