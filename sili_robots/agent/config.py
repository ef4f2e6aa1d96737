"""Agent configuration: typed sections whose types carry the allowed values.

``AgentConfig`` = the method, the latent kind, the networks' width and matrix-product library,
and three sections: ``sac`` (the RL learner), ``model`` (the latent strategy model) and ``sili``
(the stability reward). A float setting may be a ``Schedule`` over interactions. Every method of
the paper is a preset of it (``sili_robots/agent/methods.py``). Settings are addressed by dotted
paths (``sac.lr``, ``model.dim``, ``sili.beta``); ``set_path`` converts and checks a value by the
field's declared type, so a bad value is reported by name with what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field, fields
from typing import Any, Literal

from sili_robots.agent.matmul import default_matmul, default_precision, onednn_available
from sili_robots.agent.schedule import Schedule, Scheduled, span
from sili_robots.errors import ConfigError, is_number

Method = Literal["sili", "lili", "stable", "sac", "oracle", "smirl"]
#: ``none``: no latent (SAC, Oracle, SMiRL); ``true``: the diagnostic that feeds the true strategy
LatentKind = Literal["discrete", "continuous", "partial", "true", "none"]
Estimator = Literal["expected", "marginal", "gumbel"]
Precision = Literal["float32", "bfloat16"]
Matmul = Literal["onednn", "aten"]
#: where R_stable is paid: ``boundary`` = -scale d(z^j, z^{j+1}) on the last step of interaction
#: j (the change it caused); ``per_step`` = the paper's -d(z^j, z^{j-1}) on every step of j
Credit = Literal["boundary", "per_step"]

METHODS: tuple[str, ...] = typing.get_args(Method)
LATENT_KINDS: tuple[str, ...] = typing.get_args(LatentKind)
#: the kinds ``--latent`` offers ("none" is what the methods without a latent model fix)
LATENT_CHOICES: tuple[str, ...] = tuple(k for k in LATENT_KINDS if k != "none")


def setting(default: Any, low: float = -math.inf, high: float = math.inf, **kw: Any) -> Any:
    """A dataclass field with an allowed range (checked by ``check``)."""
    return field(default=default, metadata={"low": low, "high": high}, **kw)


@dataclass
class SACConfig:
    """Soft actor-critic: 2 x ``hidden`` actor and twin critics, Polyak targets, learned alpha."""

    lr: Scheduled = setting(3e-4, 0.0, 1.0)
    gamma: Scheduled = setting(0.99, 1e-9, 1.0)
    tau: Scheduled = setting(5e-3, 0.0, 1.0)
    #: the entropy the temperature holds the policy at; None = -|A|, SAC's usual choice
    target_entropy: Scheduled | None = None
    batch_interactions: int = setting(16, 1)  # an RL batch = this many interactions ...
    batch_steps: int = setting(16, 1)  # ... times this many timesteps from each
    #: at most 10,000 (half a million updates per 50-step interaction: hours each, and numpy
    #: refuses the index arrays of far more with an error that names no setting)
    updates_per_step: Scheduled = setting(1.0, 0.0, 1e4)
    random_interactions: int = setting(20, 0)  # interactions of uniform random actions first
    #: ``bfloat16``: forward passes under CPU autocast (weights, gradients stay float32); by
    #: default chosen per machine by a timing (agent/matmul.py), recorded with each run
    precision: Precision = field(default_factory=default_precision)


@dataclass
class LatentModelConfig:
    """Encoder E(tau^{j-1}) -> z^j and decoder D(s, a, z^j) -> (s' - s, r)."""

    dim: int = setting(10, 1)
    lr: Scheduled = setting(1e-3, 0.0, 1.0)
    #: 5: at equal interactions as good as 20 on Circle 3 (3 seeds each, benchmarks/RESULTS.md)
    #: at a quarter of the latent model's cost
    updates_per_interaction: int = setting(5, 0)
    batch: int = setting(32, 1)  # consecutive interaction pairs per update
    #: discrete latents: ``expected`` (exact expectation over categories), ``marginal`` or
    #: ``gumbel`` (the paper's straight-through Gumbel-Softmax); see agent/latent.py
    estimator: Estimator = "expected"
    #: discrete latents: z^j as a Gumbel-max sample of the encoder's categorical (the paper's
    #: Eq. for z^j) instead of its argmax
    sample: bool = False
    usage_bonus: Scheduled = setting(0.1, 0.0)
    #: continuous latents: weight of mean(pre-tanh output^2), keeps z off the tanh corners
    preact_penalty: Scheduled = setting(1e-3, 0.0)
    #: continuous latents: z = tanh(encoder output), in [-1, 1]; False: the raw output (the
    #: paper bounds nothing; the paper profile's choice)
    squash: bool = True
    #: discrete latents: heads closer than this (target std units) are one strategy (0 = off)
    merge_threshold: float = setting(0.5, 0.0)
    refresh_every: int = setting(10, 1)  # cached latents recomputed every this many interactions


@dataclass
class StabilityConfig:
    """R = (1 - b) R_task + b R_stable."""

    beta: Scheduled = setting(0.5, 0.0, 1.0)
    #: boundary credit: the term paid on interaction j's last step is scale x R_stable
    #: (None = H, the paper's per-step R_stable summed over one interaction)
    scale: float | None = setting(None, 0.0)
    credit: Credit = "boundary"
    smirl_std_floor: float = setting(0.05, 1e-9)  # SMiRL's density: std floor


@dataclass
class AgentConfig:
    """Everything that defines an agent; saved with every run."""

    method: Method = "sili"
    latent: LatentKind = "discrete"
    hidden: int = setting(256, 1)  # every network is 2 x hidden
    #: float32 matrix-product library of every network (agent/matmul.py)
    matmul: Matmul = field(default_factory=default_matmul)
    sac: SACConfig = field(default_factory=SACConfig)
    model: LatentModelConfig = field(default_factory=LatentModelConfig)
    sili: StabilityConfig = field(default_factory=StabilityConfig)
    #: the named profile the settings started from ("package" or "paper")
    profile: str = "package"

    # ------------------------------------------------------------------ derived
    @property
    def uses_latent_model(self) -> bool:
        return self.latent in ("discrete", "continuous")

    @property
    def policy_latents(self) -> int:
        """How many latents the policy is conditioned on: z^j (and z^{j-1} for SILI/Stable);
        none without a latent (SAC, Oracle, SMiRL, and the partial flag in the observation)."""
        if self.latent not in ("discrete", "continuous", "true"):
            return 0
        return 1 if self.method == "lili" else 2

    def to_dict(self) -> dict[str, Any]:
        return to_plain(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AgentConfig:
        return from_plain(cls, data, "agent")

    def validate(self) -> AgentConfig:
        check(self, "")
        if self.matmul == "onednn" and not onednn_available():
            raise ConfigError(
                "matmul 'onednn' needs a PyTorch built with oneDNN, which this one is not; "
                "allowed here: aten"
            )
        return self


# ---------------------------------------------------------------------- generic typed access
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _allowed(tp: Any) -> str:
    args = typing.get_args(tp)
    if typing.get_origin(tp) is Literal:
        return "one of " + ", ".join(map(str, args))
    names = [getattr(a, "__name__", str(a)) for a in args] or [getattr(tp, "__name__", str(tp))]
    return " or ".join(n.replace("NoneType", "null") for n in names)


def convert(name: str, tp: Any, value: Any) -> Any:
    """``value`` as a field of type ``tp``, or ConfigError naming ``name`` and what is allowed."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"unknown {name} {value!r}; allowed: {', '.join(map(str, args))}")
        return value
    if args and origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        if isinstance(value, Schedule) and Schedule in args:
            return value
        if isinstance(value, dict) and Schedule in args:
            try:
                return Schedule.from_dict(value)
            except ConfigError as err:
                raise ConfigError(f"setting {name}: {err}") from None
            except (TypeError, KeyError, ValueError):
                raise ConfigError(
                    f'setting {name}: a schedule is {{"points": [[INTERACTION, VALUE], ...]}} '
                    f"(or INTERACTION:VALUE,... on the command line), got {value!r}"
                ) from None
        if isinstance(value, str) and ":" in value and Schedule in args:
            try:
                return Schedule.parse(value)
            except ConfigError as err:
                raise ConfigError(f"setting {name}: {err}") from None
        if Schedule in args and not is_number(value):
            raise ConfigError(
                f"setting {name} must be a number or a schedule (INTERACTION:VALUE,... or "
                f'{{"points": [[INTERACTION, VALUE], ...]}}), got {value!r}'
            )
        for kind in (float, int, bool, str):
            if kind in args:
                return convert(name, kind, value)
        raise ConfigError(f"setting {name} must be {_allowed(tp)}, got {value!r}")
    if isinstance(value, Schedule) and tp in (float, int):
        raise ConfigError(
            f"setting {name} takes one number, not a schedule ({value}); the settings that take "
            f"schedules: {', '.join(paths(AgentConfig, schedulable=True))}"
        )
    number = is_number(value)  # numpy's too: np.float32(3e-4) is a learning rate
    if tp is float:
        if not number:
            raise ConfigError(f"setting {name} must be a number, got {value!r}")
        return float(value)
    if tp is int:
        if not (number and float(value).is_integer()):
            raise ConfigError(f"setting {name} must be a whole number, got {value!r}")
        return int(value)
    if tp is bool:
        if type(value).__name__ not in ("bool", "bool_"):
            raise ConfigError(f"setting {name} must be true or false, got {value!r}")
        return bool(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"setting {name} must be a string, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"setting {name} is a section; give its fields, got {value!r}")
        return from_plain(tp, value, name)
    return value


def check(obj: Any, prefix: str) -> None:
    """Every field of a config dataclass within its declared type and range (recursively)."""
    hints = _hints(type(obj))
    for f in fields(obj):
        name = f"{prefix}{f.name}"
        value = getattr(obj, f.name)
        if _is_section(value):
            check(value, name + ".")
            continue
        convert(name, hints[f.name], value)  # type and Literal membership
        low, high = f.metadata.get("low", -math.inf), f.metadata.get("high", math.inf)
        if isinstance(value, Schedule):
            value.check(name, low, high)
            for _, point in value.points:
                _check_float32(f"schedule of {name}: a value", point)
        elif isinstance(value, int | float) and not isinstance(value, bool):
            if math.isinf(value):  # no setting is unbounded in use (inf updates, inf entropy)
                raise ConfigError(f"{name} must be a finite number, got {value}")
            if hints[f.name] is int and value > LARGEST_INT:  # beyond, torch's sizes overflow
                raise ConfigError(f"{name} must be at most {LARGEST_INT}, got {value:.6g}")
            if hints[f.name] is not int:  # (a count is held to its own range)
                _check_float32(name, value)
            if not (low <= value <= high):
                raise ConfigError(f"{name} must be {_range(low, high, hints[f.name])}, got {value}")


#: the largest whole-number setting (a size or a count) a run can have
LARGEST_INT = 2**31 - 1
#: the least magnitude float32 rounds to infinity (just past its largest, 3.4028235e+38)
FLOAT32_OVERFLOW = 2.0**128 - 2.0**103


def _check_float32(name: str, value: float) -> None:
    if abs(value) >= FLOAT32_OVERFLOW:
        raise ConfigError(
            f"{name} must be less than {FLOAT32_OVERFLOW!r} in size (the networks compute in "
            f"float32, where {value!r} is infinite)"
        )


def _range(low: float, high: float, tp: Any) -> str:
    if tp is int or (math.isfinite(low) and not math.isfinite(high)):
        return f">= {low:g}"
    return span(low, high)


def _is_section(value: Any) -> bool:
    """A nested config section (a dataclass instance that is not a schedule)."""
    return dataclasses.is_dataclass(value) and not isinstance(value, Schedule | type)


def get_path(obj: Any, path: str) -> Any:
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def paths(cls: type, prefix: str = "", schedulable: bool = False) -> list[str]:
    """Every leaf setting's dotted path, in declaration order (``schedulable``: only those that
    take a schedule)."""
    out: list[str] = []
    hints = _hints(cls)
    for f in fields(cls):
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            out += paths(tp, f"{prefix}{f.name}.", schedulable)
        elif not schedulable or Schedule in typing.get_args(tp):
            out.append(f"{prefix}{f.name}")
    return out


class UnknownSetting(ConfigError):
    """A dotted path that names no setting (callers with more settings list them all)."""

    def __init__(self, name: str, allowed: str) -> None:
        self.name = name
        super().__init__(f"unknown setting {name!r}; allowed: {allowed}")


def set_path(obj: Any, path: str, value: Any, prefix: str = "") -> None:
    """Set a dotted path, converting ``value`` by the field's type; unknown paths are named."""
    *sections, leaf = path.split(".")
    target = obj
    for part in sections:
        if not _is_section(target) or part not in {f.name for f in fields(target)}:
            raise UnknownSetting(prefix + path, _listing(obj, prefix))
        target = getattr(target, part)
    if not _is_section(target):  # a path into a number (sac.lr.x)
        raise UnknownSetting(prefix + path, _listing(obj, prefix))
    names = {f.name for f in fields(target)}
    hints = _hints(type(target))
    if leaf not in names or dataclasses.is_dataclass(hints[leaf]):
        raise UnknownSetting(prefix + path, _listing(obj, prefix))
    setattr(target, leaf, convert(prefix + path, hints[leaf], value))


def _listing(obj: Any, prefix: str) -> str:
    return ", ".join(prefix + p for p in paths(type(obj)))


def to_plain(obj: Any) -> Any:
    """A config dataclass as JSON-ready dicts (schedules as {"points": ...})."""
    if isinstance(obj, Schedule):
        return obj.to_dict()
    if dataclasses.is_dataclass(obj):
        return {f.name: to_plain(getattr(obj, f.name)) for f in fields(obj)}
    return obj


def from_plain(cls: type, data: dict[str, Any], name: str) -> Any:
    """The dataclass ``cls`` from ``to_plain``'s output; unknown keys are named."""
    known = {f.name for f in fields(cls)}
    unknown = set(data) - known
    if unknown:
        raise ConfigError(f"unknown {name} settings {sorted(unknown)}; allowed: {sorted(known)}")
    hints = _hints(cls)
    return cls(**{k: convert(f"{name}.{k}", hints[k], v) for k, v in data.items()})


def scheduled_paths(cfg: Any, prefix: str = "") -> list[str]:
    """The dotted paths of the settings given as schedules."""
    out: list[str] = []
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        if _is_section(value):
            out += scheduled_paths(value, f"{prefix}{f.name}.")
        elif isinstance(value, Schedule):
            out.append(prefix + f.name)
    return out
