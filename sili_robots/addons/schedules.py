"""Settings given as schedules over interactions (any ``Scheduled`` float of ``AgentConfig``).

Wired in whenever a setting is a ``Schedule``: before the updates after each interaction it
applies every scheduled value to the learner that uses it (b, SAC's rate, discount, target
entropy and tau, the latent model's rate, usage bonus and penalty). Settings the agent reads at
use time (``sac.updates_per_step``) need nothing here. A method without a latent model ignores
the model's schedules, as it ignores the model's constant settings.
"""

from __future__ import annotations

from collections.abc import Callable

from sili_robots.agent.addon import AgentAddon
from sili_robots.agent.agent import SILIAgent
from sili_robots.agent.config import get_path, scheduled_paths
from sili_robots.agent.schedule import value_at


def _set_model_lr(agent: SILIAgent, value: float) -> None:
    for group in agent.model_opt.param_groups:
        group["lr"] = value


#: where each schedulable setting takes effect
APPLY: dict[str, Callable[[SILIAgent, float], None]] = {
    "sili.beta": lambda agent, v: setattr(agent, "beta", v),
    "sac.lr": lambda agent, v: agent.sac.set_lr(v),
    "sac.gamma": lambda agent, v: setattr(agent.sac, "gamma", v),
    "sac.tau": lambda agent, v: setattr(agent.sac, "tau", v),
    "sac.target_entropy": lambda agent, v: setattr(agent.sac, "target_entropy", v),
    "sac.updates_per_step": lambda agent, v: None,  # read where it is used
    "model.lr": _set_model_lr,
    "model.usage_bonus": lambda agent, v: setattr(agent.model, "usage_bonus", v),
    "model.preact_penalty": lambda agent, v: setattr(agent.model, "preact_penalty", v),
}


class Schedules(AgentAddon):
    name = "schedules"

    def attach(self, agent: SILIAgent) -> None:
        super().attach(agent)
        paths = scheduled_paths(agent.cfg)
        if agent.model is None:  # no latent model to apply them to
            paths = [p for p in paths if not p.startswith("model.")]
        self.paths = paths

    def before_update(self, interaction: int) -> None:
        for path in self.paths:
            APPLY[path](self.agent, value_at(get_path(self.agent.cfg, path), interaction))
