"""sili-robots: Stable Influencing of Latent Intent and its baselines on real simulators."""

from sili_robots import tasks  # noqa: F401  (registers every task with gymnasium)

__version__ = "0.1.0"
