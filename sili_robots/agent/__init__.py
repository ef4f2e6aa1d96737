"""The learning agent: one SAC + latent-model agent that every method is a configuration of."""

from sili_robots.agent.agent import InteractionStats, SILIAgent
from sili_robots.agent.config import (
    BETA_METHODS,
    LATENT_KINDS,
    METHODS,
    AgentConfig,
    BetaSchedule,
    DiscountSchedule,
    EntropySchedule,
    LearningRateSchedule,
    method_config,
)

__all__ = [
    "BETA_METHODS",
    "LATENT_KINDS",
    "METHODS",
    "AgentConfig",
    "BetaSchedule",
    "DiscountSchedule",
    "EntropySchedule",
    "InteractionStats",
    "LearningRateSchedule",
    "SILIAgent",
    "method_config",
]
