"""With every add-on off the agent runs none of their code; with one on, its hooks run."""

from __future__ import annotations

import cProfile
import pstats

from fast_settings import FAST_AGENT

from sili_robots.build import make_run_config
from sili_robots.training import train


def _calls(tmp_path, interactions: int = 6, **settings) -> dict[str, int]:
    """Calls per function of the add-ons package during a short Circle run."""
    cfg = make_run_config("circle-3", "sili", 0, interactions, settings={**FAST_AGENT, **settings})
    profile = cProfile.Profile()
    profile.runcall(train, cfg, tmp_path / "run", progress=False)
    stats = pstats.Stats(profile).stats
    return {
        f"{name}:{line}": calls
        for (path, line, name), (calls, *_) in stats.items()
        if "/sili_robots/addons/" in path
    }


#: wiring and saving the settings, once per run: nothing switched on
WIRING = ("build_addons", "active", "validate", "plugin_classes", "to_dict")


def test_no_addon_code_runs_with_every_addon_off(tmp_path):
    calls = _calls(tmp_path / "off", 10, **{"sili.beta": 0.5})  # constant b: no schedule either
    assert {key.split(":")[0] for key in calls} <= set(WIRING)
    # a few times per run (the config read, checked and written): not per interaction (10)
    assert max(calls.values()) <= 4


def test_silis_default_b_schedule_is_the_only_addon_it_runs(tmp_path):
    calls = _calls(tmp_path / "default")
    ran = {key.split(":")[0] for key in calls} - set(WIRING)
    assert ran == {"attach", "before_update", "<lambda>"}  # schedules.py: b applied per update


def test_a_switched_on_addon_runs_its_hooks_per_step(tmp_path):
    calls = _calls(tmp_path / "on", latent_filter=0.1)
    steps = [n for key, n in calls.items() if key.startswith("observe_step:")]
    assert steps == [6 * 50]  # each step of the 6 interactions of H = 50
