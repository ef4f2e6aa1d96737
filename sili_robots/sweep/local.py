"""Local backend: at most K worker processes on this machine, a fresh process for every run.

A fresh process per run (not a long-lived pool) keeps runs apart: libsumo allows one simulation
per process, nothing one run loads leaks into the next, and a worker that dies (killed, out of
memory) takes only its own run down, where ``concurrent.futures`` would break the whole pool.
Processes come from ``multiprocessing``'s forkserver, which has imported torch and the training
code once (a worker starts in a fraction of a second instead of ~3 s), or from ``spawn``. Never
``fork``: it would copy the parent's threads and state. Workers stop when the sweep process dies,
however it dies, so none keeps training a run that a later sweep resumes.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path

from sili_robots.errors import ConfigError, check_count
from sili_robots.runs import RUNNING_FILE, STOP_FILE
from sili_robots.sweep.backend import STOP_GRACE_S, Monitor, describe_exit
from sili_robots.sweep.worker import (
    THREAD_ENV,
    Job,
    Outcome,
    limit_threads,
    record_failure,
    run_job,
)

#: what the sweep sends a worker still running after its grace: stop at once (SIGTERM is held
#: until the interaction ends, and two close together may reach Python as one)
STOP_NOW = signal.SIGUSR1
#: how long a worker sent STOP_NOW may take to run its `finally` blocks before SIGKILL
KILL_AFTER_S = 5.0
#: imported once by the forkserver, so forked workers start with them loaded (the first keeps
#: the forkserver alive through a stop signal sent to the whole process group)
PRELOAD = [
    "sili_robots.sweep.forkserver_signals",
    "sili_robots.sweep.worker",
    "sili_robots.training",
    "torch.utils.tensorboard",
]


def _exit_when_orphaned(alive: Connection) -> None:
    """Stop this worker when the sweep process is gone, however it ended (even SIGKILL).

    Only the sweep holds the write end of ``alive``, so reading it returns EOF exactly when the
    sweep has died. (``PR_SET_PDEATHSIG`` would not do: a forkserver worker's parent is the
    forkserver, which itself lives as long as any worker does.)
    """

    def watch() -> None:
        with contextlib.suppress(EOFError, OSError):
            alive.recv()
        os.kill(os.getpid(), signal.SIGTERM)  # `finally` blocks run, simulators close
        time.sleep(STOP_GRACE_S)
        os._exit(1)

    threading.Thread(target=watch, name="sweep-watchdog", daemon=True).start()


def _exit_now(signum: int, _frame: object) -> None:
    """Exit as a stopped worker does (128 + SIGTERM), running the `finally` blocks on the way
    (they close simulators) undisturbed: a further stop signal is ignored from here on."""
    for sig in (signal.SIGTERM, STOP_NOW):
        signal.signal(sig, signal.SIG_IGN)
    raise SystemExit(128 + signal.SIGTERM)


def _child(job: Job, conn: Connection, alive: Connection) -> None:
    """Entry point of a worker process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the sweep's to handle
    signal.signal(signal.SIGTERM, _exit_now)  # held while an interaction is played, then acts
    signal.signal(STOP_NOW, _exit_now)  # never held: the sweep's stop past a worker's grace
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a hangup too: the sweep stops its workers
    _exit_when_orphaned(alive)
    limit_threads()
    try:
        outcome = run_job(job)
    except KeyboardInterrupt:  # its stop file: stopped after a checkpoint, as the sweep asked
        return
    conn.send(outcome.to_dict())
    conn.close()


@dataclass
class _Worker:
    process: mp.process.BaseProcess
    conn: Connection
    job: Job


class LocalBackend:
    """Run jobs in up to ``workers`` processes; a crashed worker's run is retried ``retries``
    times (it resumes from its checkpoint), then reported failed."""

    def __init__(
        self, workers: int = 1, retries: int = 0, start_method: str = "forkserver"
    ) -> None:
        workers, retries = check_count("workers", workers), check_count("retries", retries, 0)
        if start_method not in ("spawn", "forkserver"):
            raise ConfigError(
                f"start method {start_method!r} is not allowed; use spawn or forkserver "
                "(fork would copy the parent's threads and simulators)"
            )
        self.workers = workers
        self.retries = retries
        if start_method not in mp.get_all_start_methods():
            start_method = "spawn"
        self.start_method = start_method
        self._ctx = mp.get_context(start_method)

    def _ensure_forkserver(self) -> None:
        """Start the forkserver with the training code imported, under one-thread settings."""
        if self.start_method != "forkserver":
            return
        from multiprocessing import forkserver

        self._ctx.set_forkserver_preload(PRELOAD)
        saved = {var: os.environ.get(var) for var in THREAD_ENV}
        os.environ.update(dict.fromkeys(THREAD_ENV, "1"))
        try:
            forkserver.ensure_running()
        finally:
            for var, value in saved.items():
                if value is None:
                    os.environ.pop(var, None)
                else:
                    os.environ[var] = value

    def _start(self, job: Job, alive: Connection) -> _Worker:
        parent_conn, child_conn = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(
            target=_child, args=(job, child_conn, alive), name=f"sili-{job.name}", daemon=True
        )
        proc.start()
        child_conn.close()
        return _Worker(proc, parent_conn, job)

    def run(self, jobs: Sequence[Job], monitor: Monitor) -> list[Outcome]:
        pending = deque(jobs)
        attempts = {job.name: 0 for job in jobs}
        running: dict[int, _Worker] = {}
        outcomes: list[Outcome] = []
        if pending:
            self._ensure_forkserver()
        # workers hold the read end; it reaches EOF when this process (the write end) is gone
        alive_r, alive_w = self._ctx.Pipe(duplex=False)
        try:
            while pending or running:
                while pending and len(running) < self.workers:
                    job = pending.popleft()
                    attempts[job.name] += 1
                    worker = self._start(job, alive_r)
                    running[worker.process.sentinel] = worker
                    monitor.started(job)
                for sentinel in wait(list(running), timeout=1.0):
                    worker = running.pop(sentinel)
                    outcome = self._collect(worker)
                    if outcome is None:
                        reason = describe_exit(worker.process.exitcode)
                        if attempts[worker.job.name] <= self.retries:
                            monitor.retrying(worker.job, reason)
                            pending.appendleft(worker.job)
                            continue
                        outcome = Outcome(worker.job.name, "failed", error=reason)
                        _record_crash(worker.job, reason)
                    outcomes.append(outcome)
                    monitor.finished(outcome)
                monitor.tick()
        finally:
            self._stop(running.values())
            alive_r.close()
            alive_w.close()
        return outcomes

    @staticmethod
    def _collect(worker: _Worker) -> Outcome | None:
        worker.process.join()
        try:
            if worker.conn.poll():
                return Outcome(**worker.conn.recv())
        except (EOFError, OSError):
            pass
        finally:
            worker.conn.close()
        return None

    @staticmethod
    def _stop(workers: Iterable[_Worker]) -> None:
        """Stop the workers still running (an interrupted sweep) as a Ray sweep does: each
        run's stop file asks its training to stop once the interaction it is in is logged and
        checkpointed. No signal is sent first: a worker may already hold one (``timeout`` and
        job schedulers signal the whole process group), and a second stops it at once, losing
        the interaction. A worker still running after ``STOP_GRACE_S``, or at a second stop of
        the sweep, is sent ``STOP_NOW``, and killed if still there ``KILL_AFTER_S`` later."""
        workers = list(workers)
        stop_files = [Path(w.job.run_dir) / STOP_FILE for w in workers]
        for path in stop_files:
            with contextlib.suppress(OSError):
                path.touch()
        try:
            deadline = time.monotonic() + STOP_GRACE_S
            for w in workers:
                w.process.join(timeout=max(0.0, deadline - time.monotonic()))
        finally:
            for w in workers:
                if w.process.is_alive() and w.process.pid is not None:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(w.process.pid, STOP_NOW)
            deadline = time.monotonic() + KILL_AFTER_S
            for w in workers:
                w.process.join(timeout=max(0.0, deadline - time.monotonic()))
                if w.process.is_alive():
                    w.process.kill()
                    w.process.join()
                    (Path(w.job.run_dir) / RUNNING_FILE).unlink(missing_ok=True)
                w.conn.close()
            for path in stop_files:
                path.unlink(missing_ok=True)


def _record_crash(job: Job, reason: str) -> None:
    record_failure(Path(job.run_dir), reason + "\n")
    (Path(job.run_dir) / RUNNING_FILE).unlink(missing_ok=True)
