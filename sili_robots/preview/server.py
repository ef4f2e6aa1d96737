"""A live meshcat server that never outlives the process that started it.

meshcat-python 0.3.2's ``Visualizer.close()`` raises (its window has no ``close``) and its own
server launcher only cleans up at interpreter exit, so a crash, a SIGTERM or a killed parent
leaves ``meshcat-server`` running with its ports taken. Here the server runs in its own process
group, listens on 127.0.0.1 only, is stopped in ``LiveServer.stop()`` on every exit path
(``with`` block, Ctrl-C, SIGTERM turned into ``SystemExit`` while serving), and exits by itself
when the process that started it ends without cleaning up (see ``meshcat_child``).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import meshcat

from sili_robots.stopping import exit_on_signal

STARTUP_TIMEOUT = 20.0


class ServerError(RuntimeError):
    """The meshcat server did not start or stopped by itself."""


class LiveServer:
    """``with LiveServer() as server: server.visualizer[...]`` — the server stops on exit."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen | None = None
        self.zmq_url = ""
        self.web_url = ""
        self.visualizer: meshcat.Visualizer | None = None
        self._log: Path | None = None

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def start(self) -> LiveServer:
        fd, log = tempfile.mkstemp(prefix="sili-meshcat-", suffix=".log")
        self._log = Path(log)
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-u", "-m", "sili_robots.preview.meshcat_child", str(os.getpid())],
                stdin=subprocess.DEVNULL,
                stdout=fd,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        finally:
            os.close(fd)
        try:
            self.zmq_url, self.web_url = self._wait_for_urls()
            # read: nothing else is needed from the log, and a killed parent leaves no file
            self._log.unlink(missing_ok=True)
            # meshcat prints the URL itself when it connects; the caller prints it instead
            with contextlib.redirect_stdout(io.StringIO()):
                self.visualizer = meshcat.Visualizer(zmq_url=self.zmq_url)
            self.visualizer.window.zmq_socket.setsockopt(zmq_linger(), 0)
        except BaseException:
            self.stop()
            raise
        return self

    def _wait_for_urls(self) -> tuple[str, str]:
        assert self.proc is not None and self._log is not None
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while time.monotonic() < deadline:
            text = self._log.read_text(errors="replace")
            zmq_m = re.search(r"^zmq_url=(\S+)$", text, re.M)
            web_m = re.search(r"^web_url=(\S+)$", text, re.M)
            if zmq_m and web_m:
                return zmq_m.group(1), web_m.group(1)
            if self.proc.poll() is not None:
                raise ServerError(
                    f"meshcat server exited with code {self.proc.returncode}: {text[-500:]}"
                )
            time.sleep(0.05)
        raise ServerError(f"meshcat server did not start within {STARTUP_TIMEOUT} s")

    def stop(self) -> None:
        """Close the connection and end the server's whole process group; idempotent."""
        vis, self.visualizer = self.visualizer, None
        if vis is not None:
            # not vis.close(): it raises AttributeError in meshcat 0.3.2
            with contextlib.suppress(Exception):
                vis.window.zmq_socket.close(linger=0)
        proc, self.proc = self.proc, None
        if proc is not None:
            for sig, wait in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 10.0)):
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(proc.pid, sig)
                try:
                    proc.wait(timeout=wait)
                    break
                except subprocess.TimeoutExpired:
                    continue
        if self._log is not None:
            self._log.unlink(missing_ok=True)
            self._log = None

    def serve(
        self, seconds: float | None = None, on_ready: Callable[[], None] | None = None
    ) -> None:
        """Keep the server up for ``seconds`` (forever when None) or until Ctrl-C/SIGTERM.
        ``on_ready`` runs once SIGTERM is handled, so a caller told the URL can stop it at once."""
        previous = signal.getsignal(signal.SIGTERM)
        in_main = _in_main_thread()
        if in_main:
            signal.signal(signal.SIGTERM, exit_on_signal)
        try:
            if on_ready is not None:
                on_ready()
            end = None if seconds is None else time.monotonic() + seconds
            while end is None or time.monotonic() < end:
                if self.proc is None or self.proc.poll() is not None:
                    raise ServerError("the meshcat server stopped unexpectedly")
                time.sleep(0.2 if end is None else max(0.0, min(0.2, end - time.monotonic())))
        finally:
            if in_main:
                signal.signal(signal.SIGTERM, previous)

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def zmq_linger() -> int:
    import zmq

    return zmq.LINGER


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()
