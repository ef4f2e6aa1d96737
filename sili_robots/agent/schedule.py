"""A float setting as a piecewise-linear function of the interaction index.

The agent's settings typed ``Scheduled`` (b, SAC's learning rate, discount, target entropy, ...;
``paths(AgentConfig, schedulable=True)`` lists them) may be given as a ``Schedule`` instead of a
number. ``value_at`` reads either; the ``schedules``
add-on (sili_robots/addons/schedules.py) applies the scheduled values before each update.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

from sili_robots.errors import ConfigError, is_number


@dataclass(frozen=True)
class Schedule:
    """(interaction, value) knots in increasing interaction order; the value is held at the
    first knot's before it and at the last knot's after it."""

    points: tuple[tuple[int, float], ...]

    def __post_init__(self) -> None:
        infinite = [i for i, _ in self.points if is_number(i) and not math.isfinite(i)]
        if infinite:  # int() would raise OverflowError (inf) or ValueError (nan) unnamed
            raise ConfigError(f"a schedule's interactions are whole numbers, got {infinite[0]}")
        points = tuple((int(i), float(v)) for i, v in self.points)
        fractional = [i for (i, _), (n, _) in zip(self.points, points, strict=True) if i != n]
        if fractional:
            raise ConfigError(f"a schedule's interactions are whole numbers, got {fractional[0]}")
        object.__setattr__(self, "points", points)

    @classmethod
    def ramp(cls, start: float, end: float, length: int, delay: int = 0) -> Schedule:
        """``start`` for ``delay`` interactions, then linear to ``end`` over ``length``."""
        return cls(((delay, start), (delay + length, end)))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Schedule:
        """Read a saved schedule; a single ramp (start, end, length, delay) too."""
        if "points" in data:
            return cls(tuple(data["points"]))
        return cls.ramp(data["start"], data["end"], data["length"], data.get("delay", 0))

    @staticmethod
    def items(text: str) -> list[tuple[str, str, str]]:
        """The points of ``"250:0,300:0.5"`` as text, each (item, interaction, value); ConfigError
        naming an item without its colon. ``parse`` and the CLI's reader read them."""
        found = []
        for item in (part.strip() for part in text.split(",")):
            interaction, sep, value = item.partition(":")
            if not sep:
                raise ConfigError(f"{item!r} is not INTERACTION:VALUE")
            found.append((item, interaction, value))
        return found

    @classmethod
    def parse(cls, text: str) -> Schedule:
        """``"250:0,300:0.5"``, the form ``__str__`` writes and the command line's, for a
        setting given as text (the CLI's own reader names the option and its range)."""
        example = " (a schedule: 250:0,300:0.5)"
        try:
            items = cls.items(text)
        except ConfigError as err:
            raise ConfigError(f"{err}{example}") from None
        points = []
        for item, interaction, value in items:
            try:
                points.append((int(interaction), float(value)))
            except ValueError:
                raise ConfigError(f"{item!r} is not INTERACTION:VALUE{example}") from None
        return cls(tuple(points))

    def to_dict(self) -> dict[str, Any]:
        return {"points": [list(p) for p in self.points]}

    def __str__(self) -> str:
        """As ``--set`` takes it: ``250:0,300:0.5``."""
        return ",".join(f"{i}:{v:g}" for i, v in self.points)

    def value(self, interaction: int) -> float:
        first, last = self.points[0], self.points[-1]
        if interaction <= first[0]:
            return first[1]
        for (i0, v0), (i1, v1) in pairwise(self.points):
            if interaction < i1:
                return v0 + (interaction - i0) / (i1 - i0) * (v1 - v0)
        return last[1]

    def check(self, name: str, low: float = -math.inf, high: float = math.inf) -> None:
        """Raise ConfigError naming the setting and the first bad knot."""
        if not self.points:
            raise ConfigError(f"schedule of {name} needs at least one (interaction, value) point")
        previous = -1
        for i, v in self.points:
            if i < 0:
                raise ConfigError(f"schedule of {name}: interaction must be >= 0, got {i}")
            if i <= previous:
                raise ConfigError(
                    f"schedule of {name}: interactions must increase, got {i} after {previous}"
                )
            if not (math.isfinite(v) and low <= v <= high):
                raise ConfigError(
                    f"schedule of {name}: value must be {span(low, high)}, got {v} at "
                    f"interaction {i}"
                )
            previous = i


Scheduled = float | Schedule


def value_at(setting: Scheduled | None, interaction: int) -> float | None:
    """A setting's value at ``interaction``, whether a number or a schedule."""
    if isinstance(setting, Schedule):
        return setting.value(interaction)
    return setting


def span(low: float, high: float) -> str:
    if math.isfinite(low) or math.isfinite(high):
        return f"in [{low:g}, {high:g}]"
    return "a finite number"
