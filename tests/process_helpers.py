"""Waiting on a training process from a test: its logged rows, a condition, a stop signal."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable
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
