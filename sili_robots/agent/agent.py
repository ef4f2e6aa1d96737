"""The SILI agent (the paper's framework figure): SAC + latent strategy model + stability reward.

Left of the figure, the latent model: z^j = E(tau^{j-1}) is inferred when interaction j begins
and cached (``LatentCache``); E and the decoder D(s, a, z^j) -> (s' - s, r) are trained on
consecutive pairs (j-1, j). Right, the RL: the policy acts on [s, z^j, z^{j-1}] and SAC learns
from R = (1 - b) R_task + b R_stable (``stability.py`` says where R_stable is paid).

Crossing interactions: the last transition of interaction j goes to the first observation of
interaction j+1 with that interaction's latents (z^{j+1}, z^j), so the critic bootstraps across
the boundary; the repeated game never terminates, so every target bootstraps.

Every method of the paper is a configuration (``methods.py``). Research variants are add-ons
(``addon.py``): the agent calls only the hooks they override.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from sili_robots.agent import addon as addon_checks
from sili_robots.agent import stability
from sili_robots.agent.addon import HOOKS, AgentAddon, overriding
from sili_robots.agent.buffer import InteractionBuffer
from sili_robots.agent.config import AgentConfig
from sili_robots.agent.latent import LatentModel, transitions
from sili_robots.agent.latent_cache import LatentCache
from sili_robots.agent.sac import SAC
from sili_robots.agent.schedule import value_at
from sili_robots.agent.smirl import RunningGaussian
from sili_robots.errors import CheckpointMismatch, ConfigError, TrainingDiverged


@dataclass
class InteractionStats:
    """What the agent saw of one finished interaction."""

    #: R_stable of the interaction before b and the credit: -d(z^j, z^{j+1}) (``boundary`` pays
    #: scale x that, H by default; ``per_step`` that on each step of j+1); partial: minus the
    #: steps whose flag was raised
    stability_reward: float
    latent_category: int  # argmax of z^{j+1} (-1 when there is no discrete latent)
    #: the agent's own latent changed between j and j+1 (partial: the observed flag was raised)
    latent_changed: bool
    extra: dict[str, float] = field(default_factory=dict)  # add-ons' metric columns


def check_finite(
    losses: dict[str, float], interaction: int, unset: tuple[str, ...] = ()
) -> dict[str, float]:
    """``losses``, or TrainingDiverged: once a loss is infinite or NaN the networks are too,
    and the task would refuse the next action without saying why (``unset``: NaN by design)."""
    bad = [f"{k} {v}" for k, v in losses.items() if not math.isfinite(v) and k not in unset]
    if bad:
        raise TrainingDiverged(
            f"training diverged after interaction {interaction} ({', '.join(bad)}): settings "
            "far outside their usual range do this (a huge sac.target_entropy, sili.scale or "
            "learning rate)"
        )
    return losses


class SILIAgent:
    """One agent; ``AgentConfig.method`` decides which method of the paper it is."""

    def __init__(
        self,
        cfg: AgentConfig,
        obs_dim: int,
        act_dim: int,
        horizon: int,
        strategy_dim: int,
        seed: int = 0,
        addons: list[AgentAddon] | tuple[AgentAddon, ...] = (),
    ) -> None:
        self.cfg = cfg.validate()
        if torch.get_default_dtype() != torch.float32:  # networks of it would meet float32 data
            raise ConfigError(
                f"torch's default dtype is {torch.get_default_dtype()} (torch.set_default_dtype); "
                "the agent computes in float32: set it back to torch.float32"
            )
        self.obs_dim, self.act_dim, self.horizon = obs_dim, act_dim, horizon
        self.rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        self.addons = list(addons)
        self.hooks = {h: overriding(self.addons, h) for h in HOOKS}
        self.zdim = strategy_dim if cfg.latent == "true" else cfg.model.dim
        self.n_latents = cfg.policy_latents
        self.in_dim = obs_dim + self.n_latents * self.zdim  # the policy's and critics' input
        self.sac = SAC(
            self.in_dim,
            act_dim,
            hidden=cfg.hidden,
            lr=value_at(cfg.sac.lr, 0),
            gamma=value_at(cfg.sac.gamma, 0),
            tau=value_at(cfg.sac.tau, 0),
            precision=cfg.sac.precision,
            target_entropy=value_at(cfg.sac.target_entropy, 0),
            matmul=cfg.matmul,
        )
        self.model: LatentModel | None = None
        if cfg.uses_latent_model:
            m = cfg.model
            self.model = LatentModel(
                obs_dim,
                act_dim,
                latent_dim=m.dim,
                hidden=cfg.hidden,
                kind=cfg.latent,
                estimator=m.estimator,
                usage_bonus=value_at(m.usage_bonus, 0),
                preact_penalty=value_at(m.preact_penalty, 0),
                squash=m.squash,
                readouts=[
                    r
                    for a in self.hooks["encoder_readouts"]
                    for r in addon_checks.readouts(a, cfg.hidden, horizon)
                ],
                matmul=cfg.matmul,
            )
            self.model_opt = torch.optim.Adam(  # foreach: the same steps, a third faster on CPU
                self.model.parameters(), lr=value_at(m.lr, 0), foreach=True
            )
        self.buffer = InteractionBuffer(obs_dim, act_dim, horizon)
        self.latents = LatentCache(
            self.model,
            self.buffer,
            kind=cfg.latent,
            dim=self.zdim,
            rng=self.rng,
            merge_threshold=cfg.model.merge_threshold,
            sample=cfg.model.sample and cfg.latent == "discrete",
            optimizer=self.model_opt if self.model is not None else None,
        )
        self.smirl = RunningGaussian(obs_dim, cfg.sili.smirl_std_floor)
        self.beta = float(value_at(cfg.sili.beta, 0))  # b now (the schedules add-on moves it)
        self.stability_scale = float(horizon if cfg.sili.scale is None else cfg.sili.scale)
        self._update_credit = 0.0
        self.game_start = 0  # the first stored interaction of the game being played
        for addon in self.addons:
            addon.attach(self)
        self.begin_interaction()

    @property
    def Z(self) -> np.ndarray:
        """Z[j] = z^j for every stored interaction and the next one (Z[0]: no history)."""
        return self.latents.Z

    @Z.setter
    def Z(self, value: np.ndarray) -> None:
        self.latents.Z = value

    def attach_addon(self, addon: AgentAddon) -> None:
        """Wire in an add-on after construction (e.g. a filter on a trained agent); its
        ``encoder_readouts`` cannot change a model that is already built. With interactions
        stored, it starts as from a checkpoint saved without it (its state built for them)."""
        addon.attach(self)  # first: one it refuses is not wired in
        self.addons.append(addon)
        self.hooks = {h: overriding(self.addons, h) for h in HOOKS}
        if self.buffer.n:
            addon.load_state_dict({})

    def detach_addon(self, kind: type[AgentAddon]) -> None:
        """Unwire the add-ons of type ``kind``."""
        self.addons = [a for a in self.addons if not isinstance(a, kind)]
        self.hooks = {h: overriding(self.addons, h) for h in HOOKS}

    def addon(self, kind: type[AgentAddon]) -> AgentAddon:
        """The wired add-on of type ``kind`` (KeyError when it is not wired)."""
        for a in self.addons:
            if isinstance(a, kind):
                return a
        raise KeyError(f"no {kind.__name__} add-on wired into this agent")

    # ------------------------------------------------------------------ acting
    def policy_input(self, obs: np.ndarray, j: int | None = None) -> np.ndarray:
        """[s, z^j, z^{j-1}] (SILI), [s, z^j] (LILI) or s, for the interaction being played."""
        live = j is None
        j = self.buffer.n if j is None else j
        parts = [np.asarray(obs, np.float32)]
        if self.n_latents >= 1:
            z = self.Z[j]
            if live:
                for addon in self.hooks["acting_latent"]:
                    acted = addon.acting_latent()
                    if acted is not None:
                        z = addon_checks.acting_latent(addon, acted, self.zdim)
            parts.append(z)
        if self.n_latents == 2:
            earlier = j > self.game_start  # z^{j-1} of this game
            parts.append(self.Z[j - 1] if earlier else np.zeros(self.zdim, np.float32))
        return np.concatenate(parts)

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        x = torch.from_numpy(self.policy_input(obs)).unsqueeze(0)
        return self.sac.act(x, deterministic)[0].numpy()

    def random_action(self) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, self.act_dim).astype(np.float32)

    @property
    def watches_steps(self) -> bool:
        """Whether an add-on needs each step as it is played (``observe_step``)."""
        return bool(self.hooks["observe_step"])

    def observe_step(
        self, obs: np.ndarray, act: np.ndarray, rew: float, next_obs: np.ndarray
    ) -> None:
        """One step of the interaction being played (for add-ons that watch steps)."""
        for addon in self.hooks["observe_step"]:
            addon.observe_step(obs, act, rew, next_obs)

    def begin_game(self, info: dict[str, Any]) -> None:
        """A (re)started repeated game: the interaction about to be played has no history, so it
        is acted on as a run's first one (z^j "no history", or the true strategy in the true
        mode; no z^{j-1}). Training plays one game; evaluations and the API may start others."""
        j = self.buffer.n
        self.Z[j] = info["strategy"] if self.cfg.latent == "true" else 0.0
        self.game_start = j
        self.begin_interaction()

    def begin_interaction(self) -> None:
        """A new interaction starts (the add-ons that follow one reset their state)."""
        for addon in self.hooks["begin_interaction"]:
            addon.begin_interaction()

    # ------------------------------------------------------------------ data
    def observe_interaction(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        next_first: np.ndarray,
        strategy_id: float,
        next_info: dict[str, Any],
        refresh: bool = True,
    ) -> InteractionStats:
        """Store interaction j (obs [H+1, o], act [H, a], rew [H]) and infer z^{j+1}."""
        aux = np.zeros(self.horizon, np.float32)
        if self.cfg.method == "smirl":
            aux = self.smirl.log_likelihood(obs[1:]).astype(np.float32)
            self.smirl.update(obs[1:])
        j = self.buffer.add(obs, act, rew, aux, next_first, strategy_id)
        if self.cfg.latent == "true":
            z_next = np.asarray(next_info["strategy"], np.float32)
        elif self.model is None:
            z_next = np.zeros(self.zdim, np.float32)
        else:
            z_next = self.latents.encode(np.array([j]))[0]
        self.latents.append(z_next)
        extra: dict[str, float] = {}
        for addon in self.hooks["interaction_stored"]:
            extra.update(addon_checks.stored_values(addon, addon.interaction_stored(j)))
        if refresh and self.model is not None and (j + 1) % self.cfg.model.refresh_every == 0:
            self.refresh_latents()
        self.begin_interaction()
        return self._stats(j, next_first, extra)

    def refresh_latents(self) -> None:
        """Recompute every cached latent with the current encoder (then the add-ons' state);
        discrete categories keep their names, the latent model permuted to match (latent_cache)."""
        self.latents.refresh()
        for addon in self.hooks["latents_refreshed"]:
            addon.latents_refreshed()

    def change_after(self, j: np.ndarray) -> np.ndarray:
        """d for the change after each stored interaction j, as the stability reward counts it."""
        given = []
        for addon in self.hooks["stability_distance"]:
            d = addon.stability_distance(j)
            if d is not None:
                given.append((type(addon).__name__, np.asarray(d)))
        if not given:
            return stability.change_after(self.Z, j, self.cfg.latent)
        if len(given) > 1:
            names = ", ".join(name for name, _ in given)
            raise ConfigError(f"add-ons {names} each replace stability_distance: keep one")
        [(name, d)] = given
        return addon_checks.distances(name, d, j.shape)

    def _stats(self, j: int, next_first: np.ndarray, extra: dict[str, float]) -> InteractionStats:
        if self.cfg.latent == "partial":
            flags = np.concatenate([self.buffer.obs[j, 1:, -1], next_first[-1:]])
            return InteractionStats(-float(flags.sum()), -1, bool(flags.any()), extra)
        d = float(self.change_after(np.array([j]))[0])
        discrete = self.cfg.latent == "discrete"
        changed = d > 0
        if discrete:  # the category changed (d may be a probability, from an add-on)
            changed = bool(j > 0 and self.Z[j].argmax() != self.Z[j + 1].argmax())
        category = int(self.Z[j + 1].argmax()) if discrete else -1
        return InteractionStats(-d, category, changed, extra)

    # ------------------------------------------------------------------ learning
    def update(self, interaction: int, rl: bool = True) -> dict[str, float]:
        """Learning after an interaction: latent model, then (with ``rl``) H * updates_per_step
        SAC steps. The latent model also learns during the random warm-up, whose diverse
        trajectories are the most informative about the opponent."""
        for addon in self.hooks["before_update"]:
            addon.before_update(interaction)
        losses: dict[str, float] = {}
        if self.model is not None and self.buffer.n >= 2:
            steps = self.cfg.model.updates_per_interaction
            losses["latent_loss"] = self.update_latent_model(steps)
        unset = () if self.cfg.model.updates_per_interaction else ("latent_loss",)
        if not rl:
            return check_finite(losses, interaction, unset)
        self._update_credit += self.horizon * value_at(self.cfg.sac.updates_per_step, interaction)
        n_updates = int(self._update_credit)
        self._update_credit -= n_updates
        if n_updates and self.buffer.n >= 1:
            x, a, r, x2 = self.sample_batches(n_updates, self.beta)
            out = [self.sac.update(x[u], a[u], r[u], x2[u]) for u in range(n_updates)]
            losses["critic_loss"] = float(torch.stack([o["critic_loss"] for o in out]).mean())
            losses["actor_loss"] = float(torch.stack([o["actor_loss"] for o in out]).mean())
            losses["alpha"] = self.sac.alpha
        return check_finite(losses, interaction, unset)

    def update_latent_model(self, steps: int) -> float:
        """Max-likelihood steps on random consecutive pairs (tau^{j-1}, tau^j)."""
        if steps == 0:
            return float("nan")
        b = self.buffer
        total = 0.0
        for _ in range(steps):
            j = self.rng.integers(1, b.n, self.cfg.model.batch)
            if self.hooks["latent_pairs"]:
                j = addon_checks.redrawn(self.hooks["latent_pairs"], "latent_pairs", j, 1, b.n)
            prev = transitions(
                torch.from_numpy(b.obs[j - 1]),
                torch.from_numpy(b.act[j - 1]),
                torch.from_numpy(b.rew[j - 1]),
            )
            obs, act, rew = (torch.from_numpy(x[j]) for x in (b.obs, b.act, b.rew))
            loss = self.model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew)
            self.model_opt.zero_grad(set_to_none=True)
            loss.backward()
            self.model_opt.step()
            total += float(loss.detach())
        return total / steps

    def sample_batches(
        self, n_updates: int, beta: float
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n_updates`` RL batches at once, each ``batch_interactions x batch_steps``
        transitions (one vectorised gather instead of Python work per update)."""
        b, h = self.buffer, self.horizon
        m, k = self.cfg.sac.batch_interactions, self.cfg.sac.batch_steps
        j = self.rng.integers(0, b.n, (n_updates, m))  # [U, M]
        if self.hooks["rl_interactions"]:
            j = addon_checks.redrawn(self.hooks["rl_interactions"], "rl_interactions", j, 0, b.n)
        t = self.rng.integers(0, h, (n_updates, m, k))  # [U, M, K]
        j = np.broadcast_to(j[..., None], t.shape)
        last = t == h - 1
        s = b.obs[j, t]
        s2 = np.where(last[..., None], b.next_first[j], b.obs[j, np.minimum(t + 1, h)])
        r = b.rew[j, t] * (1.0 - beta)
        if beta > 0.0:
            r = r + beta * self._stability_rewards(j, t, last, s2)
        x, x2 = s, s2
        if self.n_latents >= 1:
            zpad = np.concatenate([np.zeros((1, self.zdim), np.float32), self.Z])
            z_prev, z_cur, z_next = zpad[j], zpad[j + 1], zpad[j + 2]  # z^{j-1}, z^j, z^{j+1}
            z_acted, z2_acted = z_cur, z_cur
            for addon in self.hooks["batch_latents"]:
                given = addon.batch_latents(j, t, z_cur)
                if given is not None:
                    z_acted, z2_acted = addon_checks.latent_pair(addon, given, z_cur.shape)
            lz = last[..., None]
            pair = self.n_latents == 2
            x = np.concatenate([s, z_acted] + ([z_prev] if pair else []), -1)
            z2_cur, z2_prev = np.where(lz, z_next, z2_acted), np.where(lz, z_cur, z_prev)
            x2 = np.concatenate([s2, z2_cur] + ([z2_prev] if pair else []), -1)
        shape = (n_updates, m * k)
        return (
            torch.from_numpy(np.ascontiguousarray(x, np.float32).reshape(*shape, -1)),
            torch.from_numpy(np.ascontiguousarray(b.act[j, t]).reshape(*shape, -1)),
            torch.from_numpy(np.ascontiguousarray(r, np.float32).reshape(shape)),
            torch.from_numpy(np.ascontiguousarray(x2, np.float32).reshape(*shape, -1)),
        )

    def _stability_rewards(
        self, j: np.ndarray, t: np.ndarray, last: np.ndarray, s2: np.ndarray
    ) -> np.ndarray:
        """The stability (or SMiRL) term of each sampled transition, before weighting by b."""
        if self.cfg.method == "smirl":
            return self.buffer.aux[j, t]
        if self.cfg.latent == "partial":
            return stability.partial_reward(s2)
        if self.cfg.sili.credit == "per_step":  # -d(z^{j-1}, z^j) on every step of j
            return -np.where(j >= 1, self.change_after(np.maximum(j - 1, 0)), 0.0)
        return -self.stability_scale * self.change_after(j) * last  # -d(z^j, z^{j+1}), j's last

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        state = {
            "sac": self.sac.state_dict(),
            "buffer": self.buffer.state_dict(),
            "latents": self.latents.state_dict(),
            "smirl": self.smirl.state_dict(),
            "rng": self.rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
            "update_credit": self._update_credit,
            "addons": {a.name: a.state_dict() for a in self.addons},
        }
        if self.model is not None:
            state["model"] = self.model.state_dict()
            state["model_opt"] = self.model_opt.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Load ``state_dict``'s output; CheckpointMismatch when it is another agent's."""
        try:
            self._load_learned(state)
        except (RuntimeError, ValueError, KeyError, IndexError, TypeError) as err:
            lines = [line.strip() for line in str(err).splitlines() if line.strip()] or [repr(err)]
            raise CheckpointMismatch(
                f"it is another agent's state ({' '.join(lines[:2])})"
            ) from None
        saved = state.get("addons", {})
        addon_checks.load_states(self.addons, saved)  # their own: errors there are no mismatch
        self.begin_interaction()

    def _load_learned(self, state: dict[str, Any]) -> None:
        """The networks, optimisers, replay and random states (what a mismatch breaks)."""
        self.sac.load_state_dict(state["sac"])
        self.buffer.load_state_dict(state["buffer"])
        self.latents.load_state_dict(state["latents"])
        self.smirl.load_state_dict(state["smirl"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        self._update_credit = float(state["update_credit"])
        if self.model is not None:
            self.model.load_state_dict(state["model"])
            self.model_opt.load_state_dict(state["model_opt"])
            for group in self.model_opt.param_groups:  # saved before it was set: the same steps
                group["foreach"] = True
