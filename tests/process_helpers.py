"""Waiting on a training process from a test: its logged rows, a condition, a stop signal."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path


def wait_for(predicate: Callable[[], bool], timeout: float = 120.0) -> bool:
    """Whether ``predicate`` came true within ``timeout`` seconds (no fixed sleep: a loaded
    machine may take much longer than an idle one)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def metrics_rows(path: Path) -> int:
    """The interactions a ``metrics.csv`` holds (0 before it exists)."""
    return max(len(path.read_text().splitlines()) - 1, 0) if path.exists() else 0


def signal_when(
    proc: subprocess.Popen, ready: Callable[[], bool], signum: int = signal.SIGTERM
) -> str:
    """Send ``signum`` to ``proc`` once ``ready()`` holds; its stderr once it has exited (it is
    killed if it does not within two minutes)."""
    try:
        assert wait_for(ready, timeout=240), "the process never got ready to be stopped"
        proc.send_signal(signum)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return stderr


@contextlib.contextmanager
def killing_its_worker_once(run_dir: Path, after_rows: int = 12) -> Iterator[list[int]]:
    """While the block runs (a sweep), SIGKILL the worker training ``run_dir`` once its history
    holds more than ``after_rows`` rows (past a checkpoint); yields the killed pids. No fixed
    deadline: on a loaded machine the worker may take minutes to get there."""
    killed: list[int] = []
    over = threading.Event()

    def kill_once() -> None:
        info = run_dir / "worker.json"
        while not over.is_set():
            if metrics_rows(run_dir / "metrics.csv") > after_rows and info.exists():
                killed.append(json.loads(info.read_text())["pid"])
                os.kill(killed[0], signal.SIGKILL)
                return
            time.sleep(0.02)

    killer = threading.Thread(target=kill_once)
    killer.start()
    try:
        yield killed
    finally:
        over.set()
        killer.join()
    assert killed, "the worker was never killed"
