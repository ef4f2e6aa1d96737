"""Within-interaction latent filter (``addons.filter``): the policy acts on the posterior of the
strategy given z^j and the steps played so far, instead of the fixed z^j.

Why. z^j = E(tau^{j-1}) is fixed before interaction j begins. When it is wrong (the opponent
moved after an ending the encoder read as a hold) the policy pursues the wrong strategy for the
whole interaction, while the rewards it is receiving already tell the strategies apart after a
step or two. The mathematics (priors, likelihoods, candidates) is in ``filter_math.py``.

At each step the policy acts on the posterior's argmax: a category for discrete latents; for
continuous ones the encoder's z^j or one of the candidate latents (medoids of the cached
latents). Where options tie (a "no history" z^j before any evidence) it keeps the encoder's.
The choice is kept per step in ``ZF`` (-1: the encoder's z^j); RL batches put
ZF[j, t] in the z^j slot and ZF[j, t+1] in the successor's (at the boundary the successor's
latent is the encoder's z^{j+1}, which no step of j+1 has corrected yet). z^{j-1} and the
stability reward stay the encoder's. The filter starts at the first latent refresh from
``start`` on; before it a run is the unfiltered run, row for row.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from sili_robots.addons.config import check_learned_latents
from sili_robots.addons.filter_math import (
    FILTER_CANDIDATES,
    continuous_residual_scale,
    continuous_step_logliks,
    decided,
    filtered_categories,
    first_departure,
    log_prior,
    medoid_candidates,
    option_log_prior,
    residual_scale,
    step_logliks,
    target_norm,
)
from sili_robots.agent.addon import AgentAddon
from sili_robots.agent.latent_cache import REFRESH_CHUNK, in_chunks, replay_target_scale


def largest_power_of_two(n: int) -> int:
    """The largest power of two <= n (n >= 1)."""
    return 1 << (n.bit_length() - 1)


class LatentFilter(AgentAddon):
    name = "latent_filter"
    metric_columns = ("filter_step",)

    def __init__(self, eps: float, start: int = 0, noise: float = 0.0) -> None:
        self.eps, self.start, self.noise = eps, start, noise

    def attach(self, agent: Any) -> None:
        check_learned_latents(self.name, agent.cfg)
        super().attach(agent)
        self.continuous = agent.cfg.latent == "continuous"
        self.horizon, self.zdim = agent.horizon, agent.zdim
        #: ZF[j, t]: category (discrete) or index into ``candidates`` (continuous) acted on at
        #: step t of stored interaction j (-1: the encoder's z^j)
        self.ZF = np.zeros((0, self.horizon + 1), np.int16)
        self.scale: torch.Tensor | None = None  # None until the filter runs
        self.in_use = np.zeros(0, int)
        self.candidates = np.zeros((0, self.zdim), np.float32)
        self.norm: tuple[torch.Tensor, torch.Tensor] | None = None  # continuous decoder
        # the interaction being played: log prior (None before the filter runs), evidence so
        # far, the option acted on before each step, and (continuous) the options' latents
        self._options: torch.Tensor | None = None
        self._logp: np.ndarray | None = None
        self._ll = np.zeros(self.zdim)
        self._cats: list[int] = [-1]

    # ------------------------------------------------------------------ acting
    def begin_interaction(self) -> None:
        """A new interaction: no evidence yet, the filter starts from the encoder's z^j."""
        n = self.agent.buffer.n
        self._ll, self._logp = np.zeros(self.zdim), None
        if self.scale is not None and self.continuous:
            self._options = self._option_latents(np.array([n]))
            self._ll = np.zeros(self._options.shape[1])
            self._logp = option_log_prior(len(self.candidates), self.eps)
        elif self.scale is not None:
            self._logp = log_prior(self.agent.Z[n][None], self.in_use, self.eps)[0]
        self._cats = [self._current()]

    def _current(self) -> int:
        if self._logp is None:
            return -1
        best = int(decided(self._logp + self._ll))
        return max(best - 1, -1) if self.continuous else best  # option 0: the encoder's z^j

    @property
    def acted(self) -> list[int]:
        """The option acted on before each step of the interaction so far (-1: the encoder's)."""
        return list(self._cats)

    def acting_latent(self) -> np.ndarray | None:
        c = self._cats[-1]
        if c < 0:
            return None
        if self.continuous:
            return self.candidates[c]
        return np.eye(self.zdim, dtype=np.float32)[c]

    def observe_step(
        self, obs: np.ndarray, act: np.ndarray, rew: float, next_obs: np.ndarray
    ) -> None:
        if self._logp is not None:
            o, a, o2 = (
                torch.from_numpy(np.asarray(x, np.float32)[None]) for x in (obs, act, next_obs)
            )
            r = torch.tensor([float(rew)], dtype=torch.float32)
            model = self.agent.model
            if self.continuous:
                o, a, o2, r = (x[None] for x in (o, a, o2, r))  # one interaction of one step
                self._ll += continuous_step_logliks(
                    model, o, a, o2, r, self._options, self.scale, self.norm
                )[0, 0]
            else:
                self._ll += step_logliks(model, o, a, o2, r, self.scale)[0]
        self._cats.append(self._current())

    # ------------------------------------------------------------------ stored interactions
    def interaction_stored(self, j: int) -> dict[str, float]:
        cats = self._cats
        if len(cats) != self.horizon + 1:  # not played through observe_step: replay it
            cats = self._rows(np.array([j]))[0]
        self.ZF = np.concatenate([self.ZF, np.asarray(cats, np.int16)[None]])
        return {"filter_step": first_departure(self.ZF[j])}  # as acted, before a refresh

    def latents_refreshed(self) -> None:
        n = self.agent.buffer.n
        if n > 0 and n >= self.start:
            self._refresh()

    def _option_latents(self, idx: np.ndarray) -> torch.Tensor:
        """[N, 1 + C, d] (continuous): each interaction's z^j, then the candidates."""
        cands = np.broadcast_to(self.candidates, (len(idx), *self.candidates.shape))
        return torch.from_numpy(np.concatenate([self.agent.Z[idx][:, None], cands], 1))

    @torch.no_grad()
    def _rows(self, idx: np.ndarray) -> np.ndarray:
        """[len(idx), H+1] filtered choices of stored interactions (-1 before the filter
        runs), with the current model and the cached latents."""
        if self.scale is None:
            return np.full((len(idx), self.horizon + 1), -1, np.int16)
        b, model = self.agent.buffer, self.agent.model
        obs, act, rew = (torch.from_numpy(x[idx]) for x in (b.obs, b.act, b.rew))
        prev, nxt = obs[:, :-1], obs[:, 1:]
        if self.continuous:
            opts = self._option_latents(idx)
            ll = continuous_step_logliks(model, prev, act, nxt, rew, opts, self.scale, self.norm)
            logp = option_log_prior(len(self.candidates), self.eps)
            logp = np.broadcast_to(logp, (len(idx), len(logp)))
            return np.maximum(filtered_categories(logp, ll) - 1, -1).astype(np.int16)
        ll = step_logliks(model, prev, act, nxt, rew, self.scale)
        logp = log_prior(self.agent.Z[idx], self.in_use, self.eps)
        return filtered_categories(logp, ll).astype(np.int16)

    def _refresh(self) -> None:
        """The candidates and the noise scale (``noise`` times the targets' std, or the
        decoder's residual on the newest interactions), then every ZF row."""
        agent, b = self.agent, self.agent.buffer
        n = b.n
        recent = np.arange(n - min(REFRESH_CHUNK, largest_power_of_two(n)), n)  # few shapes
        obs, act, rew = (torch.from_numpy(x[recent]) for x in (b.obs, b.act, b.rew))
        if self.continuous:
            self.candidates = medoid_candidates(agent.Z[1 : n + 1], FILTER_CANDIDATES, n)
            self.norm = target_norm(torch.from_numpy(b.obs[:n]), torch.from_numpy(b.rew[:n]))
            cands = torch.from_numpy(self.candidates)
            if self.noise > 0:
                self.scale = self.noise * self.norm[1]
            else:
                self.scale = continuous_residual_scale(agent.model, obs, act, rew, cands, self.norm)
        else:
            self.in_use = np.unique(agent.Z[1 : n + 1].argmax(-1))
            if self.noise > 0:
                self.scale = self.noise * replay_target_scale(b)
            else:
                self.scale = residual_scale(agent.model, obs, act, rew, self.in_use)
        self.ZF = in_chunks(self._rows, n, self.horizon + 1)

    # ------------------------------------------------------------------ batches
    def _filtered(self, j: np.ndarray, t: np.ndarray, z_encoder: np.ndarray) -> np.ndarray:
        cats = self.ZF[j, t]
        if self.continuous:
            if not len(self.candidates):  # not running yet: every row is the encoder's
                return z_encoder
            chosen = self.candidates[np.maximum(cats, 0)]
        else:
            chosen = np.eye(self.zdim, dtype=np.float32)[np.maximum(cats, 0)]
        return np.where(cats[..., None] >= 0, chosen, z_encoder)

    def batch_latents(
        self, j: np.ndarray, t: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return self._filtered(j, t, z), self._filtered(j, np.minimum(t + 1, self.horizon), z)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {
            "ZF": self.ZF.copy(),
            "scale": self.scale,
            "in_use": self.in_use.copy(),
            "candidates": self.candidates.copy(),
            "norm": self.norm,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        n = self.agent.buffer.n
        self.ZF = np.asarray(state.get("ZF", np.zeros((0, self.horizon + 1))), np.int16)
        self.scale, self.norm = state.get("scale"), state.get("norm")
        self.in_use = np.asarray(state.get("in_use", np.zeros(0)), int)
        self.candidates = np.asarray(state.get("candidates", np.zeros((0, self.zdim))), np.float32)
        if len(self.ZF) != n:  # saved without the filter: start it as a run with it would have
            self.scale = None
            self.ZF = np.full((n, self.horizon + 1), -1, np.int16)
            if n > 0 and n >= self.start:
                self._refresh()
