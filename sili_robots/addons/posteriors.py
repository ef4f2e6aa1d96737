"""Hindsight posteriors of the strategy in effect during each interaction (discrete latents).

P[j] is the posterior over the categories in use (uniform prior) of the strategy in effect
during stored interaction j, from how well each decoder head predicts it. An interaction that
tells the strategies apart gives a one-hot posterior; one that does not (every head predicts it
alike, e.g. standing still at the start) gives a flat one, so "the strategy stayed" cannot be
claimed by playing uninformatively. Targets are in units of their standard deviation over the
whole replay (a deliberately broad noise model: only consistent differences over many steps
make the posterior sharp). Two uses, each switched on by its setting:

- ``addons.stability_distance``: ``posterior``: R_stable = -(1 - P[j, argmax z^{j+1}]),
  against the encoder's prediction; ``hindsight``: -(1 - sum_k P[j, k] P[j+1, k]), the
  strategies in effect during j and j+1 (the newest interaction, whose successor is not played
  yet, uses the prediction).
- ``addons.change_fraction`` F: draw the fraction F of each latent-model batch from the pairs
  (j-1, j) across which the strategy changed (both posteriors at least 0.5 on their category).
  Once the opponent is held, changes are rare in the replay, so uniform pairs teach the encoder
  little about where in an interaction a change is decided.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from sili_robots.addons.config import check_learned_latents
from sili_robots.agent.addon import AgentAddon
from sili_robots.agent.latent_cache import in_chunks, replay_target_scale


class HindsightPosteriors(AgentAddon):
    name = "posteriors"

    def __init__(self, distance: str = "latents", change_fraction: float = 0.0) -> None:
        self.distance, self.change_fraction = distance, change_fraction
        self.P = np.zeros((0, 0), np.float32)

    def attach(self, agent: Any) -> None:
        check_learned_latents(self.name, agent.cfg, discrete=True)
        super().attach(agent)
        self.P = np.zeros((0, agent.zdim), np.float32)
        #: LILI has no stability reward to replace (nor a column of it: build_addons leaves
        #: the add-on out there unless change_fraction draws batches)
        self.replaces_distance = self.distance != "latents" and agent.cfg.method != "lili"

    def interaction_stored(self, j: int) -> dict[str, float]:
        if len(self.P) == j:  # else the next refresh fills P
            self.P = np.concatenate([self.P, self.posteriors(np.array([j]))])
        return {}

    def latents_refreshed(self) -> None:
        scale = replay_target_scale(self.agent.buffer)
        n, zdim = self.agent.buffer.n, self.agent.zdim
        self.P = in_chunks(lambda idx: self.posteriors(idx, scale), n, zdim)

    @torch.no_grad()
    def posteriors(self, idx: np.ndarray, scale: torch.Tensor | None = None) -> np.ndarray:
        """[len(idx), k]: P of stored interactions ``idx`` (module docstring)."""
        agent, b = self.agent, self.agent.buffer
        in_use = np.unique(agent.Z[1 : b.n + 1].argmax(-1))
        obs, act, rew = (torch.from_numpy(x[idx]) for x in (b.obs, b.act, b.rew))
        if scale is None:
            scale = replay_target_scale(b)
        loglik = agent.model.step_log_likelihoods(obs[:, :-1], act, obs[:, 1:], rew, scale)
        loglik = loglik.sum(1).numpy()  # log p(tau | k) of each interaction
        post = np.zeros((len(idx), agent.zdim), np.float32)
        ll = loglik[:, in_use]
        ll = np.exp(ll - ll.max(-1, keepdims=True))
        post[:, in_use] = ll / ll.sum(-1, keepdims=True)
        return post

    def stability_distance(self, j: np.ndarray) -> np.ndarray | None:
        """The probability that the strategy changed after each interaction j."""
        if not self.replaces_distance:
            return None
        Z, P = self.agent.Z, self.P
        predicted = np.take_along_axis(P[j], Z[j + 1].argmax(-1)[..., None], axis=-1)[..., 0]
        if self.distance == "posterior":
            return 1.0 - predicted
        n = len(P)
        same = (P[j] * P[np.minimum(j + 1, n - 1)]).sum(-1)
        return 1.0 - np.where(j + 1 < n, same, predicted)

    def change_pairs(self, confidence: float = 0.5) -> np.ndarray:
        """Interactions j whose strategy differs from j-1's by the posteriors, where both are
        sure (max >= ``confidence``): an interaction that does not tell the strategies apart
        says nothing about a change."""
        n = min(len(self.P), self.agent.buffer.n)
        if n < 2:
            return np.zeros(0, int)
        category, sure = self.P[:n].argmax(-1), self.P[:n].max(-1) >= confidence
        changed = (category[1:] != category[:-1]) & sure[1:] & sure[:-1]
        return np.flatnonzero(changed) + 1

    def latent_pairs(self, j: np.ndarray) -> np.ndarray:
        m = round(len(j) * self.change_fraction)
        if m:
            changes = self.change_pairs()
            if len(changes):
                j[:m] = self.agent.rng.choice(changes, m)
        return j

    def state_dict(self) -> dict[str, Any]:
        return {"P": self.P.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.P = np.asarray(state.get("P", np.zeros((0, self.agent.zdim))), np.float32)
        if len(self.P) != self.agent.buffer.n:  # saved without the add-on: P of every one
            self.latents_refreshed()
