"""Stop signals held until an interaction is logged (the loop's side: test_train_cli.py)."""

from __future__ import annotations

import signal

import pytest

from sili_robots import cli, stopping
from sili_robots.stopping import HeldStops, StopBetweenInteractions


@pytest.fixture
def handlers():
    """Ctrl-C as in a terminal, SIGHUP ignored as under nohup; both put back afterwards."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGHUP)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    yield
    for sig, handler in previous.items():
        signal.signal(sig, handler)


class FakeClock:
    """``time.monotonic`` that moves only when a test moves it."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    fake = FakeClock()
    monkeypatch.setattr(stopping, "time", fake)
    return fake


def test_a_stop_is_held_until_delivered_and_a_second_acts_at_once(handlers, clock):
    with StopBetweenInteractions() as stop:
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN  # ignored stays ignored
        signal.raise_signal(signal.SIGINT)
        assert stop.requested  # held: no KeyboardInterrupt mid-interaction
        clock.now += stopping.SAME_STOP_S / 2
        signal.raise_signal(signal.SIGINT)  # the same stop again (to the process group)
        assert stop.requested
        clock.now += stopping.SAME_STOP_S
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)  # asked twice
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(KeyboardInterrupt), StopBetweenInteractions() as stop:
        signal.raise_signal(signal.SIGINT)
        assert stop.requested
        stop.deliver()  # the loop's boundary: the stop acts through the handler it met
    with pytest.raises(KeyboardInterrupt), StopBetweenInteractions():
        signal.raise_signal(signal.SIGINT)  # held during the last interaction: still stops
    with StopBetweenInteractions() as stop:
        pass
    assert not stop.requested  # nothing asked: nothing delivered


class Terminated(Exception):
    pass


def _terminated(_signum, _frame):
    raise Terminated


def test_a_second_stop_of_another_kind_acts_as_itself(handlers):
    previous = signal.signal(signal.SIGTERM, _terminated)
    try:
        with pytest.raises(Terminated), StopBetweenInteractions():
            signal.raise_signal(signal.SIGINT)  # Ctrl-C, then `kill`: the run is killed
            signal.raise_signal(signal.SIGTERM)
        assert signal.getsignal(signal.SIGTERM) is _terminated
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_held_stops_hold_every_stop_and_the_first_acts_after_the_step_failed_too(handlers):
    previous = signal.signal(signal.SIGTERM, _terminated)
    try:
        with pytest.raises(KeyboardInterrupt), HeldStops():
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)  # again: still held, the step must not be cut
        with pytest.raises(KeyboardInterrupt), HeldStops():
            signal.raise_signal(signal.SIGINT)  # Ctrl-C first, then a scheduler's stop:
            signal.raise_signal(signal.SIGTERM)  # both held, and the first one acts
        with pytest.raises(Terminated), HeldStops():
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGINT)
        with pytest.raises(Terminated) as stopped, HeldStops():  # a scheduler's SIGTERM ...
            signal.raise_signal(signal.SIGTERM)
            raise ValueError("the checkpoint could not be read")  # ... not lost to an error
        assert isinstance(stopped.value.__context__, ValueError)
        assert signal.getsignal(signal.SIGTERM) is _terminated
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_the_cli_takes_one_stop_sent_twice_as_one_and_a_later_one_as_a_second(handlers, clock):
    """``timeout`` and schedulers signal the command, then its process group."""
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with cli._stop_signals_as_ctrl_c():
            for signum, stopped in ((signal.SIGTERM, cli.Terminated), (signal.SIGINT, None)):
                with pytest.raises(stopped or KeyboardInterrupt):
                    signal.raise_signal(signum)
                signal.raise_signal(signum)  # the same stop: nothing more
                clock.now += stopping.SAME_STOP_S * 1.01
                with pytest.raises(stopped or KeyboardInterrupt):
                    signal.raise_signal(signum)  # a second stop
            assert cli._received == [signal.SIGTERM, signal.SIGTERM]  # Ctrl-C is no signal's
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        signal.signal(signal.SIGINT, _terminated)  # a caller's own Ctrl-C is left to it
        with pytest.raises(Terminated), cli._stop_signals_as_ctrl_c():
            signal.raise_signal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_held_stop_passed_on_acts_where_its_handler_saw_it_just_before(handlers, clock):
    """The held stop is the handler's to act on, not the same stop again."""
    with cli._stop_signals_as_ctrl_c():
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)  # the command's handler: caught (a library's)
        with pytest.raises(KeyboardInterrupt), StopBetweenInteractions() as stop:
            signal.raise_signal(signal.SIGINT)  # at once: held for the interaction's end
            assert stop.requested
            stop.deliver()
