"""Where the package keeps what it works out once per machine (the kernel choice, the generated
SUMO scenario), so a later process reuses it."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from sili_robots.errors import ConfigError


def cache_dir() -> Path:
    """``$SILI_ROBOTS_CACHE``, else ``$XDG_CACHE_HOME/sili-robots`` (``~/.cache/sili-robots``);
    without a home (no ``$HOME`` and no user entry, as in some containers) the temporary
    directory's ``sili-robots-cache``, not a ``~`` folder in the current directory."""
    if os.environ.get("SILI_ROBOTS_CACHE"):
        return _expanded("SILI_ROBOTS_CACHE")
    if os.environ.get("XDG_CACHE_HOME"):
        return _expanded("XDG_CACHE_HOME") / "sili-robots"
    home = os.path.expanduser("~")
    if home == "~":
        return Path(tempfile.gettempdir()) / "sili-robots-cache"
    return Path(home) / ".cache" / "sili-robots"


def _expanded(variable: str) -> Path:
    value = os.environ[variable]
    try:
        return Path(value).expanduser()
    except RuntimeError:  # ~name of no user here
        raise ConfigError(
            f"${variable} is {value!r}, whose '~' names no user with a home on this machine; "
            "give a path"
        ) from None
