"""Errors users see: one type for bad input, caught by the CLI and shown without a traceback."""

from __future__ import annotations


class ConfigError(ValueError):
    """A value given by the user is not allowed; the message names the value and the choices."""


def check_choice(name: str, value: object, allowed: list[str] | tuple[str, ...]) -> None:
    """Raise ``ConfigError`` unless ``value`` is one of ``allowed``."""
    if value not in allowed:
        raise ConfigError(f"unknown {name} {value!r}; allowed: {', '.join(map(str, allowed))}")
