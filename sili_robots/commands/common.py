"""Argument types shared by sub-commands: each rejects bad values with the allowed ones."""

from __future__ import annotations

import argparse
import functools
import math
import os
import re
from pathlib import Path
from typing import Any

from sili_robots.agent.config import LARGEST_INT
from sili_robots.agent.schedule import Schedule
from sili_robots.atomic import check_can_write_in
from sili_robots.build import canonical_task, is_class_path
from sili_robots.errors import MAX_SEED, ConfigError, check_seed
from sili_robots.migrations import setting_path
from sili_robots.runs import MAX_THREADS
from sili_robots.tasks import task_spec

#: the longest name (a path's part) in bytes that most file systems allow
NAME_MAX = 255


def _int_in(text: str, minimum: int, maximum: int = LARGEST_INT) -> int:
    """An integer option's value; the largest a run's counts and sizes can hold by default."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an integer (need >= {minimum})"
        ) from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"{value} is not allowed: need an integer >= {minimum}")
    if value > maximum:
        raise argparse.ArgumentTypeError(f"{value} is not allowed: need an integer <= {maximum}")
    return value


def positive_int(text: str) -> int:
    return _int_in(text, 1)


def non_negative_int(text: str) -> int:
    return _int_in(text, 0)


def threads_arg(text: str) -> int:
    return _int_in(text, 1, MAX_THREADS)


def seed(text: str) -> int:
    """A seed: an integer in [0, MAX_SEED]."""
    try:
        return check_seed(int(text))
    except (ValueError, ConfigError):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a seed: give an integer in [0, {MAX_SEED}]"
        ) from None


def _check_can_create(path: Path, option: str, given: Path, what: str) -> None:
    """ConfigError naming ``given`` unless ``path`` (a directory) exists or can be created:
    the nearest existing ancestor must be a directory a file can be written in. Nothing is
    created, so input found bad later leaves no trace."""
    try:
        check_can_write_in(path)
    except OSError as err:
        raise ConfigError(
            f"{option} {given}: cannot write there ({err.strerror or err}); give {what} that "
            "can be written"
        ) from None


def path_arg(text: str) -> Path:
    """A path option's value, ``~`` expanded as the shell does (it leaves the one in
    ``--out=~/runs`` to us, and pandas would expand it where the rest would not); an empty one
    (``--out ""``, a variable left unset) is refused rather than read as the current directory."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path; give a directory or file name")
    try:
        path = Path(text).expanduser()
    except RuntimeError:  # ~name of no user here (the shell leaves it as it is)
        user = text.split(os.sep, 1)[0]
        raise argparse.ArgumentTypeError(
            f"{text}: '{user}' names no user with a home on this machine"
        ) from None
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)  # ".": no parts
    if longest > NAME_MAX:  # found here: pathlib's checks return False
        raise argparse.ArgumentTypeError(
            f"{text}: a name in it is too long ({longest} bytes; most file systems allow "
            f"{NAME_MAX})"
        )
    return path


def writable_dir(path: Path, option: str) -> Path:
    """``path`` if it is, or can be made, a directory to write in; else ``ConfigError``."""
    _check_can_create(path, option, path, "a directory")
    return path


def writable_file(path: Path, option: str) -> Path:
    """``path`` if a file can be written there (its directory may not exist yet), else
    ``ConfigError`` naming it."""
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a directory; give a file name")
    _check_can_create(path.parent, option, path, "a file")
    return path


def float_in(
    text: str, low: float = -math.inf, high: float = math.inf, low_open: bool = False
) -> float:
    """A number in [low, high] (``low_open``: (low, high]); with no bounds, any finite one."""
    bounded = math.isfinite(low) or math.isfinite(high)
    span = f"{'(' if low_open else '['}{low:g}, {high:g}]"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number" + (f" in {span}" if bounded else "")
        ) from None
    if not bounded and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    if not (low < value <= high if low_open else low <= value <= high):
        raise argparse.ArgumentTypeError(f"{value} is outside the allowed range {span}")
    return value


def unit_float(text: str) -> float:
    return float_in(text, 0.0, 1.0)


def parse_schedule(
    text: str, option: str, low: float = -math.inf, high: float = math.inf
) -> Schedule:
    """``"250:0,300:0.5"`` -> Schedule(((250, 0.0), (300, 0.5))), unparsable points named."""
    try:
        points = [(non_negative_int(i), float_in(v, low, high)) for _, i, v in Schedule.items(text)]
    except (ConfigError, argparse.ArgumentTypeError) as err:
        raise ConfigError(f"{option} {text!r}: {err}") from None
    return Schedule(tuple(points))  # the config's check names a bad order


#: schedule options of ``sili train`` and ``sili sweep``:
#: option -> (setting path, metavar, what it sets, example, low, high)
SCHEDULE_ARGS: dict[str, tuple[str, str, str, str, float, float]] = {
    "--beta-schedule": (
        "sili.beta",
        "I:B,I:B,...",
        "b (sili, smirl)",
        "250:0,300:0.5,1500:0.5,1600:0",
        0.0,
        1.0,
    ),
    "--target-entropy-schedule": (
        "sac.target_entropy",
        "I:E,I:E,...",
        "SAC's target entropy (default -|A| throughout)",
        "1500:-2,1600:-4",
        -math.inf,
        math.inf,
    ),
    "--discount-schedule": (
        "sac.gamma",
        "I:G,I:G,...",
        "SAC's discount gamma (default 0.99)",
        "1600:0.99,1700:0.998",
        0.0,
        1.0,
    ),
    "--lr-schedule": (
        "sac.lr",
        "I:LR,I:LR,...",
        "SAC's learning rate (default 3e-4)",
        "2200:3e-4,2400:3e-5",
        0.0,
        1.0,
    ),
}


def add_schedule_args(p: argparse.ArgumentParser, scope: str) -> None:
    for option, (_, metavar, what, example, *_) in SCHEDULE_ARGS.items():
        p.add_argument(
            option,
            metavar=metavar,
            help=f"{what}{scope}, piecewise linear through (interaction, value) points, held "
            f"before the first and after the last; e.g. {example} (the other settings that take "
            "schedules take the same form through --set PATH=I:V,I:V)",
        )


def schedule_args(args: argparse.Namespace) -> dict[str, Schedule]:
    """The schedule options given, parsed, keyed by their setting path."""
    out: dict[str, Schedule] = {}
    for option, (path, _, _, _, low, high) in SCHEDULE_ARGS.items():
        text = getattr(args, option[2:].replace("-", "_"))
        if text is not None:  # an empty one is refused, not read as none given
            out[path] = parse_schedule(text, option, low, high)
    return out


def check_schedule_overrides(
    schedules: dict[str, Schedule],
    settings: dict[str, Any],
    options: dict[str, str] | None = None,
) -> None:
    """Refuse a schedule option given together with ``--set`` of the setting it schedules.

    ``options`` names the option that gave each schedule (setting path -> option) where it is
    not the one ``SCHEDULE_ARGS`` lists for that setting (e.g. ``--beta-anneal``)."""
    given = {setting_path(name): name for name in settings}
    for option, (path, *_) in SCHEDULE_ARGS.items():
        if path in schedules and path in given:
            option = (options or {}).get(path, option)
            raise ConfigError(f"give one of --set {given[path]} and {option}, not both")


def parse_settings(items: list[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` pairs: JSON values, ``I:V,I:V`` as a schedule, else a string."""
    out = parse_env_kwargs(items, "--set")
    for key, value in out.items():
        if isinstance(value, str) and SCHEDULE_START.match(value):
            out[key] = parse_schedule(value, f"--set {key}")  # a bad point named
    return out


#: a value that starts as a schedule (``I:V``) is read as one
SCHEDULE_START = re.compile(r"\s*\d+\s*:")


def task_name(text: str) -> str:
    """A registered task's CLI name, or a user's ``package.module:ClassName`` (checked)."""
    try:
        return canonical_task(text)
    except ConfigError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def registered_task(text: str, command: str, why: str) -> str:
    """A registered task's CLI name for a command that only registered tasks have data for
    (``why``); a user's task class is told so, not called unknown."""
    if is_class_path(text):
        raise argparse.ArgumentTypeError(f"{text!r} is a task class; sili {command} {why}")
    try:
        return task_spec(text).name
    except ConfigError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def parse_env_kwargs(items: list[str], flag: str) -> dict:
    """``KEY=VALUE`` pairs with JSON values (bare words are taken as strings), in the order
    each key was last given, so a later name of the same setting (``lr`` for ``sac.lr``) wins."""
    import json

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{flag} takes KEY=VALUE, got {item!r}")
        out.pop(key, None)
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def task_kwargs_arg(args: argparse.Namespace) -> dict:
    """``--env-kwarg`` pairs, which may not name the controller ``--controller`` gives."""
    env_kwargs = parse_env_kwargs(args.env_kwarg, "--env-kwarg")
    if args.controller is not None and "controller" in env_kwargs:
        raise ConfigError("give one of --controller and --env-kwarg controller=..., not both")
    return env_kwargs


def task_arguments_given(args: argparse.Namespace) -> dict:
    """The task arguments of a command that builds one task: ``--env-kwarg`` pairs and the
    ``--controller``."""
    env_kwargs = task_kwargs_arg(args)
    if args.controller is not None:
        env_kwargs["controller"] = args.controller
    return env_kwargs


def add_override_args(
    p: argparse.ArgumentParser, scope: str, refused: str = "", refused_kwargs: str = ""
) -> None:
    """``--set KEY=VALUE`` (agent settings) and ``--env-kwarg KEY=VALUE`` (task arguments);
    ``refused``, ``refused_kwargs``: what the command takes through its own options instead."""
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="agent_set",
        help=f"override an agent or add-on setting{scope} (JSON value), repeatable, "
        "e.g. --set sac.updates_per_step=0.5; your own add-on: --set "
        f"addons.plugins=module:ClassName{refused}",
    )
    add_env_kwarg_arg(p, scope, refused_kwargs)


def add_env_kwarg_arg(p: argparse.ArgumentParser, scope: str = "", note: str = "") -> None:
    p.add_argument(
        "--env-kwarg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"extra task constructor argument{scope} (JSON value), repeatable{note}",
    )


def add_task_args(p: argparse.ArgumentParser, only: str = "") -> None:
    """``--controller`` and ``--env-kwarg``: the task arguments of a command that plays a task
    (``task_kwargs_arg`` reads them); ``only``: where the command takes them."""
    p.add_argument("--controller", help=f"controller of a robot task ({CONTROLLERS_HELP}){only}")
    add_env_kwarg_arg(p, note=only)


#: the controllers, for help texts (written out: importing them at start-up loads MuJoCo)
CONTROLLERS_HELP = "sawyer-reach: mink, the default; osc; joint_velocity"
LATENT_HELP = (
    "discrete (categories), continuous (a vector), partial (no model: the observation's "
    "'strategy changed' flag) or true (the true strategy, a diagnostic); default: the task's "
    "(continuous on circle-continuous, partial on speaker-listener, where lili takes discrete; "
    "else discrete)"
)


def track_typed_options(p: argparse.ArgumentParser) -> None:
    """Record on the parsed arguments which options were typed, whatever their value (an option
    typed at its default counts), for ``given_options``; call after the last ``add_argument``."""
    for action in p._actions:
        if action.option_strings and not isinstance(action, argparse._HelpAction):
            action.__class__ = _typed(type(action))
    names = {a.dest: a.option_strings[0] for a in p._actions if a.option_strings}
    p.set_defaults(option_names=names, typed_options=())


@functools.cache
def _typed(cls: type[argparse.Action]) -> type[argparse.Action]:
    class Typed(cls):  # type: ignore[valid-type, misc]
        def __call__(
            self,
            parser: argparse.ArgumentParser,
            namespace: argparse.Namespace,
            values: Any,
            option_string: str | None = None,
        ) -> None:
            namespace.typed_options = (*namespace.typed_options, self.dest)
            super().__call__(parser, namespace, values, option_string)

    return Typed


def given_options(args: argparse.Namespace, allowed: set[str]) -> list[str]:
    """The options typed on the command line, other than those whose dest is ``allowed``."""
    typed = dict.fromkeys(args.typed_options)  # in order, once each
    return [args.option_names[dest] for dest in typed if dest not in allowed]


def counted(n: int, noun: str) -> str:
    """``1 run``, ``3 runs``: a count as the commands print it."""
    return f"{n} {noun}{'' if n == 1 else 's'}"
