"""Where the package keeps what it works out once per machine (the kernel choice, the generated
SUMO scenario), so a later process reuses it."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    """``$SILI_ROBOTS_CACHE``, else ``$XDG_CACHE_HOME/sili-robots`` (``~/.cache/sili-robots``)."""
    if os.environ.get("SILI_ROBOTS_CACHE"):
        return Path(os.environ["SILI_ROBOTS_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sili-robots"
