"""Argument types shared by sub-commands: each rejects bad values with the allowed ones."""

from __future__ import annotations

import argparse
import math

from sili_robots.agent.config import (
    BetaSchedule,
    DiscountSchedule,
    EntropySchedule,
    LearningRateSchedule,
    Schedule,
    ScheduleT,
)
from sili_robots.errors import ConfigError
from sili_robots.tasks import task_spec


def _int_at_least(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an integer (need >= {minimum})"
        ) from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"{value} is not allowed: need an integer >= {minimum}")
    return value


def positive_int(text: str) -> int:
    return _int_at_least(text, 1)


def non_negative_int(text: str) -> int:
    return _int_at_least(text, 0)


def float_in(text: str, low: float = -math.inf, high: float = math.inf) -> float:
    """A number in [low, high]; with no bounds, any finite number."""
    bounded = math.isfinite(low) or math.isfinite(high)
    span = f"[{low:g}, {high:g}]"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number" + (f" in {span}" if bounded else "")
        ) from None
    if not bounded and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"{value} is outside the allowed range {span}")
    return value


def unit_float(text: str) -> float:
    return float_in(text, 0.0, 1.0)


def parse_schedule(text: str, option: str, kind: type[ScheduleT]) -> ScheduleT:
    """``"250:0,300:0.5"`` -> kind([(250, 0.0), (300, 0.5)]), unparsable points named."""
    points = []
    for item in text.split(","):
        interaction, sep, value = item.strip().partition(":")
        try:
            if not sep:
                raise argparse.ArgumentTypeError(f"{item.strip()!r} is not INTERACTION:VALUE")
            points.append((non_negative_int(interaction), float_in(value, kind.low, kind.high)))
        except argparse.ArgumentTypeError as err:
            raise ConfigError(f"{option} {text!r}: {err}") from None
    return kind(points)  # AgentConfig.validate checks the points' order


#: the schedule options of ``sili train`` and ``sili sweep``:
#: option -> (agent setting, kind, metavar, what it sets, example)
SCHEDULE_ARGS: dict[str, tuple[str, type[Schedule], str, str, str]] = {
    "--beta-schedule": (
        "beta_schedule",
        BetaSchedule,
        "I:B,I:B,...",
        "b (sili, smirl)",
        "250:0,300:0.5,1500:0.5,1600:0",
    ),
    "--target-entropy-schedule": (
        "target_entropy_schedule",
        EntropySchedule,
        "I:E,I:E,...",
        "SAC's target entropy (default -|A| throughout)",
        "1500:-2,1600:-4",
    ),
    "--discount-schedule": (
        "gamma_schedule",
        DiscountSchedule,
        "I:G,I:G,...",
        "SAC's discount gamma (default 0.99 throughout)",
        "1600:0.99,1700:0.998",
    ),
    "--lr-schedule": (
        "lr_schedule",
        LearningRateSchedule,
        "I:LR,I:LR,...",
        "SAC's learning rate (default 3e-4 throughout)",
        "2200:3e-4,2400:3e-5",
    ),
}


def add_schedule_args(p: argparse.ArgumentParser, scope: str) -> None:
    for option, (_, _, metavar, what, example) in SCHEDULE_ARGS.items():
        p.add_argument(
            option,
            metavar=metavar,
            help=f"{what}{scope}, piecewise linear through (interaction, value) points, held "
            f"before the first and after the last; e.g. {example}",
        )


def schedule_args(args: argparse.Namespace) -> dict[str, Schedule]:
    """The schedule options given, parsed, keyed by their agent setting."""
    out: dict[str, Schedule] = {}
    for option, (setting, kind, *_) in SCHEDULE_ARGS.items():
        text = getattr(args, option[2:].replace("-", "_"))
        if text:
            out[setting] = parse_schedule(text, option, kind)
    return out


def task_name(text: str) -> str:
    try:
        return task_spec(text).name
    except ConfigError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def parse_env_kwargs(items: list[str], flag: str) -> dict:
    """``KEY=VALUE`` pairs with JSON values (bare words are taken as strings)."""
    import json

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{flag} takes KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def add_override_args(p: argparse.ArgumentParser, scope: str) -> None:
    """``--set KEY=VALUE`` (agent settings) and ``--env-kwarg KEY=VALUE`` (task arguments)."""
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="agent_set",
        help=f"override an agent setting{scope} (JSON value), repeatable, "
        "e.g. --set updates_per_step=0.5",
    )
    p.add_argument(
        "--env-kwarg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"extra task constructor argument{scope} (JSON value), repeatable",
    )
