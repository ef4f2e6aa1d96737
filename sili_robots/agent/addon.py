"""The extension point for research add-ons: hooks the agent calls, none of them required.

An add-on subclasses ``AgentAddon`` and overrides the hooks it needs. The agent collects, per
hook, only the add-ons that override it, so a hook nobody overrides costs nothing: with no
add-ons the agent runs the paper's algorithm and none of their code, per step or per update.
Add-ons live outside ``sili_robots/agent/`` (in ``sili_robots/addons/``, or a user's own module
named by the setting ``addons.plugins``) and are wired in by configuration
(``sili_robots.addons.build_addons``); they may read the agent's public state (``buffer``;
``Z``, the cached latents: ``Z[j]`` is z^j of stored interaction j, ``Z[0]`` the zeros of no
history, the true strategy for ``latent="true"``; ``zdim``, their size; ``latents``, ``model``,
``cfg``, ``rng``). A run records each of a user's add-ons by ``module:Class`` and a digest of
its module's file (``config.json``'s ``versions``; a resume on another is noted in
``continued``): its settings are its class attributes.

Hooks, in the order the agent calls them:

- ``encoder_readouts``: extra per-interaction features for the encoder's head, at construction.
- ``begin_interaction``: a new interaction starts (after construction, each interaction, load).
- ``acting_latent`` / ``observe_step``: per step, z^j as the policy should act on it now (the
  last add-on's that gives one), and each step played (the only per-step hooks).
- ``interaction_stored(j)``: interaction j is stored and z^{j+1} cached; returns values for
  the ``metrics.csv`` columns the class declares in ``metric_columns``.
- ``stability_distance``: d(z^j, z^{j+1}) replaced (one add-on), for the metrics here and for
  each batch's stability reward below (``stability.change_after(agent.Z, j, agent.cfg.latent)``
  is the latents' own). Not read with partial latents, whose R_stable counts the opponent's
  change flags; SMiRL trains on its own term (its metrics still show d).
- ``latents_refreshed``: the cached latents were recomputed with the current encoder.
- ``before_update(interaction)``: settings for the updates after ``interaction``.
- ``latent_pairs`` / ``rl_interactions``: which stored interactions a batch draws.
- ``batch_latents``: z^j per sampled step as the policy acted on it (the last add-on's).
- ``state_dict`` / ``load_state_dict``: checkpoints.

What a hook returns is checked where the agent reads it (its type, its shape, indices within the
stored interactions); a wrong one is refused with the add-on's name and what the hook must return.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch

from sili_robots.errors import ConfigError, first_line

if TYPE_CHECKING:
    from sili_robots.agent.agent import SILIAgent

HOOKS = (
    "encoder_readouts",
    "begin_interaction",
    "acting_latent",
    "observe_step",
    "interaction_stored",
    "latents_refreshed",
    "before_update",
    "latent_pairs",
    "rl_interactions",
    "batch_latents",
    "stability_distance",
)


class AgentAddon:
    """Base class: every hook is a no-op; override what the add-on changes."""

    name: ClassVar[str] = "addon"
    #: the ``metrics.csv`` columns ``interaction_stored`` fills (written after the usual ones)
    metric_columns: ClassVar[tuple[str, ...]] = ()
    agent: SILIAgent

    def attach(self, agent: SILIAgent) -> None:
        self.agent = agent

    def encoder_readouts(self) -> list[Callable[[torch.Tensor], torch.Tensor]]:
        """Functions of the per-step features [N, H, hidden] -> [N, hidden] for the head."""
        return []

    def begin_interaction(self) -> None:
        pass

    def acting_latent(self) -> np.ndarray | None:
        """z^j for the step about to be played (None: the encoder's)."""
        return None

    def observe_step(
        self, obs: np.ndarray, act: np.ndarray, rew: float, next_obs: np.ndarray
    ) -> None:
        pass

    def interaction_stored(self, j: int) -> dict[str, float]:
        """Values of ``metric_columns`` for interaction j (others are not written)."""
        return {}

    def latents_refreshed(self) -> None:
        pass

    def before_update(self, interaction: int) -> None:
        pass

    def latent_pairs(self, j: np.ndarray) -> np.ndarray:
        """Interactions j of a latent-model batch of pairs (j-1, j)."""
        return j

    def rl_interactions(self, j: np.ndarray) -> np.ndarray:
        """Interactions [U, M] of the RL batches."""
        return j

    def batch_latents(
        self, j: np.ndarray, t: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """z^j at steps t and t+1 of stored interactions j as acted on (None: ``z`` both)."""
        return None

    def stability_distance(self, j: np.ndarray) -> np.ndarray | None:
        """d for the change after each stored interaction j, finite, of ``j``'s shape (any:
        ``[1]`` for the metrics, ``[U, M, K]`` for training batches); None: the latents'
        distance, which is 0 after interaction 0 (there was no z^0 to keep; not so for the
        true latent, whose z^0 is the true strategy)."""
        return None

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass


def overriding(addons: list[AgentAddon], hook: str) -> list[AgentAddon]:
    """The add-ons whose class overrides ``hook``."""
    base = getattr(AgentAddon, hook)
    return [a for a in addons if getattr(type(a), hook) is not base]


def refused(addon: AgentAddon, hook: str, value: object, wanted: str) -> ConfigError:
    """The error for a hook's wrong return, naming the add-on: it failed deep in the agent with
    numpy's or torch's words, and an index past the stored interactions read empty rows."""
    shown = f"{value!r:.80}"
    if isinstance(value, (np.ndarray, list)) and shape_of(value) is not None:
        array = np.asarray(value)  # a list of indices is shown as the array it makes
        shown = f"an array of shape {array.shape} and dtype {array.dtype}"
        if array.dtype.kind in "iu" and array.size:
            shown += f", entries {array.min()} to {array.max()}"
    return ConfigError(f"add-on {type(addon).__name__}: {hook} must return {wanted}, got {shown}")


def readouts(addon: AgentAddon, hidden: int, horizon: int) -> list[Callable]:
    """An ``encoder_readouts`` return checked: functions, each tried on zero features
    [2, horizon, hidden] to give [2, hidden] (a wrong one failed later in the encoder's head,
    in torch's words); tried without gradients, torch's random state put back."""
    given = addon.encoder_readouts()
    wanted = f"a list of functions of per-step features [N, H, {hidden}] to [N, {hidden}]"
    if not isinstance(given, list | tuple) or not all(callable(r) for r in given):
        raise refused(addon, "encoder_readouts", given, wanted)
    probe = torch.zeros(2, horizon, hidden)
    for readout in given:
        try:
            with torch.no_grad(), torch.random.fork_rng(devices=[]):
                out = readout(probe)
        except Exception as err:  # the add-on's own code, named with it
            raise ConfigError(
                f"add-on {type(addon).__name__}: an encoder_readouts function failed on "
                f"features of shape {tuple(probe.shape)}: {first_line(err)}"
            ) from err
        if not isinstance(out, torch.Tensor) or tuple(out.shape) != (2, hidden):
            got = tuple(out.shape) if isinstance(out, torch.Tensor) else out
            raise refused(addon, "encoder_readouts", got, wanted + " (given [2, H, hidden])")
    return list(given)


def distances(name: str, d: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A ``stability_distance`` return checked: finite (else met as a diverged training), of
    the batch's shape and >= 0 (a negative d would pay for changes)."""
    if d.shape != shape or not np.isfinite(d).all() or (d < 0).any():
        wrong = " (not finite)" if not np.isfinite(d).all() else " (negative)"
        raise ConfigError(
            f"add-on {name}: stability_distance must return finite values >= 0 of j's shape "
            f"{shape}, got shape {d.shape}{'' if d.shape != shape else wrong}"
        )
    return d


def load_states(addons: list[AgentAddon], saved: Mapping[str, Any]) -> None:
    """Each add-on's state from a checkpoint, by its ``name``; an error of its own is named
    with it and the states the checkpoint holds under other names (an add-on renamed since
    finds none of its own)."""
    for addon in addons:
        try:
            addon.load_state_dict(saved.get(addon.name, {}))
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as err:
            others = sorted(set(saved) - {a.name for a in addons})
            held = f"; the checkpoint holds states named {others}" if others else ""
            raise ConfigError(
                f"add-on {type(addon).__name__} (name {addon.name!r}) could not load its state "
                f"from the checkpoint: {first_line(err)}{held}"
            ) from err


def as_indices(value: object, shape: tuple[int, ...], low: int, high: int) -> np.ndarray | None:
    """``value`` (an array, list or tensor) as integers of ``shape`` in [low, high), or None."""
    try:
        j = np.asarray(value)
    except (TypeError, ValueError):  # e.g. a ragged list
        return None
    if j.shape != shape or j.dtype.kind not in "iu":
        return None
    return j if j.size == 0 or (int(j.min()) >= low and int(j.max()) < high) else None


def redrawn(addons: list[AgentAddon], hook: str, j: np.ndarray, low: int, high: int) -> np.ndarray:
    """Stored interactions ``j`` as the add-ons of ``hook`` (``latent_pairs``,
    ``rl_interactions``) redraw them in turn, each return checked to lie in [low, high)."""
    for addon in addons:
        given = getattr(addon, hook)(j)
        checked = as_indices(given, j.shape, low, high)
        if checked is None:
            wanted = f"an integer array of shape {j.shape} in [{low}, {high})"
            raise refused(addon, hook, given, wanted)
        j = checked
    return j


def stored_values(addon: AgentAddon, given: object) -> dict[str, float]:
    """An ``interaction_stored`` return checked: its columns' values, each a number (a tensor
    or a string would be written as its text), a flag as 0 or 1 (as the package's own)."""
    if not isinstance(given, Mapping):
        raise refused(addon, "interaction_stored", given, "a dict of its metric_columns' values")
    out = {}
    for column in type(addon).metric_columns:
        if column not in given:
            continue
        value = given[column]
        if not isinstance(value, int | float | np.integer | np.floating | np.bool_):
            raise refused(addon, "interaction_stored", value, f"a number for its column {column}")
        out[column] = int(value) if isinstance(value, bool | np.bool_) else value
    return out


def acting_latent(addon: AgentAddon, given: object, zdim: int) -> np.ndarray:
    """An ``acting_latent`` return (not None) checked: shape (zdim,), as float32 (the policy's
    dtype; float64 failed in torch)."""
    if shape_of(given) != (zdim,):
        raise refused(addon, "acting_latent", given, f"None or an array of shape ({zdim},)")
    return np.asarray(given, np.float32)


def latent_pair(addon: AgentAddon, given: object, shape: tuple[int, ...]) -> tuple[Any, Any]:
    """A ``batch_latents`` return (not None) checked: a pair of arrays of ``shape``."""
    if not (
        isinstance(given, (tuple, list))
        and len(given) == 2
        and all(shape_of(z) == shape for z in given)
    ):
        raise refused(addon, "batch_latents", given, f"None or two arrays of shape {shape}")
    return given[0], given[1]


def shape_of(value: object) -> tuple[int, ...] | None:
    """``value``'s array shape; None for a ragged one (numpy refuses to make it an array)."""
    try:
        return np.shape(value)
    except ValueError:
        return None
