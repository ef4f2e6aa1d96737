"""Building agents for tests from flat or dotted settings, as ``sili train --set`` takes them."""

from __future__ import annotations

from typing import Any

from sili_robots.addons import build_addons
from sili_robots.agent import SILIAgent
from sili_robots.build import make_run_config
from sili_robots.migrations import LEGACY_SETTINGS
from sili_robots.runs import RunConfig


def run_config(method: str = "sili", latent: str | None = None, **settings: Any) -> RunConfig:
    """A run config of ``method`` with ``settings`` (earlier flat names or dotted paths with
    ``__`` for the dots, e.g. ``sac__lr=1e-3``)."""
    settings = {k.replace("__", "."): v for k, v in settings.items()}
    return make_run_config("circle-3", method, latent=latent, settings=settings)


def make_agent(
    method: str = "sili",
    latent: str | None = None,
    obs_dim: int = 3,
    act_dim: int = 2,
    horizon: int = 10,
    strategy_dim: int = 2,
    seed: int = 0,
    **settings: Any,
) -> SILIAgent:
    """An agent with the add-ons its settings switch on, as a run would build it."""
    cfg = run_config(method, latent, **settings)
    addons = build_addons(cfg.addons, cfg.agent)
    return SILIAgent(cfg.agent, obs_dim, act_dim, horizon, strategy_dim, seed=seed, addons=addons)


def flat_layout(run: dict[str, Any]) -> dict[str, Any]:
    """A run config (config.json's "run") as runs were saved before the settings were nested:
    every agent and add-on setting under its earlier flat name, a schedule under its
    ``*_schedule`` name, no "addons" section."""
    names = {path: name for name, path in LEGACY_SETTINGS.items() if not name.endswith("_schedule")}
    schedules = {path: name for name, path in LEGACY_SETTINGS.items() if name.endswith("_schedule")}
    flat = {key: run["agent"][key] for key in ("method", "latent", "hidden", "matmul")}

    def leaves(tree: dict[str, Any], prefix: str) -> None:
        for key, value in tree.items():
            path = f"{prefix}{key}"
            if isinstance(value, dict) and "points" in value and path in schedules:
                flat[schedules[path]] = value
                flat[names[path]] = value["points"][-1][1]
            elif isinstance(value, dict):
                leaves(value, f"{path}.")
            elif path in names:
                flat[names[path]] = value

    leaves({k: run["agent"][k] for k in ("sac", "model", "sili")}, "")
    leaves(run["addons"], "addons.")
    return {**{k: v for k, v in run.items() if k != "addons"}, "agent": flat}
