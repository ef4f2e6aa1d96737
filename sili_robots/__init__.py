"""sili-robots: Stable Influencing of Latent Intent and its baselines on real simulators.

``from sili_robots import SILI`` is the Python API (sili_robots/api.py); importing the package
registers every task with gymnasium.
"""

from typing import Any

from sili_robots import tasks  # noqa: F401  (registers every task with gymnasium)

__version__ = "0.2.0"
__all__ = ["SILI"]


def __getattr__(name: str) -> Any:
    if name == "SILI":  # imported on first use: torch is not needed to use the tasks
        from sili_robots.api import SILI

        return SILI
    raise AttributeError(f"module 'sili_robots' has no attribute {name!r}")
