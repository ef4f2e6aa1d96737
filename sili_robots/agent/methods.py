"""Every method of the paper is a preset of one agent; each preset fixes what defines it.

| method  | latent model | policy input        | reward                                  |
|---------|--------------|---------------------|-----------------------------------------|
| sili    | yes          | s, z^j, z^{j-1}     | (1-b) R_task + b R_stable               |
| lili    | yes          | s, z^j              | R_task (b = 0)                          |
| stable  | yes          | s, z^j, z^{j-1}     | R_stable (b = 1)                        |
| sac     | no           | s                   | R_task                                  |
| oracle  | no           | s + true z          | R_task                                  |
| smirl   | no           | s                   | (1-b) R_task + b log p(s) (SMiRL)       |

Two profiles give the starting settings: ``package`` (the defaults of ``AgentConfig``) and
``paper`` (the settings of the paper's appendix: discrete latents by straight-through
Gumbel-Softmax at temperature 1, z^j sampled as its Eq. for z^j says, b = 0.5 constant (the
package's SILI starts b at 0 and raises it to 0.5 over interactions 250-300), 2 x 256 networks,
latent dimension 10, R_stable = -d(z^j, z^{j-1}) on every step, no grouping of categories,
continuous latents the encoder's raw output, which the paper does not bound).
Both keep the model's structure, which the paper leaves open or states loosely (the encoder's
pooling, a discrete decoder with one head per category; README, "Two profiles").
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from sili_robots.agent.config import AgentConfig, get_path, set_path
from sili_robots.agent.schedule import Schedule
from sili_robots.errors import ConfigError

#: the methods whose b is a setting (the others fix it)
BETA_METHODS = ("sili", "smirl")
PROFILES = ("package", "paper")


@dataclass(frozen=True)
class Preset:
    """What a method fixes: setting path -> (value, why); and its own defaults (overridable)."""

    fixed: dict[str, tuple[Any, str]]
    defaults: dict[str, Any] = field(default_factory=dict)


#: SILI's default b: 0 for the first 250 interactions, then up to 0.5 by 300. The latent model
#: first learns the strategies from a policy that pursues the task; with b = 0.5 from the start
#: the policy learns to hold whatever its untrained latents call one strategy. Measured on
#: Circle (3 Goals) at 1,000 interactions: 3 of 3 seeds hold the opponent (benchmarks/RESULTS.md).
SILI_BETA = Schedule(((250, 0.0), (300, 0.5)))

PRESETS: dict[str, Preset] = {
    "sili": Preset({}, {"sili.beta": SILI_BETA}),
    "lili": Preset({"sili.beta": (0.0, "LILI is SILI without the stability reward (b = 0)")}),
    "stable": Preset({"sili.beta": (1.0, "Stable optimises the stability reward only (b = 1)")}),
    "sac": Preset(
        {
            "sili.beta": (0.0, "SAC optimises the task reward only"),
            "latent": ("none", "SAC conditions on the state only, no latent"),
        }
    ),
    "oracle": Preset(
        {
            "sili.beta": (0.0, "Oracle optimises the task reward only"),
            "latent": ("none", "Oracle observes the true strategy instead of a latent"),
        }
    ),
    "smirl": Preset({"latent": ("none", "SMiRL's stability is a state density, no latent")}),
}

#: the methods whose latent kind is a choice (the others fix it to "none")
LATENT_METHODS = tuple(m for m, preset in PRESETS.items() if "latent" not in preset.fixed)

#: the paper's appendix (the latent kind stays the task's: discrete, continuous or partial)
PAPER_PROFILE: dict[str, Any] = {
    "hidden": 256,
    "model.dim": 10,
    "model.estimator": "gumbel",
    "model.sample": True,
    "model.usage_bonus": 0.0,
    "model.merge_threshold": 0.0,
    "model.preact_penalty": 0.0,  # continuous latents: no penalty on the encoder's output
    "sili.beta": 0.5,
    "sili.credit": "per_step",
    "sili.scale": None,
    "sac.precision": "float32",  # as the authors' code; a machine may choose bfloat16 products
}


def method_config(
    method: str,
    latent: str | None = None,
    profile: str = "package",
    overrides: dict[str, Any] | None = None,
    task_latent: str | None = None,
) -> AgentConfig:
    """The preset for ``method`` in ``profile``, with ``overrides`` (dotted paths) applied.

    ``latent`` is the user's choice of latent kind; without it the task's (``task_latent``, else
    discrete). Overriding what the method fixes raises ConfigError naming the method, the
    setting and why."""
    if method not in PRESETS:
        raise ConfigError(f"unknown method {method!r}; allowed: {', '.join(PRESETS)}")
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}; allowed: {', '.join(PROFILES)}")
    cfg = AgentConfig(method=method, profile=profile)
    for path, value in PRESETS[method].defaults.items():
        set_path(cfg, path, value)
    if profile == "paper":
        for path, value in PAPER_PROFILE.items():
            set_path(cfg, path, value)
    given = dict(overrides or {})
    for name in ("method", "profile"):
        if name in given:
            raise ConfigError(
                f"{name} is not a setting to override ({name} {given[name]!r}); choose the "
                f"{name} itself (allowed: {', '.join(PRESETS if name == 'method' else PROFILES)})"
            )
    if latent is not None:
        given["latent"] = latent
    if method == "lili" and given.get("latent") == "partial":
        raise ConfigError(
            "method 'lili' learns a latent strategy, and 'partial' learns none (its flag only "
            "feeds R_stable, which LILI's b = 0 never pays): choose discrete, continuous or true"
        )
    fixed = PRESETS[method].fixed
    if "latent" not in fixed and "latent" not in given:
        kind = task_latent or "discrete"
        # LILI always learns a latent: on a task whose default is partial, the discrete one
        given["latent"] = "discrete" if method == "lili" and kind == "partial" else kind
    if "latent" not in fixed and given.get("latent") == "none":
        raise ConfigError(
            f"method {method!r} learns a latent strategy (its policy and, with b > 0, its reward "
            f"use z); got latent 'none': choose discrete, continuous, partial or true, or "
            "method sac for no latent"
        )
    for path, value in given.items():
        if path in fixed and value != fixed[path][0]:
            want, why = fixed[path]
            raise ConfigError(
                f"method {method!r} fixes {path} = {want!r} ({why}); got {value!r}: "
                f"drop the setting or choose another method"
            )
        set_path(cfg, path, value)
    for path, (value, _) in fixed.items():
        set_path(cfg, path, value)
    if profile == "paper" and cfg.latent == "continuous" and "model.squash" not in given:
        cfg.model.squash = False  # the raw output (recorded for continuous latents alone)
    return cfg.validate()


def paper_departures(cfg: AgentConfig, given: Iterable[str]) -> dict[str, Any]:
    """The settings among ``given`` (dotted paths) at which ``cfg``, an agent of the paper
    profile, departs from the profile's own configuration, with the profile's values: the run
    is recorded as that profile all the same, so a reader is told."""
    if cfg.profile != "paper":
        return {}
    latent = cfg.latent if cfg.method in LATENT_METHODS else None
    own = method_config(cfg.method, latent, "paper")
    unread = unused_settings(cfg, given)  # a setting it never reads departs from nothing
    out = {}
    for path in given:
        try:
            value = get_path(own, path)
        except AttributeError:  # not the agent's (an add-on's setting)
            continue
        if path not in unread and _held(value) != _held(get_path(cfg, path)):
            out[path] = value
    return out


def _held(value: Any) -> Any:
    """A schedule that holds one value is that value (``sili.beta=0:0.5`` is b = 0.5)."""
    if isinstance(value, Schedule) and len({v for _, v in value.points}) == 1:
        return value.points[0][1]
    return value


def unused_settings(cfg: AgentConfig, given: Iterable[str]) -> dict[str, str]:
    """The settings among ``given`` (dotted paths) that the agent ``cfg`` never reads, and why:
    recorded in its config.json all the same, so a reader is told (a sweep gives its settings
    to every method, so they are not refused)."""
    out = {}
    for path in given:
        if path.startswith("model.") and not cfg.uses_latent_model:
            out[path] = f"it learns no latent model (latent {cfg.latent!r})"
        elif path in DISCRETE_ONLY and cfg.latent != "discrete":
            out[path] = f"only discrete latents read it (latent {cfg.latent!r})"
        elif path in CONTINUOUS_ONLY and cfg.latent != "continuous":
            out[path] = f"only continuous latents read it (latent {cfg.latent!r})"
        elif path == "model.usage_bonus" and cfg.model.estimator == "gumbel":
            out[path] = "the gumbel estimator has no usage bonus"
        elif path == "sili.smirl_std_floor" and cfg.method != "smirl":
            out[path] = "only SMiRL's state density reads it"
        elif path in ("sili.scale", "sili.credit") and (why := no_stability_term(cfg)):
            out[path] = why
        elif path == "sili.scale" and cfg.sili.credit == "per_step":
            out[path] = "per-step credit pays -d(z^j, z^{j-1}) on every step, unscaled"
    return out


#: latent-model settings only one kind of latent reads (agent/latent.py, agent/latent_cache.py)
DISCRETE_ONLY = ("model.estimator", "model.sample", "model.usage_bonus", "model.merge_threshold")
CONTINUOUS_ONLY = ("model.squash", "model.preact_penalty")


def no_stability_term(cfg: AgentConfig) -> str:
    """Why ``cfg`` has no stability term to scale or count changes for ('' when it has one)."""
    if cfg.method == "smirl":
        return "SMiRL's term is its state density's log-likelihood"
    if cfg.latent == "partial":
        return "the partial latent's term is read off each state"
    beta = cfg.sili.beta
    values = [v for _, v in beta.points] if isinstance(beta, Schedule) else [beta]
    if not any(values):
        return "b is 0 throughout: no stability term"
    return ""
