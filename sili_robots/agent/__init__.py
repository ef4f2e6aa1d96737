"""The learning agent: one SAC + latent-model agent that every method is a configuration of."""

from sili_robots.agent.addon import AgentAddon
from sili_robots.agent.agent import InteractionStats, SILIAgent
from sili_robots.agent.config import (
    LATENT_CHOICES,
    LATENT_KINDS,
    METHODS,
    AgentConfig,
    LatentModelConfig,
    SACConfig,
    StabilityConfig,
)
from sili_robots.agent.methods import BETA_METHODS, PROFILES, method_config
from sili_robots.agent.schedule import Schedule

__all__ = [
    "BETA_METHODS",
    "LATENT_CHOICES",
    "LATENT_KINDS",
    "METHODS",
    "PROFILES",
    "AgentAddon",
    "AgentConfig",
    "InteractionStats",
    "LatentModelConfig",
    "SACConfig",
    "SILIAgent",
    "Schedule",
    "StabilityConfig",
    "method_config",
]
