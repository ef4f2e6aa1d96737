"""The ``sili`` command line: one sub-command per module in ``sili_robots.commands``.

Every sub-command module exposes ``add_parser(subparsers)`` and ``run(args) -> int``. Bad input
(``ConfigError`` or an argparse error, a name too long for the file system) exits with code 2 and
a one-line message (a line per damaged run), no traceback; so do, with code 1, an agent too
large for the machine's memory and a file the disk refuses to take (full, over quota, read-only).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import re
import select
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NoReturn

from sili_robots import __version__
from sili_robots.errors import STORAGE_ERRORS, ConfigError
from sili_robots.stopping import RepeatedStops

#: sub-commands, in the order ``sili --help`` lists them
COMMANDS = (
    "rollout",
    "bounds",
    "train",
    "eval",
    "preview",
    "sweep",
    "grid",
    "collect",
    "runs",
    "claims",
    "plot",
)


def _command_modules() -> list:
    return [importlib.import_module(f"sili_robots.commands.{name}") for name in COMMANDS]


class UsageArgsFormatter(argparse.HelpFormatter):
    """argparse's help, except that an option with ``usage_args`` shows them as its arguments
    (``--beta-anneal START END LENGTH [DELAY]``, not argparse's repeated form of nargs="+")."""

    def _format_args(self, action: argparse.Action, default_metavar: str) -> str:
        usage = getattr(action, "usage_args", None)
        return usage or super()._format_args(action, default_metavar)


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse with its errors on one line (its own prints the whole usage before them);
    sub-command parsers inherit the class."""

    commands: dict[str, argparse.ArgumentParser]  # the top-level parser's sub-command parsers

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", UsageArgsFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> OneLineErrorParser:
    parser = OneLineErrorParser(
        prog="sili",
        description="Stable Influencing of Latent Intent: train and evaluate its methods; sweep, "
        "list, collect and plot runs; play the scripted references; rebuild the paper's grid and "
        "claims; preview the tasks.",
    )
    parser.add_argument("--version", action="version", version=f"sili {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in _command_modules():
        module.add_parser(sub)
    parser.commands = sub.choices
    return parser


def _parse(parser: OneLineErrorParser, argv: Sequence[str] | None) -> argparse.Namespace:
    """Arguments the sub-command does not take are its error (``sili bounds: error: ...``,
    pointing at ``sili bounds --help``); those before its name are ``sili``'s."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args, extra = parser.parse_known_args(argv)
    before = argv[: argv.index(args.command)] if args.command in argv else argv
    ours = [a for a in extra if a in before]
    if ours:
        parser.error(f"unrecognized arguments: {' '.join(ours)}")
    if extra:
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    return args


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (``timeout``, a closed terminal, a job scheduler) stops a command as
    Ctrl-C does: ``finally`` blocks run, a sweep stops its workers and writes its tables."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


#: the stop signal a command received; libraries that catch KeyboardInterrupt and raise their
#: own (Ray's waits) lose which signal it was, the command's exit status still tells it
_received: list[int] = []


@contextlib.contextmanager
def _stop_signals_as_ctrl_c() -> Iterator[None]:
    """While a command runs; a signal already ignored (``nohup``'s SIGHUP) stays ignored, and
    one stop delivered twice (to the process, then to its group) acts once."""
    _received.clear()
    stops = RepeatedStops()

    def interrupt(signum: int, frame: object) -> None:
        if not stops.repeated(signum):
            raise KeyboardInterrupt

    def terminate(signum: int, frame: object) -> None:
        if not stops.repeated(signum):
            _received.append(signum)
            raise Terminated(signum)

    handled: dict[int, Callable[[int, object], None]] = {}
    if threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            handled[signal.SIGINT] = interrupt
        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) == signal.SIG_DFL:
                handled[sig] = terminate
    previous = {s: signal.signal(s, handler) for s, handler in handled.items()}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _out_of_memory(err: BaseException) -> bool:
    return isinstance(err, MemoryError) or "can't allocate memory" in str(err)


def _allocation(err: BaseException) -> str:
    """torch's "you tried to allocate 92000000000 bytes" as "85.7 GiB were asked for", as
    numpy's "Unable to allocate 5.68 PiB for an array" reads "5.68 PiB were asked for"."""
    match = re.search(r"allocate (\d+) bytes", str(err))
    if match:
        return f"{_binary_size(int(match.group(1)))} were asked for"
    match = re.search(r"allocate ([\d.]+ [KMGTPE]iB)", str(err))
    return f"{match.group(1)} were asked for" if match else type(err).__name__


def _binary_size(size: int) -> str:
    """Bytes as numpy's allocation error writes them: 3 significant figures in the largest
    binary unit they do not round up out of (1048575 bytes is "1.00 MiB")."""
    units = ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB")
    power = max(size.bit_length() - 1, 1) // 10
    value = size / 1024**power
    if round(value) == 1024:
        power, value = power + 1, value / 1024
    if power >= len(units):
        power, value = len(units) - 1, value * 1024 ** (power - len(units) + 1)
    if power == 0:
        return f"{value:.0f} bytes"
    return f"{value:#.3g} {units[power]}" if round(value) < 1000 else f"{value:#.0f} {units[power]}"


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = _parse(build_parser(), argv)  # imports every command: a second or two
    except KeyboardInterrupt:  # Ctrl-C while starting: nothing has been done yet
        print("sili: interrupted", file=sys.stderr)
        return 130
    try:
        with _stop_signals_as_ctrl_c():
            code = int(args.run(args) or 0)
    except ConfigError as err:
        print(f"sili {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:
        # a SIGTERM or SIGHUP may reach here as a library's own KeyboardInterrupt (Ray's waits)
        signum = stop.signum if isinstance(stop, Terminated) else next(iter(_received), None)
        if signum is None:
            print(f"sili {args.command}: interrupted", file=sys.stderr)
            return 130
        print(f"sili {args.command}: stopped by {signal.Signals(signum).name}", file=sys.stderr)
        return 128 + signum
    except (MemoryError, RuntimeError) as err:
        if not _out_of_memory(err):
            raise
        print(
            f"sili {args.command}: error: out of memory ({_allocation(err)}); the settings that "
            "size the agent (hidden, model.dim, sac.batch_interactions, sac.batch_steps, "
            "model.batch) or its batches per interaction (sac.updates_per_step) may be too large "
            "for this machine",
            file=sys.stderr,
        )
        return 1
    except BrokenPipeError:
        if not _stdout_closed():
            raise  # another pipe (e.g. the browser's): a real failure
        _silence_stdout()
        return 1  # the reader stopped mid-output (`sili runs DIR | head`): cut short, quietly
    except OSError as err:
        if err.errno == errno.ENAMETOOLONG:  # a path given: bad input
            print(
                f"sili {args.command}: error: {err.filename}: the path, or a name in it, is too "
                "long for the file system",
                file=sys.stderr,
            )
            return 2
        if err.errno not in STORAGE_ERRORS:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"sili {args.command}: error: {where}{err.strerror}", file=sys.stderr)
        return 1
    try:
        sys.stdout.flush()  # a closed pipe fails here, not in the interpreter's exit
    except BrokenPipeError:
        _silence_stdout()
    return code


def _stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader has gone."""
    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # not a file, or no poll here
        return False


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's own flush at exit does not fail too."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
