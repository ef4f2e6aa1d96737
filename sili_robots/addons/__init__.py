"""Research add-ons: optional pieces the agent calls through ``sili_robots.agent.addon``.

``build_addons`` wires in those the configuration switches on, in a fixed order (posteriors
before the filter: a refresh recomputes them in that order). With none switched on the agent is
the paper's algorithm and runs none of their code.

- ``schedules`` (a setting given as a schedule): the value per interaction.
- ``last_step`` (``addons.last_step``): the encoder also reads the last transition.
- ``posteriors`` (``addons.stability_distance``, ``addons.change_fraction``): R_stable from
  hindsight posteriors; latent batches from the pairs across which the strategy changed.
- ``recent`` (``addons.recent.fraction``): part of each RL batch from the newest interactions.
- ``latent_filter`` (``addons.filter.eps``): the policy's z^j corrected within the interaction.
- your own (``addons.plugins``, ``package.module:ClassName``): after these, in the order given.
"""

from __future__ import annotations

import inspect

from sili_robots.addons.config import AddonsConfig
from sili_robots.addons.last_step import LastStep
from sili_robots.addons.latent_filter import LatentFilter
from sili_robots.addons.posteriors import HindsightPosteriors
from sili_robots.addons.recent import RecentBatches
from sili_robots.addons.schedules import Schedules
from sili_robots.agent.addon import AgentAddon
from sili_robots.agent.config import AgentConfig, scheduled_paths
from sili_robots.errors import ConfigError
from sili_robots.plugins import class_path


def build_addons(addons: AddonsConfig, agent: AgentConfig) -> list[AgentAddon]:
    """The add-ons ``addons`` switches on (and ``schedules`` when a setting is scheduled)."""
    out: list[AgentAddon] = []
    if scheduled_paths(agent):
        out.append(Schedules())
    active = addons.validate(agent).active()
    if "last_step" in active:
        out.append(LastStep())
    if "posteriors" in active and (addons.change_fraction or agent.method != "lili"):
        out.append(HindsightPosteriors(addons.stability_distance, addons.change_fraction))
    if "recent" in active:
        out.append(RecentBatches(addons.recent.fraction, addons.recent.interactions))
    if "latent_filter" in active:
        f = addons.filter
        out.append(LatentFilter(f.eps, f.start, f.noise))
    for cls in addons.plugin_classes():
        try:
            inspect.signature(cls).bind()
        except TypeError as err:  # e.g. a constructor that takes settings
            raise ConfigError(
                f"add-on {class_path(cls)} is built with no arguments ({err}): "
                "give its settings as class attributes, a subclass per variant"
            ) from None
        out.append(cls())
    named: dict[str, AgentAddon] = {}  # one checkpoint entry per name: a second would replace
    for addon in out:
        first = named.setdefault(addon.name, addon)
        if first is not addon:
            raise ConfigError(
                f"add-ons {class_path(type(first))} and {class_path(type(addon))} are both named "
                f"{addon.name!r}; give each its own `name` (their saved states are kept by name)"
            )
    return out


__all__ = [
    "AddonsConfig",
    "HindsightPosteriors",
    "LastStep",
    "LatentFilter",
    "RecentBatches",
    "Schedules",
    "build_addons",
]
