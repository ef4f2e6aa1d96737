"""Errors users see: one type for bad input, caught by the CLI and shown without a traceback."""

from __future__ import annotations

import contextlib
import errno
import numbers
import os
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path


class ConfigError(ValueError):
    """A value given by the user is not allowed; the message names the value and the choices."""


class RenderModeRefused(ConfigError, TypeError):
    """A ``render_mode`` the task does not draw: also a TypeError, as from an ``__init__``
    without that argument, which tools catch to build the task again without one
    (stable-baselines3's ``make_vec_env`` asks for ``rgb_array`` first)."""


class UnreadSettingWarning(UserWarning):
    """A setting the run records but its method never reads (``sili train`` prints a note):
    a category of its own, so a script giving one dict of settings to every method can filter
    it."""


class CutInteractionWarning(UserWarning):
    """An interaction played on ``model.env`` ended before its H steps (a ``TimeLimit``, a
    reset before its end), so the agent's latent strategy does not follow it."""


class TrainingDiverged(ConfigError):
    """A loss became infinite or NaN: settings far outside their usual range."""


class CheckpointMismatch(ConfigError):
    """A checkpoint's networks or replay do not fit the agent its run's settings build (a
    checkpoint copied from another run, or settings edited by hand)."""


#: how a file system refuses a write (full, over a quota or ``ulimit -f``, read-only): the CLI
#: names the file and the cause, no traceback; a run's last checkpoint is kept
STORAGE_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


@contextlib.contextmanager
def writing(path: Path, temporary: Path | None = None) -> Iterator[None]:
    """An OSError while ``path`` is written names it: a full disk's failed ``write`` names no
    file, and one on the ``temporary`` written in its place would name a file then gone."""
    try:
        yield
    except OSError as err:
        named = err.filename is None or (temporary is not None and err.filename == str(temporary))
        if not named or err.errno is None:
            raise
        raise OSError(err.errno, err.strerror, str(path)) from err


#: seeds are what numpy's legacy seeding, torch and gymnasium all accept: 0 .. 2**32 - 1
MAX_SEED = 2**32 - 1


def check_seed(seed: object) -> int:
    """``seed`` as an int (numpy's integers too), or ``ConfigError`` naming it and the range."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise ConfigError(f"seed {seed!r} is not an integer; give one in [0, {MAX_SEED}]")
    if not 0 <= int(seed) <= MAX_SEED:
        raise ConfigError(f"seed {int(seed)} is not allowed: give an integer in [0, {MAX_SEED}]")
    return int(seed)


def check_count(name: str, value: object, low: int = 1, high: int | None = None) -> int:
    """``value`` as an int (numpy's integers too) in [``low``, ``high``], or ``ConfigError``."""
    whole = not isinstance(value, bool) and isinstance(value, numbers.Integral)
    if not (whole and low <= value and (high is None or value <= high)):
        allowed = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ConfigError(f"{name} must be an integer {allowed}, got {value!r}")
    return int(value)


def check_path(name: str, value: object) -> Path:
    """``value`` (a string or path-like) as a ``Path``, ``~`` expanded, or ``ConfigError``:
    pathlib's own ``TypeError`` or NUL-byte ``ValueError`` would escape a check that catches
    ``OSError``."""
    wrong = ConfigError(f"{name} must be a path (a string or pathlib.Path), got {value!r}")
    if isinstance(value, bytes) or not isinstance(value, (str, os.PathLike)):
        raise wrong
    try:
        path = Path(value)
    except TypeError:  # a path-like giving bytes
        raise wrong from None
    given = os.fspath(value)
    if "\0" in given or not given.strip():  # blank: as the CLI's path options
        raise ConfigError(
            f"{name} {given!r} is not a usable path (empty, blank or with a NUL byte)"
        )
    try:  # "~" as the shell (and the CLI's path options) expand it
        return path.expanduser()
    except RuntimeError:  # ~name of no user here
        raise ConfigError(
            f"{name} {given!r}: {given.split(os.sep, 1)[0]!r} names no user with a home on this "
            "machine"
        ) from None


def first_line(err: Exception) -> str:
    """An error as one line of a message: its type and first sentence (a damaged file's
    ``pickle`` or ``pandas`` error runs on over many)."""
    return f"{type(err).__name__}: {str(err).split('. ')[0]}"


def check_flag(name: str, value: object) -> bool:
    """``value`` as a bool (numpy's too), or ``ConfigError``: a string such as ``"no"`` would
    count as true, and ``overwrite="no"`` replace a run."""
    if type(value).__name__ not in ("bool", "bool_"):
        raise ConfigError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_names(name: str, value: object) -> dict:
    """``value`` as a dict keyed by names (settings, task arguments), or ``ConfigError``."""
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"{name} must be a dict of names to values, got {value!r}")
    return dict(value)


def is_number(value: object) -> bool:
    """A real number, numpy's too (``np.float32(0.1)``), and not a bool."""
    return not isinstance(value, bool) and isinstance(value, numbers.Real)


def compared(value: object) -> str:
    """``value`` as a range check compares it: ``np.float32(1.1)`` is 1.100000023841858."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        return repr(int(value))
    return repr(float(value)) if is_number(value) else repr(value)


def one_line_errors(main: Callable[[], object], prog: str) -> None:
    """Run a script's ``main``: bad input (``ConfigError``) is one line on stderr and exit 2, as
    the CLI does, not a traceback."""
    try:
        main()
    except ConfigError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


def check_choice(name: str, value: object, allowed: list[str] | tuple[str, ...]) -> None:
    """Raise ``ConfigError`` unless ``value`` is one of ``allowed``."""
    if value not in allowed:
        raise ConfigError(f"unknown {name} {value!r}; allowed: {', '.join(map(str, allowed))}")
