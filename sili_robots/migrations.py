"""Reading runs and checkpoints written by earlier versions.

Earlier runs saved every agent setting flat (``latent_dim``, ``beta_schedule``, ...) and the
agent's state with the latent cache and the add-ons' state at the top level. These functions
turn both into today's layout, so an old run resumes exactly where it stopped; the flat names
also stay valid for ``--set`` (``LEGACY_SETTINGS``). A setting an earlier version recorded but
did not apply is recorded as what the run trained with.
"""

from __future__ import annotations

from typing import Any

#: flat setting name of earlier runs -> dotted path today
LEGACY_SETTINGS: dict[str, str] = {
    "beta": "sili.beta",
    "beta_schedule": "sili.beta",
    "stability_scale": "sili.scale",
    "smirl_std_floor": "sili.smirl_std_floor",
    "latent_dim": "model.dim",
    "latent_lr": "model.lr",
    "latent_updates_per_interaction": "model.updates_per_interaction",
    "latent_batch": "model.batch",
    "latent_estimator": "model.estimator",
    "latent_usage_bonus": "model.usage_bonus",
    "latent_preact_penalty": "model.preact_penalty",
    "latent_merge_threshold": "model.merge_threshold",
    "lr": "sac.lr",
    "lr_schedule": "sac.lr",
    "gamma": "sac.gamma",
    "gamma_schedule": "sac.gamma",
    "tau": "sac.tau",
    "target_entropy": "sac.target_entropy",
    "target_entropy_schedule": "sac.target_entropy",
    "batch_interactions": "sac.batch_interactions",
    "batch_steps": "sac.batch_steps",
    "updates_per_step": "sac.updates_per_step",
    "random_interactions": "sac.random_interactions",
    "precision": "sac.precision",
    "latent_last_step": "addons.last_step",
    "latent_change_fraction": "addons.change_fraction",
    "stability_distance": "addons.stability_distance",
    "recent_fraction": "addons.recent.fraction",
    "recent_interactions": "addons.recent.interactions",
    "latent_filter": "addons.filter.eps",
    "latent_filter_start": "addons.filter.start",
    "latent_filter_noise": "addons.filter.noise",
}
#: methods whose latent is fixed to "none" today (earlier runs recorded an unused "discrete")
NO_LATENT = ("sac", "oracle", "smirl")


def setting_path(name: str) -> str:
    """Today's dotted path of a setting given by either name."""
    return LEGACY_SETTINGS.get(name, name)


def _nest(tree: dict[str, Any], path: str, value: Any) -> None:
    *sections, leaf = path.split(".")
    for part in sections:
        tree = tree.setdefault(part, {})
    tree[leaf] = value


def migrate_run(run: dict[str, Any]) -> dict[str, Any]:
    """A saved run (config.json's "run") in today's layout; unchanged when already current."""
    return _posteriors_as_run(run if "sac" in run["agent"] else _nested(run))


def _posteriors_as_run(run: dict[str, Any]) -> dict[str, Any]:
    """Earlier versions accepted the posteriors add-on with continuous latents and left it
    out; such a run says so now (it trained without it), and resumes as it trained."""
    addons = run.get("addons", {})
    on = (
        addons.get("change_fraction", 0) > 0
        or addons.get("stability_distance", "latents") != "latents"
    )
    if not on or run["agent"].get("latent") != "continuous":
        return run
    return {**run, "addons": {**addons, "change_fraction": 0.0, "stability_distance": "latents"}}


def _nested(run: dict[str, Any]) -> dict[str, Any]:
    """A run saved with flat settings, nested by section."""
    flat = dict(run["agent"])
    flat.pop("extra", None)
    # each setting saved before it existed: what the run trained with then
    flat.setdefault("latent_preact_penalty", 0.0)  # none
    flat.setdefault("matmul", "aten")  # PyTorch's default kernels
    flat.setdefault("precision", "float32")  # float32 products (not today's timed choice)
    flat.setdefault("latent_merge_threshold", 0.0)  # no categories merged
    if "latent_estimator" not in flat:  # the first latent model: straight-through Gumbel
        flat.update(latent_estimator="gumbel", latent_usage_bonus=0.0)
    nested: dict[str, Any] = {}
    for name, value in flat.items():
        unset_schedule = name.endswith("_schedule") and value is None
        if not unset_schedule and flat.get(f"{name}_schedule") is None:  # a schedule wins
            _nest(nested, setting_path(name), value)
    if nested.get("method") in NO_LATENT:
        nested["latent"] = "none"
    addons = nested.pop("addons", {})
    return {**run, "agent": nested, "addons": addons}


def migrate_agent_state(state: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's agent state in today's layout (latent cache and add-ons in their own
    entries); unchanged when already current."""
    if "latents" in state:
        return state
    state = dict(state)
    latents = {"Z": state.pop("Z"), "category_map": state.pop("category_map", None)}
    if latents["category_map"] is None:
        del latents["category_map"]
    addons = {"posteriors": {"P": state.pop("posteriors", None)}}
    if addons["posteriors"]["P"] is None:
        addons = {}
    if "filter" in state:
        addons["latent_filter"] = state.pop("filter")
    return {**state, "latents": latents, "addons": addons}
