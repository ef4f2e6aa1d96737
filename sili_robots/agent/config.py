"""Agent configuration: one dataclass, and the methods as presets of it.

Every method of the paper is this one agent with different settings:

| method  | latent model | policy input        | reward                                  |
|---------|--------------|---------------------|-----------------------------------------|
| sili    | yes          | s, z^j, z^{j-1}     | (1-b) R_task + b R_stable               |
| lili    | yes          | s, z^j              | R_task (b = 0)                          |
| stable  | yes          | s, z^j, z^{j-1}     | R_stable (b = 1)                        |
| sac     | no           | s                   | R_task                                  |
| oracle  | no           | s + true z          | R_task                                  |
| smirl   | no           | s                   | (1-b) R_task + b log p(s) (SMiRL)       |
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, fields
from itertools import pairwise
from typing import Any, ClassVar, TypeVar

from sili_robots.agent.matmul import MATMULS, default_matmul, onednn_available
from sili_robots.errors import ConfigError

METHODS = ("sili", "lili", "stable", "sac", "oracle", "smirl")
#: the methods whose b is a setting (the others fix it: LILI 0, Stable 1, SAC and Oracle none)
BETA_METHODS = ("sili", "smirl")
#: ``true`` is the diagnostic that feeds the true strategy in place of the predicted latent
LATENT_KINDS = ("discrete", "continuous", "partial", "true")
STABILITY_DISTANCES = ("latents", "posterior", "hindsight")
PRECISIONS = ("float32", "bfloat16")


ScheduleT = TypeVar("ScheduleT", bound="Schedule")


@dataclass
class Schedule:
    """A setting as a piecewise-linear function of the interaction index.

    ``points`` are (interaction, value) knots in increasing interaction order; the value is held at
    the first knot's before it and at the last knot's after it. Subclasses name the setting and
    bound its values, so a bad knot is reported by name."""

    points: list[tuple[int, float]]
    name: ClassVar[str] = "schedule"  # for messages
    symbol: ClassVar[str] = "value"
    low: ClassVar[float] = -math.inf
    high: ClassVar[float] = math.inf

    @classmethod
    def from_dict(cls: type[ScheduleT], data: dict[str, Any]) -> ScheduleT:
        return cls([(int(i), float(v)) for i, v in data["points"]])

    def value(self, interaction: int) -> float:
        first, last = self.points[0], self.points[-1]
        if interaction <= first[0]:
            return first[1]
        for (i0, v0), (i1, v1) in pairwise(self.points):
            if interaction < i1:
                return v0 + (interaction - i0) / (i1 - i0) * (v1 - v0)
        return last[1]

    def check(self) -> None:
        """Raise ConfigError naming the first bad knot."""
        name = self.name
        if not self.points:
            raise ConfigError(f"{name} needs at least one (interaction, {self.symbol}) point")
        previous = -1
        for i, v in self.points:
            if i < 0:
                raise ConfigError(f"{name} interaction must be >= 0, got {i}")
            if i <= previous:
                raise ConfigError(f"{name} interactions must increase, got {i} after {previous}")
            if not (math.isfinite(v) and self.low <= v <= self.high):
                raise ConfigError(
                    f"{name}: {self.symbol} must be {self.allowed()}, got {v} at interaction {i}"
                )
            previous = i

    @classmethod
    def allowed(cls) -> str:
        bounded = math.isfinite(cls.low) or math.isfinite(cls.high)
        return f"in [{cls.low:g}, {cls.high:g}]" if bounded else "a finite number"


@dataclass
class BetaSchedule(Schedule):
    """The stability weight b over interactions.

    A ramp that starts late (b = 0 first) lets the latent model learn from a policy that pursues
    the task (as LILI) before the stability reward, which is noise while the latent is still
    wrong, starts to shape the policy; a later knot can lower b again once the opponent is held,
    so the task term weighs more."""

    name: ClassVar[str] = "beta schedule"
    symbol: ClassVar[str] = "b"
    low: ClassVar[float] = 0.0
    high: ClassVar[float] = 1.0

    @classmethod
    def ramp(cls, start: float, end: float, length: int, delay: int = 0) -> BetaSchedule:
        """b = ``start`` for ``delay`` interactions, then linear to ``end`` over ``length``."""
        return cls([(delay, start), (delay + length, end)])

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BetaSchedule:
        """Read a saved schedule; runs saved as a single ramp (start, end, length, delay) too."""
        if "points" in data:
            return super().from_dict(data)
        return cls.ramp(data["start"], data["end"], data["length"], data.get("delay", 0))


@dataclass
class EntropySchedule(Schedule):
    """SAC's target entropy over interactions.

    Exploration matters while the policy finds the opponent and learns to hold it; once it holds,
    the same entropy keeps the ego jittering around the opponent and forces a margin at the
    circle's edge. A target lowered late tightens both where the noise is the cost (Oracle on
    Circle) without starving early exploration, which a low target from the start does
    (benchmarks/RESULTS.md)."""

    name: ClassVar[str] = "target entropy schedule"
    symbol: ClassVar[str] = "target entropy"


@dataclass
class DiscountSchedule(Schedule):
    """SAC's discount gamma over interactions.

    gamma^H is what one interaction's value weighs in the one before it (0.99^50 = 0.61). While b
    pays for holding the opponent that is enough; once b is 0, only the task reward of later
    interactions pays for holding it, or for moving it on to a cheaper place first, and a larger
    gamma weighs those later interactions more."""

    name: ClassVar[str] = "discount schedule"
    symbol: ClassVar[str] = "gamma"
    low: ClassVar[float] = 0.0
    high: ClassVar[float] = 1.0


@dataclass
class LearningRateSchedule(Schedule):
    """SAC's learning rate (actor, critics and temperature) over interactions.

    Once the policy is near-deterministic and holds the opponent, what still moves its last step
    across the edge is the drift of its own mean under continued updates; a smaller step size late
    lets the mean settle where the critic puts it."""

    name: ClassVar[str] = "learning rate schedule"
    symbol: ClassVar[str] = "learning rate"
    low: ClassVar[float] = 0.0
    high: ClassVar[float] = 1.0


#: the agent settings that are schedules, their kind, and the options that give them
SCHEDULES: dict[str, type[Schedule]] = {
    "beta_schedule": BetaSchedule,
    "target_entropy_schedule": EntropySchedule,
    "gamma_schedule": DiscountSchedule,
    "lr_schedule": LearningRateSchedule,
}
SCHEDULE_OPTIONS = {
    "beta_schedule": "--beta-anneal or --beta-schedule",
    "target_entropy_schedule": "--target-entropy-schedule",
    "gamma_schedule": "--discount-schedule",
    "lr_schedule": "--lr-schedule",
}
#: schedules that replace a plain setting, which may then not be given as well
SCHEDULE_REPLACES = {"gamma_schedule": "gamma", "lr_schedule": "lr"}


def check_schedule_overrides(schedules: Iterable[str], overrides: dict[str, Any]) -> None:
    """Refuse a schedule given together with ``--set`` of the setting it replaces."""
    for key in schedules:
        setting = SCHEDULE_REPLACES.get(key)
        if setting in overrides:
            raise ConfigError(f"give one of --set {setting} and {SCHEDULE_OPTIONS[key]}, not both")


@dataclass
class AgentConfig:
    """Everything that defines an agent; saved with every run."""

    method: str = "sili"
    latent: str = "discrete"
    beta: float = 0.5
    beta_schedule: BetaSchedule | None = None
    latent_dim: int = 10
    hidden: int = 256
    # SAC
    lr: float = 3e-4
    #: SAC's learning rate over interactions (``--lr-schedule``); replaces ``lr`` when given
    lr_schedule: LearningRateSchedule | None = None
    gamma: float = 0.99
    #: gamma over interactions (``--discount-schedule``); replaces ``gamma`` when given
    gamma_schedule: DiscountSchedule | None = None
    tau: float = 5e-3
    batch_interactions: int = 16  # an RL batch = this many interactions ...
    batch_steps: int = 16  # ... times this many timesteps from each
    updates_per_step: float = 1.0  # SAC gradient updates per environment step
    #: "bfloat16": SAC's forward passes under CPU autocast (faster on CPUs with bfloat16 units;
    #: weights, gradients and optimizer state stay float32; see sili_robots/agent/sac.py)
    precision: str = "float32"
    #: the library of the float32 matrix products of every network: "onednn" or "aten"
    #: (PyTorch's default BLAS). Both compute in float32; oneDNN is faster where the BLAS is slow
    #: (sili_robots/agent/matmul.py). The default is onednn where this PyTorch has it; runs saved
    #: before this setting existed load with aten, the kernels they were trained with
    matmul: str = field(default_factory=default_matmul)
    #: the entropy SAC's temperature holds the policy at (default -|A|, SAC's usual choice).
    #: Lower is more deterministic everywhere (measured on Circle in benchmarks/RESULTS.md)
    target_entropy: float | None = None
    #: the target entropy over interactions (``--target-entropy-schedule``); replaces
    #: ``target_entropy`` when given
    target_entropy_schedule: EntropySchedule | None = None
    #: fraction of each RL batch's interactions drawn from the newest ``recent_interactions``
    #: (the rest uniformly from the whole replay). 0 = uniform (default). A policy that held one
    #: strategy for a long time has little replay of the others; after a slip, this makes the
    #: new strategy's on-policy data count sooner
    recent_fraction: float = 0.0
    recent_interactions: int = 100
    random_interactions: int = 20  # uniform random actions first (20 x 50 = 1,000 steps)
    # latent model
    latent_lr: float = 1e-3
    latent_updates_per_interaction: int = 20
    latent_batch: int = 32  # consecutive interaction pairs per latent-model update
    #: discrete latents: "expected" (exact expectation over categories, default), "marginal"
    #: (exact marginal likelihood) or "gumbel" (the paper's straight-through Gumbel-Softmax);
    #: see sili_robots/agent/latent.py
    latent_estimator: str = "expected"
    latent_usage_bonus: float = 0.1
    #: continuous latents: weight of mean(pre-tanh output^2) in the latent-model loss, which
    #: keeps z^j off the corners of the tanh box (0 = off; see sili_robots/agent/latent.py).
    #: Runs saved before this setting existed load with 0, the loss they were trained with
    latent_preact_penalty: float = 1e-3
    #: the encoder also sees the last transition of tau^{j-1} on its own, beside the mean- and
    #: max-pooled features of all of them (see sili_robots/agent/latent.py). Off by default
    latent_last_step: bool = False
    #: discrete latents: categories whose decoder heads differ by less than this many target
    #: standard deviations count as one strategy (0 = off; see latent.category_groups)
    latent_merge_threshold: float = 0.5
    #: discrete latents: fraction of each latent-model batch drawn from the pairs (j-1, j)
    #: across which the strategy changed, as the decoder's posterior tells it in hindsight
    #: (0 = uniform pairs). Changes are rare once the opponent is held, so uniform pairs teach
    #: the encoder little about where in tau^{j-1} a change is decided (e.g. the edge of the
    #: circle); see ``SILIAgent.change_pairs``
    latent_change_fraction: float = 0.0
    #: the prior probability eps that the strategy in effect differs from the encoder's z^j.
    #: Above 0 the policy acts on a within-interaction filter, the posterior given z^j and the
    #: steps played so far under the decoder (over the categories of discrete latents, over
    #: z^j and encoder latents of other strategies for continuous ones), and the critic learns
    #: on the same per-step latents (0 = off, the paper's fixed z^j; see
    #: sili_robots/agent/latent_filter.py)
    latent_filter: float = 0.0
    #: the filter runs from the first latent refresh at or after this many interactions (0: the
    #: first refresh), e.g. once the policy has learned to reach each strategy
    latent_filter_start: int = 0
    #: the filter's noise scale per output: 0 = the decoder's own residual error (on its newest
    #: interactions), s > 0 = s times the targets' standard deviation over the replay. The
    #: residual treats every step as independent evidence, but a decoder's errors within an
    #: interaction are correlated (a bias over its 50 steps), so at that scale small biases add
    #: up to a switch; a broader scale lets only differences as large as a strategy's count
    latent_filter_noise: float = 0.0
    #: discrete latents: what the stability reward counts as a change of strategy. "latents":
    #: the paper's d(z^j, z^{j+1}), 1 when the encoder's category changed. "posterior": the
    #: probability that the strategy in effect during interaction j (the decoder's posterior
    #: given that interaction) differs from the predicted z^{j+1}. "hindsight": the probability
    #: that the strategies in effect during j and j+1 differ (see sili_robots/agent/agent.py)
    stability_distance: str = "latents"
    #: total stability reward credited per interaction = stability_scale * R_stable
    #: (default: the horizon, i.e. the paper's per-step R_stable summed over the interaction)
    stability_scale: float | None = None
    # SMiRL
    smirl_std_floor: float = 0.05
    extra: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ derived
    @property
    def uses_latent_model(self) -> bool:
        return self.method in ("sili", "lili", "stable") and self.latent in (
            "discrete",
            "continuous",
        )

    @property
    def latent_width(self) -> int:
        """Width of one latent as fed to the policy (0 when the policy sees none)."""
        if self.method not in ("sili", "lili", "stable") or self.latent == "partial":
            return 0
        return self.latent_dim

    @property
    def policy_latents(self) -> int:
        """How many latents the policy is conditioned on: z^j (and z^{j-1} for SILI/Stable)."""
        if self.latent_width == 0:
            return 0
        return 1 if self.method == "lili" else 2

    def beta_at(self, interaction: int) -> float:
        if self.method in ("sac", "oracle"):
            return 0.0
        if self.beta_schedule is not None:
            return self.beta_schedule.value(interaction)
        return self.beta

    def target_entropy_at(self, interaction: int, act_dim: int) -> float:
        """SAC's target entropy for updates made after ``interaction`` (default -|A|)."""
        if self.target_entropy_schedule is not None:
            return self.target_entropy_schedule.value(interaction)
        return -float(act_dim) if self.target_entropy is None else self.target_entropy

    def gamma_at(self, interaction: int) -> float:
        """SAC's discount for updates made after ``interaction``."""
        if self.gamma_schedule is not None:
            return self.gamma_schedule.value(interaction)
        return self.gamma

    def lr_at(self, interaction: int) -> float:
        """SAC's learning rate for updates made after ``interaction``."""
        if self.lr_schedule is not None:
            return self.lr_schedule.value(interaction)
        return self.lr

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AgentConfig:
        data = dict(data)
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown agent settings {sorted(unknown)}; allowed: {sorted(known)}")
        for key, kind in SCHEDULES.items():
            if data.get(key) is not None:
                data[key] = kind.from_dict(data[key])
        data.setdefault("latent_preact_penalty", 0.0)  # saved before it existed: trained without
        data.setdefault("matmul", "aten")  # likewise: trained on PyTorch's default kernels
        return cls(**data)

    def validate(self) -> AgentConfig:
        if self.method not in METHODS:
            raise ConfigError(f"unknown method {self.method!r}; allowed: {', '.join(METHODS)}")
        if self.latent not in LATENT_KINDS:
            raise ConfigError(
                f"unknown latent kind {self.latent!r}; allowed: {', '.join(LATENT_KINDS)}"
            )
        if not 0.0 <= self.beta <= 1.0:
            raise ConfigError(f"beta must be in [0, 1], got {self.beta}")
        for key in SCHEDULES:
            if getattr(self, key) is not None:
                getattr(self, key).check()
        if self.target_entropy_schedule is not None and self.target_entropy is not None:
            raise ConfigError("give one of target_entropy and a target entropy schedule")
        for name in ("latent_dim", "hidden", "batch_interactions", "batch_steps", "latent_batch"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("updates_per_step", "random_interactions", "latent_updates_per_interaction"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.recent_fraction <= 1.0:
            raise ConfigError(f"recent_fraction must be in [0, 1], got {self.recent_fraction}")
        if self.recent_interactions < 1:
            raise ConfigError(f"recent_interactions must be >= 1, got {self.recent_interactions}")
        if self.latent_merge_threshold < 0:
            raise ConfigError(
                f"latent_merge_threshold must be >= 0, got {self.latent_merge_threshold}"
            )
        if self.latent_preact_penalty < 0:
            raise ConfigError(
                f"latent_preact_penalty must be >= 0, got {self.latent_preact_penalty}"
            )
        if not 0.0 <= self.latent_change_fraction <= 1.0:
            raise ConfigError(
                f"latent_change_fraction must be in [0, 1], got {self.latent_change_fraction}"
            )
        if not 0.0 <= self.latent_filter < 1.0:
            raise ConfigError(f"latent_filter must be in [0, 1), got {self.latent_filter}")
        if self.latent_filter > 0 and not (
            self.uses_latent_model and self.latent in ("discrete", "continuous")
        ):
            raise ConfigError(
                f"latent_filter {self.latent_filter} needs learned latents (discrete or "
                f"continuous) of a method with a latent model (sili, lili, stable), got method "
                f"{self.method!r} with latent {self.latent!r}; allowed otherwise: 0"
            )
        if self.latent_filter_noise < 0:
            raise ConfigError(
                f"latent_filter_noise must be >= 0 (0: the decoder's residual), "
                f"got {self.latent_filter_noise}"
            )
        if self.latent_filter_start < 0:
            raise ConfigError(
                f"latent_filter_start must be >= 0 interactions, got {self.latent_filter_start}"
            )
        if self.precision not in PRECISIONS:
            raise ConfigError(
                f"unknown precision {self.precision!r}; allowed: {', '.join(PRECISIONS)}"
            )
        if self.matmul not in MATMULS:
            raise ConfigError(f"unknown matmul {self.matmul!r}; allowed: {', '.join(MATMULS)}")
        if self.matmul == "onednn" and not onednn_available():
            raise ConfigError(
                "matmul 'onednn' needs a PyTorch built with oneDNN, which this one is not; "
                "allowed here: aten"
            )
        if self.stability_distance not in STABILITY_DISTANCES:
            raise ConfigError(
                f"unknown stability_distance {self.stability_distance!r}; "
                f"allowed: {', '.join(STABILITY_DISTANCES)}"
            )
        if self.latent_estimator not in ("expected", "marginal", "gumbel"):
            raise ConfigError(
                f"unknown latent_estimator {self.latent_estimator!r}; "
                "allowed: expected, marginal, gumbel"
            )
        if not 0.0 < self.gamma <= 1.0:
            raise ConfigError(f"gamma must be in (0, 1], got {self.gamma}")
        return self


def _typed(name: str, annotation: str, value: Any) -> Any:
    """``value`` as the setting's declared type, so a mistyped ``--set`` fails here, by name,
    and not later inside the networks."""
    is_number = isinstance(value, int | float) and not isinstance(value, bool)
    if annotation == "float" or (annotation == "float | None" and value is not None):
        if not is_number:
            raise ConfigError(f"agent setting {name} must be a number, got {value!r}")
        return float(value)
    if annotation == "int":
        if not (is_number and float(value).is_integer()):
            raise ConfigError(f"agent setting {name} must be a whole number, got {value!r}")
        return int(value)
    if name in SCHEDULES and not isinstance(value, SCHEDULES[name] | None):
        raise ConfigError(f"give {name} with {SCHEDULE_OPTIONS[name]}, not {value!r}")
    if annotation == "bool" and not isinstance(value, bool):
        raise ConfigError(f"agent setting {name} must be true or false, got {value!r}")
    if annotation == "str" and not isinstance(value, str):
        raise ConfigError(f"agent setting {name} must be a string, got {value!r}")
    return value


def method_config(method: str, latent: str | None = None, **overrides: Any) -> AgentConfig:
    """The preset for ``method``; ``latent`` defaults to the task's choice (else discrete)."""
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; allowed: {', '.join(METHODS)}")
    cfg = AgentConfig(method=method, latent=latent or "discrete")
    if method == "lili":
        cfg.beta = 0.0
    elif method == "stable":
        cfg.beta = 1.0
    elif method in ("sac", "oracle"):
        cfg.beta = 0.0
    types = {f.name: f.type for f in fields(AgentConfig)}
    for k, v in overrides.items():
        if k not in types:
            raise ConfigError(f"unknown agent setting {k!r}")
        setattr(cfg, k, _typed(k, types[k], v))
    if method == "lili" and cfg.latent == "partial":
        cfg.latent = "discrete"  # LILI always learns a latent; b = 0 makes the flag unused
    return cfg.validate()
