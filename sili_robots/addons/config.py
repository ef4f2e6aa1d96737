"""Settings of the research add-ons, one section each; all off by default (the paper's agent)."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, Literal

from sili_robots.agent.addon import AgentAddon
from sili_robots.agent.config import AgentConfig, check, from_plain, setting, to_plain
from sili_robots.errors import ConfigError
from sili_robots.plugins import load_class

StabilityDistance = Literal["latents", "posterior", "hindsight"]


def check_learned_latents(name: str, agent: AgentConfig, discrete: bool = False) -> None:
    """Refuse add-on ``name`` on an agent without the learned latents it reads: from the
    settings before a run starts, and again when an add-on is wired into an agent directly."""
    if not agent.uses_latent_model:
        raise ConfigError(
            f"add-on {name} needs learned latents (discrete or continuous) of a method "
            f"with a latent model (sili, lili, stable), got method {agent.method!r} with "
            f"latent {agent.latent!r}; switch it off for this method"
        )
    if discrete and agent.latent != "discrete":
        raise ConfigError(f"add-on {name} needs discrete latents, got latent {agent.latent!r}")


@dataclass
class FilterConfig:
    """Within-interaction latent filter (addons/latent_filter.py)."""

    #: prior probability that the strategy in effect differs from the encoder's z^j (0 = off)
    eps: float = setting(0.0, 0.0, 0.999999)
    #: the filter runs from the first latent refresh at or after this many interactions
    start: int = setting(0, 0)
    #: noise scale per output: 0 = the decoder's residual, s > 0 = s x the targets' std
    noise: float = setting(0.0, 0.0)


@dataclass
class RecentConfig:
    """Part of each RL batch from the newest interactions (addons/recent.py)."""

    fraction: float = setting(0.0, 0.0, 1.0)  # 0 = uniform over the whole replay
    interactions: int = setting(100, 1)


@dataclass
class AddonsConfig:
    """Every research add-on's settings; ``active`` lists the ones switched on."""

    #: the encoder also reads the last transition unpooled (addons/last_step.py)
    last_step: bool = False
    #: discrete latents: fraction of each latent-model batch from pairs across which the
    #: strategy changed by the decoder's hindsight posterior (addons/posteriors.py)
    change_fraction: float = setting(0.0, 0.0, 1.0)
    #: discrete latents: what R_stable counts as a change (addons/posteriors.py)
    stability_distance: StabilityDistance = "latents"
    recent: RecentConfig = field(default_factory=RecentConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    #: your own add-ons: package.module:ClassName of AgentAddon subclasses, comma-separated,
    #: built with no arguments after the packaged ones (a run records them: resumed with them)
    plugins: str = ""

    def plugin_classes(self) -> list[type[AgentAddon]]:
        """The classes ``plugins`` names, imported (also from the current directory)."""
        if not self.plugins.strip():
            return []
        names = [p.strip() for p in self.plugins.split(",") if p.strip()]
        twice = sorted({p for p in names if names.count(p) > 1})
        if twice:  # else refused as two add-ons declaring one name or column
            raise ConfigError(f"addons.plugins lists {', '.join(twice)} twice; give each once")
        return [load_class(p, AgentAddon, "add-on") for p in names]

    def active(self) -> list[str]:
        on = []
        if self.last_step:
            on.append("last_step")
        if self.change_fraction > 0 or self.stability_distance != "latents":
            on.append("posteriors")
        if self.recent.fraction > 0:
            on.append("recent")
        if self.filter.eps > 0:
            on.append("latent_filter")
        return on

    def unread(self, given: Collection[str], agent: AgentConfig) -> dict[str, str]:
        """The settings among ``given`` (dotted paths) that no add-on of this configuration
        reads or that do nothing, and why (noted, not refused, as ``unused_settings``)."""
        out = {}
        for path in given:
            if path.startswith("addons.filter.") and path != "addons.filter.eps":
                if not self.filter.eps:
                    out[path] = "the latent filter is off (addons.filter.eps 0)"
            elif path == "addons.recent.interactions" and not self.recent.fraction:
                out[path] = "recent batches are off (addons.recent.fraction 0)"
            elif path == "addons.stability_distance" and agent.method == "lili":
                out[path] = "LILI has no stability reward (b = 0) to count changes for"
        draws = (  # a fraction of a batch that rounds to no draw
            ("addons.recent.fraction", self.recent.fraction, agent.sac.batch_interactions),
            ("addons.change_fraction", self.change_fraction, agent.model.batch),
        )
        for path, fraction, batch in draws:
            if path in given and fraction and not round(fraction * batch):
                out[path] = f"{fraction:g} of a batch of {batch} rounds to no draw"
        return out

    def to_dict(self) -> dict[str, Any]:
        return to_plain(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AddonsConfig:
        return from_plain(cls, data, "addons")

    def validate(self, agent: AgentConfig) -> AddonsConfig:
        check(self, "addons.")
        self.plugin_classes()  # each one loads, before a run starts
        active = self.active()
        for name in active:
            if name != "recent":
                check_learned_latents(name, agent)
        if "posteriors" in active and agent.latent != "discrete":
            raise ConfigError(
                f"add-on posteriors (addons.stability_distance {self.stability_distance!r}, "
                f"addons.change_fraction {self.change_fraction}) needs discrete latents, got "
                f"latent {agent.latent!r}; allowed with it: stability_distance 'latents' and "
                "change_fraction 0"
            )
        return self
