"""One running SUMO simulation, driven in-process by libsumo or over a socket by TraCI.

libsumo keeps a single simulation per process in module-level state: starting a second one
silently replaces the first. So a libsumo session claims the process when it starts and a second
live session in the same process raises :class:`SimulationSlotError`; ``close()`` (or garbage
collection of the owner) gives the slot back, after which a new session may start. Parallel
environments therefore run in subprocesses (e.g. gymnasium's ``AsyncVectorEnv``). The TraCI
backend talks to a ``sumo`` subprocess and has no such limit; it is slower (a socket round trip
per call) and exists mainly as the reference in ``benchmarks/bench_driving.py``.

Errors SUMO reports (``TraCIException``, ``FatalTraCIError``) become :class:`SumoError` carrying
SUMO's own message from its error log, instead of an opaque "Process Error".
"""

from __future__ import annotations

import contextlib
import io
import itertools
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sili_robots.errors import ConfigError, check_choice
from sili_robots.tasks.sumo_scenario import ScenarioFiles, sumo_binary, sumo_home

BACKENDS = ("libsumo", "traci")


class SumoError(RuntimeError):
    """SUMO failed (could not start, or refused a command); the message is SUMO's own."""


class SimulationSlotError(ConfigError, RuntimeError):
    """A second libsumo simulation was requested in a process that already runs one."""


# The libsumo slot of this process: (pid, token) of the live session, or None.
_LIBSUMO_OWNER: dict[str, Any] = {"pid": None, "token": None}
_TOKENS = itertools.count(1)
#: a session's folder in the temporary directory (SUMO's logs, the task's start state), and the
#: file in it that the session keeps locked while its process lives
WORKDIR_PREFIX = "sili-driving-"
WORKDIR_LOCK = "session.lock"
#: a folder is hidden (a leading dot) only between its creation and its lock, microseconds; one
#: hidden for longer than this (seconds) was left by a process killed in between
HIDDEN_LEFTOVER_AGE = 3600.0
#: this process's live session folders: never taken for leftovers (on NFS, flock is a POSIX
#: lock, which the process holding it takes again, and loses on closing any descriptor)
_OWN_WORKDIRS: set[Path] = set()


def _sumo_exceptions() -> tuple[type[BaseException], ...]:
    sumo_home()  # make sure the wheel's SUMO_HOME is in os.environ before the clients import
    import libsumo
    import traci.exceptions

    return (
        libsumo.TraCIException,
        libsumo.FatalTraCIError,
        traci.exceptions.TraCIException,
        traci.exceptions.FatalTraCIError,
    )


class SumoSession:
    """Start SUMO on the scenario's config; ``api`` exposes the TraCI domains (vehicle, ...)."""

    def __init__(self, files: ScenarioFiles, backend: str = "libsumo") -> None:
        check_choice("SUMO backend", backend, BACKENDS)
        if not files.config.is_file():
            raise SumoError(f"SUMO configuration {files.config} does not exist")
        self.backend = backend
        self.closed = False
        self._errors = _sumo_exceptions()
        binary = str(sumo_binary("sumo"))
        token = next(_TOKENS)
        if backend == "libsumo":
            _claim_libsumo(token)
        self.workdir, self._lock = _make_workdir()
        self.error_log = self.workdir / "sumo-errors.log"
        cmd = [binary, "-c", str(files.config), "--error-log", str(self.error_log)]
        connection = None
        try:
            if backend == "libsumo":
                import libsumo

                with _stderr_to(self.workdir / "sumo-start.log"):  # libsumo buffers its log
                    libsumo.start(cmd)
                self.api: Any = libsumo
            else:
                import traci

                label = f"sili-driving-{os.getpid()}-{token}"
                with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # traci's retry chatter
                    traci.start(
                        cmd,
                        label=label,
                        numRetries=2,
                        stdout=subprocess.DEVNULL,
                        doSwitch=False,
                    )
                connection = traci.getConnection(label)
                self.api = connection
        except BaseException as exc:  # give the slot back whatever went wrong
            _shutdown(
                backend, connection, token, self.workdir, None, os.getpid(), keep_workdir=True
            )
            message = self._sumo_message(exc) if isinstance(exc, self._errors) else None
            shutil.rmtree(self.workdir, ignore_errors=True)
            _release(self._lock)  # (held until its logs are read)
            if message is None:
                raise
            raise SumoError(f"SUMO could not start ({backend}): {message}") from None
        self._finalizer = weakref.finalize(
            self, _shutdown, backend, connection, token, self.workdir, self._lock, os.getpid()
        )

    @contextlib.contextmanager
    def guard(self, doing: str) -> Iterator[None]:
        """Turn SUMO's exceptions raised while ``doing`` something into :class:`SumoError`."""
        if self.closed:
            raise RuntimeError("the SUMO simulation of this environment was closed")
        try:
            yield
        except self._errors as exc:
            raise SumoError(f"SUMO failed while {doing}: {self._sumo_message(exc)}") from None

    def _sumo_message(self, exc: BaseException) -> str:
        text = str(exc).strip() or type(exc).__name__
        with contextlib.suppress(OSError):
            errors = [
                line.strip()
                for log in (self.error_log, self.workdir / "sumo-start.log")
                if log.is_file()
                for line in log.read_text(errors="replace").splitlines()
                if line.startswith("Error:")
            ]
            if errors:
                text = f"{text}; SUMO said: {errors[-1]}"
        return text

    def close(self) -> None:
        """Stop SUMO and give the process's libsumo slot back (idempotent)."""
        if self.closed:
            return
        self.closed = True
        self._finalizer()


def _make_workdir() -> tuple[Path, int | None]:
    """A new session folder, locked (the descriptor returned) while this process lives: the
    kernel drops the lock when the process dies, also on a kill, which runs no clean-up. The
    folders whose lock nobody holds were left so, and are removed first, with the hidden ones
    of a process killed before it locked its folder."""
    import fcntl

    root = Path(tempfile.gettempdir())
    for folder in root.glob(f"{WORKDIR_PREFIX}*"):
        if folder in _OWN_WORKDIRS:
            continue
        try:
            held = os.open(folder / WORKDIR_LOCK, os.O_WRONLY)
        except OSError:
            continue  # no lock file (not a session's), or another user's
        try:
            fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # locked: a live session's
        finally:
            os.close(held)  # (the lock, if taken, goes with it)
        shutil.rmtree(folder, ignore_errors=True)
    for folder in root.glob(f".{WORKDIR_PREFIX}*"):
        with contextlib.suppress(OSError):
            if time.time() - folder.stat().st_mtime > HIDDEN_LEFTOVER_AGE:
                shutil.rmtree(folder, ignore_errors=True)
    new = Path(tempfile.mkdtemp(prefix=f".{WORKDIR_PREFIX}"))  # hidden from the scan until
    lock: int | None = os.open(new / WORKDIR_LOCK, os.O_CREAT | os.O_WRONLY, 0o600)  # locked
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # a file system without locks: the folder is never taken for a leftover
        os.close(lock)
        lock = None
        (new / WORKDIR_LOCK).unlink()
    workdir = new.with_name(new.name.removeprefix("."))
    new.rename(workdir)
    _OWN_WORKDIRS.add(workdir)
    return workdir, lock


@contextlib.contextmanager
def _stderr_to(path: Path) -> Iterator[None]:
    """Send file descriptor 2 (SUMO's C++ messages) to ``path`` for the duration."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no usable stderr: nothing to capture
        yield
        return
    try:
        with open(path, "wb") as log:
            os.dup2(log.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _claim_libsumo(token: int) -> None:
    pid = os.getpid()
    if _LIBSUMO_OWNER["token"] is not None and _LIBSUMO_OWNER["pid"] == pid:
        raise SimulationSlotError(
            "libsumo runs one SUMO simulation per process and another Driving environment in "
            "this process still holds it; call close() on that environment first, pass "
            "backend='traci', or run parallel environments in subprocesses (gymnasium "
            "AsyncVectorEnv, stable-baselines3 SubprocVecEnv)"
        )
    if _LIBSUMO_OWNER["token"] is not None:
        # A forked child inherited its parent's simulation: drop this copy before starting ours.
        import libsumo

        with contextlib.suppress(Exception):
            if libsumo.isLoaded():
                libsumo.close()
    _LIBSUMO_OWNER["pid"] = pid
    _LIBSUMO_OWNER["token"] = token


def _shutdown(
    backend: str,
    connection: Any,
    token: int,
    workdir: Path,
    lock: int | None,
    owner: int,
    keep_workdir: bool = False,
) -> None:
    """Close the simulation; also run by the garbage collector for a never-closed session. In a
    forked child (not the ``owner`` process), which inherits this at its exit, only the child's
    copies go: the parent's SUMO and its saved start state (``workdir``) are the parent's."""
    if os.getpid() != owner:
        _OWN_WORKDIRS.discard(workdir)
        _release(lock)
        return
    if backend == "libsumo":
        if _LIBSUMO_OWNER["token"] == token and _LIBSUMO_OWNER["pid"] == os.getpid():
            import libsumo

            with contextlib.suppress(Exception):
                if libsumo.isLoaded():
                    libsumo.close()
            _LIBSUMO_OWNER["pid"] = None
            _LIBSUMO_OWNER["token"] = None
    elif connection is not None:
        with contextlib.suppress(Exception):
            connection.close()
    if not keep_workdir:
        shutil.rmtree(workdir, ignore_errors=True)
    _OWN_WORKDIRS.discard(workdir)
    _release(lock)


def _release(lock: int | None) -> None:
    if lock is not None:
        with contextlib.suppress(OSError):
            os.close(lock)
