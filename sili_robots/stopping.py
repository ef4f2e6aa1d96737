"""Stopping a training run between interactions, so that a stop loses no work.

A stop signal (Ctrl-C, SIGTERM from ``timeout``, a job scheduler or a sweep, SIGHUP) that
arrives while an interaction is played or learned from is held until the interaction is logged;
the training loop then checkpoints and lets the signal act as it would have (its previous
handler: ``KeyboardInterrupt``, the CLI's exit code, a sweep worker's exit). A second stop
acts at once, as itself. Signals that are ignored stay ignored.

``timeout`` and job schedulers signal a process and then its whole process group, so one stop
can reach a process twice, a moment apart: the same signal again within ``SAME_STOP_S`` is
that one stop, not a second.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: seconds within which the same stop signal again is the one stop sent twice (``timeout``'s
#: two sends are microseconds apart, a busy machine's milliseconds); a person's second Ctrl-C
#: comes later
SAME_STOP_S = 0.3
#: the stops ``act_as`` is passing on now: a held stop, never the same one again
_passed_on: list[int] = []


class RepeatedStops:
    """Tells a stop signal from the same one delivered twice (one per handler)."""

    def __init__(self) -> None:
        self._first: dict[int, float] = {}

    def repeated(self, signum: int) -> bool:
        """Whether ``signum`` is the stop received just before; else it is noted as a stop."""
        now, first = time.monotonic(), self._first.get(signum)
        if first is not None and now - first < SAME_STOP_S and signum not in _passed_on:
            return True
        self._first[signum] = now
        return False


def exit_on_signal(signum: int, _frame: object) -> None:
    """A handler that exits with 128 + signal, as a shell reports it, running ``finally``
    blocks on the way (which close simulators and servers)."""
    raise SystemExit(128 + signum)


def act_as(signum: int, handler: object) -> None:
    """Let ``signum`` act through ``handler`` as the signal itself would (called like a signal
    handler, or raised again for the default); an ignored one does nothing."""
    if callable(handler):
        _passed_on.append(signum)
        try:
            handler(signum, None)
        finally:
            _passed_on.pop()
    elif handler != signal.SIG_IGN:
        signal.raise_signal(signum)


class StopBetweenInteractions:
    """``with StopBetweenInteractions() as stop:`` around the loop; ``stop.requested`` says a
    stop is held (checkpoint now), ``stop.deliver()`` lets it act."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, signal.Handlers | object] = {}
        self._stops = RepeatedStops()

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def __enter__(self) -> StopBetweenInteractions:
        if threading.current_thread() is threading.main_thread():  # only it may set handlers
            for sig in STOP_SIGNALS:
                if signal.getsignal(sig) not in (signal.SIG_IGN, None):
                    self._previous[sig] = signal.signal(sig, self._hold)
        return self

    def __exit__(self, exc_type: object, *_: object) -> None:
        self._restore()
        if exc_type is None:
            self.deliver()  # held during the last interaction: it still stops the command

    def deliver(self) -> None:
        """Let a held stop act now, through the handler it would have met."""
        if self.signum is None:
            return
        signum, self.signum = self.signum, None
        handler = self._previous.get(signum)
        self._restore()
        # called as the signal would: a raised one may not reach it (Ray's workers do not route
        # SIGINT to Python)
        act_as(signum, handler)

    def _hold(self, signum: int, _frame: FrameType | None) -> None:
        if self._stops.repeated(signum):
            return
        if self.signum is not None:  # asked twice: at once, as the second signal says
            self.signum = signum
            self.deliver()
            return
        self.signum = signum
        if signum == signal.SIGINT:  # a person at a terminal; os.write: no stream is re-entered
            os.write(2, b"\nstopping after this interaction, once it is saved (again: now)\n")

    def _restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}


class HeldStops(StopBetweenInteractions):
    """``with HeldStops():`` around a short step that must not be cut (a model taking back its
    run's checkpoint after training): every stop is held, and the first acts at the end."""

    def _hold(self, signum: int, _frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum

    def __exit__(self, exc_type: object, *_: object) -> None:
        self._restore()
        self.deliver()  # also when the step failed: a stop asked for meanwhile still acts
