"""Building agents for tests from flat or dotted settings, as ``sili train --set`` takes them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

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


def timed_kernels(
    monkeypatch: pytest.MonkeyPatch,
    cache: Path,
    matmul: dict[str, float],
    precision: dict[str, float],
) -> None:
    """A kernel cache at ``cache`` (``$SILI_ROBOTS_CACHE``) where this machine chose aten and
    float32 from these timings (seconds per option), as if it had timed them."""
    import json

    from sili_robots.agent.matmul import machine_key

    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(cache))
    cache.mkdir(parents=True)
    entry = {"matmul": "aten", "seconds": matmul}
    entry |= {"precision": "float32", "precision_seconds": precision}
    (cache / "kernels.json").write_text(json.dumps({machine_key(): entry}))
