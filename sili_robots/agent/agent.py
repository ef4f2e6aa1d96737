"""The SILI agent: SAC + latent strategy model + stability reward, configured into every method.

How the learning signal crosses interactions (the paper's Eq. 1 made concrete):

* Latents. z^j = E(tau^{j-1}) is computed once when interaction j begins and kept in a cache
  ``Z`` (Z[0] is the all-zero "no history yet" latent). The cache is recomputed with the current
  encoder every ``latent_refresh_every`` interactions, so RL batches use up-to-date latents
  without running the encoder inside every gradient step.
* Bootstrapping. The transition from the last step of interaction j goes to the *first
  observation of interaction j+1*, paired with that interaction's latents: the critic's target
  at the boundary is Q(s^{j+1}_0, z^{j+1}, z^j, .) rather than a terminal value. The repeated
  game never terminates, so every target bootstraps.
* Stability credit. The change z^j -> z^{j+1} is caused by what the ego did in interaction j, so
  its stability reward, stability_scale * -d(z^j, z^{j+1}) (stability_scale defaults to H: the
  paper's per-step R_stable summed over an interaction), is paid on the last step of
  interaction j, the step whose successor lies in interaction j+1. Reward on each step:
  (1 - b) R_task + b [t = H-1] stability_scale R_stable.
* ``stability_distance`` "posterior" / "hindsight" (discrete latents) replace d(z^j, z^{j+1}) by
  a probability of change computed from the decoder heads' posterior of the strategy in effect
  during an interaction (``_posteriors``, ``_posterior_distance``); same credit, same step.
* Partial observations: R_stable on each step is -flag(s_{t+1}), the observed "strategy changed"
  flag of the next observation (at the boundary: of interaction j+1's first observation).
* ``latent_filter``: within interaction j the policy acts on the filtered latent at each step
  (the encoder's z^j as prior, corrected by the decoder's likelihood of the steps played so
  far): a category for discrete latents, for continuous ones the encoder's z^j or one of the
  candidate latents ``filter_candidates`` (medoids of the cached latents). It is kept per step
  in ``ZF`` (-1: the encoder's z^j); RL batches put ZF[j, t] in the z^j slot and ZF[j, t+1] in
  the successor's (at the boundary the successor's latent is the encoder's z^{j+1}, which no
  step of j+1 has corrected yet). z^{j-1} and the stability reward stay the encoder's.
* ``latent="true"`` (diagnostic): z^j is the true strategy's encoding and d is 1 when the true
  strategy changed, which isolates influence learning from representation learning.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from sili_robots.agent.buffer import InteractionBuffer
from sili_robots.agent.config import AgentConfig
from sili_robots.agent.latent import LatentModel, category_groups, target_scale, transitions
from sili_robots.agent.latent_filter import (
    FILTER_CANDIDATES,
    continuous_residual_scale,
    continuous_step_logliks,
    filtered_categories,
    first_departure,
    log_prior,
    medoid_candidates,
    option_log_prior,
    residual_scale,
    step_logliks,
    target_norm,
)
from sili_robots.agent.sac import SAC
from sili_robots.agent.smirl import RunningGaussian

REFRESH_CHUNK = 512  # interactions per batch when recomputing latents over the replay


def largest_power_of_two(n: int) -> int:
    """The largest power of two <= n (n >= 1)."""
    return 1 << (n.bit_length() - 1)


def padded_size(m: int) -> int:
    """A batch of ``m`` rows runs as the next power of two up to 64, else the next multiple of
    64: at most 14 shapes for chunks of up to 512, and at most 63 extra rows."""
    return 1 << max(m - 1, 0).bit_length() if m <= 64 else -(-m // 64) * 64


def pad_rows(idx: np.ndarray) -> np.ndarray:
    """``idx`` with its last entry repeated up to ``padded_size`` entries."""
    return np.pad(idx, (0, padded_size(len(idx)) - len(idx)), mode="edge")


@dataclass
class InteractionStats:
    """What the agent saw of one finished interaction."""

    stability_reward: float  # R_stable as the agent measured it (before weighting by b)
    latent_category: int  # argmax of z^{j+1} (-1 when there is no discrete latent)
    latent_changed: bool  # the agent's own latent changed between j and j+1
    #: ``latent_filter``: the first step at which the policy acted on another latent than the
    #: one it started the interaction on (-1: never, or no filter)
    filter_step: int = -1


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
        latent_refresh_every: int = 10,
    ) -> None:
        self.cfg = cfg.validate()
        self.obs_dim, self.act_dim, self.horizon = obs_dim, act_dim, horizon
        self.rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        self.latent_refresh_every = latent_refresh_every
        self.zdim = strategy_dim if cfg.latent == "true" else cfg.latent_dim
        self.n_latents = cfg.policy_latents
        self.in_dim = obs_dim + self.n_latents * self.zdim
        self.sac = SAC(
            self.in_dim,
            act_dim,
            cfg.hidden,
            cfg.lr_at(0),
            cfg.gamma_at(0),
            cfg.tau,
            cfg.precision,
            cfg.target_entropy_at(0, act_dim),
            cfg.matmul,
        )
        self.model: LatentModel | None = None
        if cfg.uses_latent_model:
            self.model = LatentModel(
                obs_dim,
                act_dim,
                cfg.latent_dim,
                cfg.hidden,
                cfg.latent,
                cfg.latent_estimator,
                cfg.latent_usage_bonus,
                preact_penalty=cfg.latent_preact_penalty,
                last_step=cfg.latent_last_step,
                matmul=cfg.matmul,
            )
            self.model_opt = torch.optim.Adam(self.model.parameters(), lr=cfg.latent_lr)
        self.buffer = InteractionBuffer(obs_dim, act_dim, horizon, strategy_dim)
        self.Z = np.zeros((1, self.zdim), np.float32)  # Z[j] = z^j; Z[0] = no history
        self.smirl = RunningGaussian(obs_dim, cfg.smirl_std_floor)
        self.stability_scale = float(cfg.stability_scale or horizon)
        self._update_credit = 0.0
        self.relabels = 0  # how often refresh_latents renamed categories (diagnostics)
        #: discrete latents: category -> the category standing for its behaviour group
        self.category_map = np.arange(self.zdim)
        #: stability_distance "posterior" / "hindsight": P[j] = posterior over categories of the
        #: strategy in effect during stored interaction j
        self.P = np.zeros((0, self.zdim), np.float32)
        self.uses_posterior = (
            self.model is not None
            and cfg.latent == "discrete"
            and cfg.stability_distance != "latents"
            and cfg.method != "lili"
        )
        #: P is also what tells ``change_pairs`` where the strategy changed
        self.keeps_posteriors = self.uses_posterior or (
            self.model is not None and cfg.latent == "discrete" and cfg.latent_change_fraction > 0
        )
        #: the within-interaction filter (``latent_filter``): ZF[j, t] is the category (discrete)
        #: or the index into ``filter_candidates`` (continuous) the policy acted on at step t of
        #: stored interaction j (-1: the encoder's z^j stands, as before the filter runs); it
        #: starts running at the first latent refresh from ``latent_filter_start`` on
        self.ZF = np.zeros((0, horizon + 1), np.int16)
        self.filter_scale: torch.Tensor | None = None
        self.filter_in_use = np.zeros(0, int)
        self.filter_candidates = np.zeros((0, self.zdim), np.float32)
        self.filter_norm: tuple[torch.Tensor, torch.Tensor] | None = None  # continuous decoder
        #: the interaction being played: log prior (None before the filter runs), evidence so
        #: far, the category acted on before each step, and (continuous) its options' latents
        self._live_options: torch.Tensor | None = None
        self._live_logp: np.ndarray | None = None
        self._live_ll = np.zeros(self.zdim)
        self._live_cats: list[int] = []
        self._reset_live()

    @property
    def filtering(self) -> bool:
        """Whether the within-interaction filter is configured (``latent_filter`` > 0)."""
        return self.model is not None and self.cfg.latent_filter > 0

    @property
    def continuous_filter(self) -> bool:
        return self.filtering and self.cfg.latent == "continuous"

    # ------------------------------------------------------------------ acting
    def policy_input(self, obs: np.ndarray, j: int | None = None) -> np.ndarray:
        """[s, z^j, z^{j-1}] (SILI), [s, z^j] (LILI) or s, for the interaction being played."""
        live = j is None
        j = self.buffer.n if j is None else j
        parts = [np.asarray(obs, np.float32)]
        if self.n_latents >= 1:
            parts.append(self._live_latent() if live and self.filtering else self.Z[j])
        if self.n_latents == 2:
            parts.append(self.Z[j - 1] if j >= 1 else np.zeros(self.zdim, np.float32))
        return np.concatenate(parts)

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        x = torch.from_numpy(self.policy_input(obs)).unsqueeze(0)
        return self.sac.act(x, deterministic)[0].numpy()

    def _live_latent(self) -> np.ndarray:
        """z^j as the filter has it after the steps of the current interaction played so far."""
        c = self._live_cats[-1]
        if c < 0:
            return self.Z[self.buffer.n]
        if self.continuous_filter:
            return self.filter_candidates[c]
        return np.eye(self.zdim, dtype=np.float32)[c]

    def _live_category(self) -> int:
        if self._live_logp is None:
            return -1
        best = int((self._live_logp + self._live_ll).argmax())
        return best - 1 if self.continuous_filter else best  # option 0: the encoder's z^j

    def _filter_options(self, idx: np.ndarray) -> torch.Tensor:
        """[N, 1 + C, d] (continuous filter): each interaction's z^j, then the candidates."""
        cands = np.broadcast_to(self.filter_candidates, (len(idx), *self.filter_candidates.shape))
        return torch.from_numpy(np.concatenate([self.Z[idx][:, None], cands], 1))

    def _reset_live(self) -> None:
        """A new interaction: no evidence yet, the filter starts from the encoder's z^j."""
        if not self.filtering:
            return
        self._live_ll = np.zeros(self.zdim)
        self._live_logp = None
        if self.filter_scale is not None and self.continuous_filter:
            self._live_options = self._filter_options(np.array([self.buffer.n]))
            self._live_ll = np.zeros(self._live_options.shape[1])
            self._live_logp = option_log_prior(len(self.filter_candidates), self.cfg.latent_filter)
        elif self.filter_scale is not None:
            z = self.Z[self.buffer.n][None]
            self._live_logp = log_prior(z, self.filter_in_use, self.cfg.latent_filter)[0]
        self._live_cats = [self._live_category()]

    def observe_step(
        self, obs: np.ndarray, act: np.ndarray, rew: float, next_obs: np.ndarray
    ) -> None:
        """One step of the interaction being played: evidence for the filter (no-op without)."""
        if not self.filtering:
            return
        if self._live_logp is not None:
            o, a, o2 = (
                torch.from_numpy(np.asarray(x, np.float32)[None]) for x in (obs, act, next_obs)
            )
            r = torch.tensor([float(rew)], dtype=torch.float32)
            if self.continuous_filter:
                o, a, o2, r = (x[None] for x in (o, a, o2, r))  # one interaction of one step
                self._live_ll += continuous_step_logliks(
                    self.model, o, a, o2, r, self._live_options, self.filter_scale, self.filter_norm
                )[0, 0]
            else:
                self._live_ll += step_logliks(self.model, o, a, o2, r, self.filter_scale)[0]
        self._live_cats.append(self._live_category())

    def random_action(self) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, self.act_dim).astype(np.float32)

    def begin_game(self, info: dict[str, Any]) -> None:
        """A (re)started repeated game: z^0 is "no history"; the true mode knows z^0 already."""
        if self.cfg.latent == "true" and self.buffer.n == 0:
            self.Z[0] = info["strategy"]

    # ------------------------------------------------------------------ data
    def observe_interaction(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        next_first: np.ndarray,
        strategy_id: float,
        strategy: np.ndarray,
        next_info: dict[str, Any],
        refresh: bool = True,
    ) -> InteractionStats:
        """Store interaction j (obs [H+1, o], act [H, a], rew [H]) and infer z^{j+1}."""
        aux = np.zeros(self.horizon, np.float32)
        if self.cfg.method == "smirl":
            aux = self.smirl.log_likelihood(obs[1:]).astype(np.float32)
            self.smirl.update(obs[1:])
        j = self.buffer.add(obs, act, rew, aux, next_first, strategy_id, strategy)
        filter_step = -1
        z_next = self._infer_next_latent(j, next_info)
        self.Z = np.concatenate([self.Z, z_next[None]])
        if self.keeps_posteriors and len(self.P) == j:  # else the next refresh fills P
            self.P = np.concatenate([self.P, self._posteriors(np.array([j]))])
        if self.filtering:
            cats = self._live_cats
            if len(cats) != self.horizon + 1:  # not played through observe_step: replay it
                cats = self._filter_rows(np.array([j]))[0]
            self.ZF = np.concatenate([self.ZF, np.asarray(cats, np.int16)[None]])
            filter_step = first_departure(self.ZF[j])  # as acted, before a refresh
        if refresh and self.model is not None and (j + 1) % self.latent_refresh_every == 0:
            self.refresh_latents()
        self._reset_live()
        stats = self._stats(j, next_first)
        stats.filter_step = filter_step
        return stats

    @torch.no_grad()
    def _filter_rows(self, idx: np.ndarray) -> np.ndarray:
        """[len(idx), H+1] filtered categories of stored interactions (-1 before the filter
        runs), with the current model and the latents cached in Z."""
        if self.filter_scale is None:
            return np.full((len(idx), self.horizon + 1), -1, np.int16)
        b = self.buffer
        obs, act, rew = (torch.from_numpy(x[idx]) for x in (b.obs, b.act, b.rew))
        prev, nxt = obs[:, :-1], obs[:, 1:]
        if self.continuous_filter:
            opts = self._filter_options(idx)
            scale, norm = self.filter_scale, self.filter_norm
            ll = continuous_step_logliks(self.model, prev, act, nxt, rew, opts, scale, norm)
            logp = option_log_prior(len(self.filter_candidates), self.cfg.latent_filter)
            logp = np.broadcast_to(logp, (len(idx), len(logp)))
            return (filtered_categories(logp, ll) - 1).astype(np.int16)
        ll = step_logliks(self.model, prev, act, nxt, rew, self.filter_scale)
        logp = log_prior(self.Z[idx], self.filter_in_use, self.cfg.latent_filter)
        return filtered_categories(logp, ll).astype(np.int16)

    def _refresh_filter(self) -> None:
        """The candidates and the noise scale (``latent_filter_noise`` times the targets' std,
        or the decoder's residual on the newest interactions), then every ZF row."""
        b = self.buffer
        n = b.n
        recent = np.arange(n - min(REFRESH_CHUNK, largest_power_of_two(n)), n)  # few shapes
        obs, act, rew = (torch.from_numpy(x[recent]) for x in (b.obs, b.act, b.rew))
        noise = self.cfg.latent_filter_noise
        if self.continuous_filter:
            self.filter_candidates = medoid_candidates(self.Z[1 : n + 1], FILTER_CANDIDATES, n)
            self.filter_norm = target_norm(torch.from_numpy(b.obs[:n]), torch.from_numpy(b.rew[:n]))
            cands, norm = torch.from_numpy(self.filter_candidates), self.filter_norm
            if noise > 0:
                self.filter_scale = noise * norm[1]
            else:
                self.filter_scale = continuous_residual_scale(
                    self.model, obs, act, rew, cands, norm
                )
        else:
            self.filter_in_use = np.unique(self.Z[1 : n + 1].argmax(-1))
            if noise > 0:
                self.filter_scale = noise * self._replay_target_scale()
            else:
                self.filter_scale = residual_scale(self.model, obs, act, rew, self.filter_in_use)
        self.ZF = self._in_chunks(self._filter_rows, n)

    def _infer_next_latent(self, j: int, next_info: dict[str, Any]) -> np.ndarray:
        if self.cfg.latent == "true":
            return np.asarray(next_info["strategy"], np.float32)
        if self.model is None:
            return np.zeros(self.zdim, np.float32)
        return self._encode(np.array([j]))[0]

    @torch.no_grad()
    def _encode(self, idx: np.ndarray) -> np.ndarray:
        """z^{j+1} = E(tau^j) for each j in ``idx``, deterministic."""
        b = self.buffer
        traj = transitions(
            torch.from_numpy(b.obs[idx]), torch.from_numpy(b.act[idx]), torch.from_numpy(b.rew[idx])
        )
        return self._grouped(self.model.encode(traj).numpy())

    def _grouped(self, z: np.ndarray) -> np.ndarray:
        """Discrete latents: each category replaced by its behaviour group's category."""
        if self.cfg.latent != "discrete":
            return z
        return np.eye(self.zdim, dtype=np.float32)[self.category_map[z.argmax(-1)]]

    def refresh_latents(self) -> None:
        """Recompute every cached latent with the current encoder.

        Discrete categories whose decoder heads predict the same behaviour are first mapped to
        one category (``latent_merge_threshold``, see ``category_groups``), then renamed to agree
        as much as possible with the cached ones (a maximum matching on the old-by-new confusion
        matrix): training may shuffle which category stands for which strategy, and the policy
        should not have to relearn that.
        """
        n = self.buffer.n
        discrete = self.cfg.latent == "discrete" and n > 0
        if discrete:
            self.category_map = np.arange(self.zdim)  # encode raw categories first
        new = self._encode_all(n)
        if discrete:
            if self.cfg.latent_merge_threshold > 0:
                self.category_map = self._behaviour_groups(new.argmax(-1))
                new = self._grouped(new)
            old_c, new_c = self.Z[1 : n + 1].argmax(-1), new.argmax(-1)
            k = self.zdim
            confusion = np.zeros((k, k))
            np.add.at(confusion, (old_c, new_c), 1.0)
            rows, cols = linear_sum_assignment(-confusion)
            perm = np.empty(k, int)
            perm[rows] = cols  # new name i <- old model category perm[i]
            if not np.array_equal(perm, np.arange(k)):
                self.model.relabel(torch.from_numpy(perm))
                inverse = np.argsort(perm)
                self.category_map = inverse[self.category_map[perm]]
                new = new[:, perm]
                self.relabels += 1
        self.Z = np.concatenate([self.Z[:1], new])
        if self.keeps_posteriors:
            scale = self._replay_target_scale()
            self.P = self._in_chunks(lambda idx: self._posteriors(idx, scale), n)
        if self.filtering and n > 0 and n >= self.cfg.latent_filter_start:
            self._refresh_filter()

    def _replay_target_scale(self) -> torch.Tensor:
        """Per-output standard deviation of the decoder's targets over the whole replay."""
        b = self.buffer
        obs = torch.from_numpy(b.obs[: b.n])
        return target_scale(obs[:, :-1], obs[:, 1:], torch.from_numpy(b.rew[: b.n]))

    @torch.no_grad()
    def _posteriors(self, idx: np.ndarray, scale: torch.Tensor | None = None) -> np.ndarray:
        """Posterior over the categories in use (uniform prior) of the strategy in effect during
        each stored interaction in ``idx``, from how well each decoder head predicts it.

        An interaction that tells the strategies apart gives a one-hot posterior; one that does
        not (every head predicts it alike, e.g. standing still at the start) gives a flat one,
        so "the strategy stayed" cannot be claimed by playing uninformatively. Targets are in
        units of their standard deviation over the whole replay (a deliberately broad noise
        model: only consistent differences over many steps make the posterior sharp).
        """
        b = self.buffer
        in_use = np.unique(self.Z[1 : b.n + 1].argmax(-1))
        obs, act, rew = (torch.from_numpy(x[idx]) for x in (b.obs, b.act, b.rew))
        if scale is None:
            scale = self._replay_target_scale()
        loglik = self.model.step_log_likelihoods(obs[:, :-1], act, obs[:, 1:], rew, scale)
        loglik = loglik.sum(1).numpy()  # log p(tau | k) of each interaction
        post = np.zeros((len(idx), self.zdim), np.float32)
        ll = loglik[:, in_use]
        ll = np.exp(ll - ll.max(-1, keepdims=True))
        post[:, in_use] = ll / ll.sum(-1, keepdims=True)
        return post

    def _behaviour_groups(self, categories: np.ndarray, reference: int = 64) -> np.ndarray:
        """category -> group leader, from the decoder heads' predictions on up to ``reference``
        stored interactions (unused categories map to themselves)."""
        b = self.buffer
        idx = self.rng.choice(b.n, min(reference, b.n), replace=False)
        obs, act, rew = (torch.from_numpy(x[idx]) for x in (b.obs, b.act, b.rew))
        scale = target_scale(obs[:, :-1], obs[:, 1:], rew)
        distances = self.model.head_distances(obs[:, :-1], act, scale)
        counts = np.bincount(categories, minlength=self.zdim)
        used = [int(c) for c in np.argsort(-counts, kind="stable") if counts[c] > 0]
        groups = category_groups(distances, used, self.cfg.latent_merge_threshold)
        mapping = np.arange(self.zdim)
        for c, leader in groups.items():
            mapping[c] = leader
        return mapping

    def _encode_all(self, n: int) -> np.ndarray:
        return self._in_chunks(self._encode, n)

    def _in_chunks(self, fn: Callable[[np.ndarray], np.ndarray], n: int) -> np.ndarray:
        """``fn`` over stored interactions 0..n-1 in chunks of ``REFRESH_CHUNK``, rows
        concatenated. Each chunk is padded (``pad_rows``; the extra rows dropped), so a run's
        refreshes use at most 14 batch shapes: every new shape leaves memory behind (oneDNN's
        kernels for it and the allocator's fragments), and a new last chunk at each refresh grew
        a run by gigabytes."""
        parts = [np.zeros((0, self.zdim), np.float32)] if n == 0 else []
        for start in range(0, n, REFRESH_CHUNK):
            idx = np.arange(start, min(start + REFRESH_CHUNK, n))
            parts.append(fn(pad_rows(idx))[: len(idx)])
        return np.concatenate(parts)

    def _stats(self, j: int, next_first: np.ndarray) -> InteractionStats:
        if self.cfg.latent == "partial":
            flags = np.concatenate([self.buffer.obs[j, 1:, -1], next_first[-1:]])
            return InteractionStats(-float(flags.sum()), -1, bool(flags.any()))
        if self.uses_posterior:
            d = float(self._posterior_distance(np.array([j]))[0])
            changed = j > 0 and bool(self.Z[j].argmax() != self.Z[j + 1].argmax())
        else:
            d = float(self._distance(self.Z[j : j + 1], self.Z[j + 1 : j + 2])[0])
            if self.cfg.latent != "true" and j == 0:
                d = 0.0  # z^0 is "no history", not a strategy
            changed = d > 0
        category = (
            int(self.Z[j + 1].argmax())
            if self.model is not None and self.cfg.latent == "discrete"
            else -1
        )
        return InteractionStats(-d, category, changed)

    def _posterior_distance(self, j: np.ndarray) -> np.ndarray:
        """Per entry of ``j``, the probability that the strategy changed after interaction j.

        ``posterior``: 1 - P[j, argmax z^{j+1}], the strategy in effect during j against the
        encoder's prediction for j+1. ``hindsight``: 1 - sum_k P[j, k] P[j+1, k], the strategies
        in effect during j and j+1 (for the newest interaction, whose successor is not played
        yet, the prediction stands in for P[j+1])."""
        predicted = np.take_along_axis(self.P[j], self.Z[j + 1].argmax(-1)[..., None], axis=-1)
        if self.cfg.stability_distance == "posterior":
            return 1.0 - predicted[..., 0]
        n = len(self.P)
        same = (self.P[j] * self.P[np.minimum(j + 1, n - 1)]).sum(-1)
        return 1.0 - np.where(j + 1 < n, same, predicted[..., 0])

    def _distance(self, za: np.ndarray, zb: np.ndarray) -> np.ndarray:
        """d(z, z') per row: discrete 0/1 on the category, continuous Euclidean."""
        if self.cfg.latent == "discrete":
            return (za.argmax(-1) != zb.argmax(-1)).astype(np.float32)
        if self.cfg.latent == "true":
            return (np.abs(za - zb).max(-1) > 1e-6).astype(np.float32)
        return np.linalg.norm(za - zb, axis=-1).astype(np.float32)

    # ------------------------------------------------------------------ learning
    def update(self, interaction: int, rl: bool = True) -> dict[str, float]:
        """Learning after an interaction: latent model, then (with ``rl``) H * updates_per_step
        SAC steps. The latent model also learns during the random warm-up, whose diverse
        trajectories are the most informative about the opponent."""
        losses: dict[str, float] = {}
        if self.model is not None and self.buffer.n >= 2:
            losses["latent_loss"] = self.update_latent_model(
                self.cfg.latent_updates_per_interaction
            )
        if not rl:
            return losses
        self._update_credit += self.horizon * self.cfg.updates_per_step
        n_updates = int(self._update_credit)
        self._update_credit -= n_updates
        if n_updates and self.buffer.n >= 1:
            beta = self.cfg.beta_at(interaction)
            self.sac.target_entropy = self.cfg.target_entropy_at(interaction, self.act_dim)
            self.sac.gamma = self.cfg.gamma_at(interaction)
            self.sac.set_lr(self.cfg.lr_at(interaction))
            x, a, r, x2 = self.sample_batches(n_updates, beta)
            out = [self.sac.update(x[u], a[u], r[u], x2[u]) for u in range(n_updates)]
            losses["critic_loss"] = float(torch.stack([o["critic_loss"] for o in out]).mean())
            losses["actor_loss"] = float(torch.stack([o["actor_loss"] for o in out]).mean())
            losses["alpha"] = self.sac.alpha
        return losses

    def update_latent_model(self, steps: int) -> float:
        """Max-likelihood steps on random consecutive pairs (tau^{j-1}, tau^j)."""
        if steps == 0:
            return float("nan")
        b = self.buffer
        total = 0.0
        changes = self.change_pairs() if self.cfg.latent_change_fraction > 0 else np.zeros(0, int)
        m_changes = round(self.cfg.latent_batch * self.cfg.latent_change_fraction)
        for _ in range(steps):
            j = self.rng.integers(1, b.n, self.cfg.latent_batch)
            if len(changes) and m_changes:
                j[:m_changes] = self.rng.choice(changes, m_changes)
            prev = transitions(
                torch.from_numpy(b.obs[j - 1]),
                torch.from_numpy(b.act[j - 1]),
                torch.from_numpy(b.rew[j - 1]),
            )
            obs = torch.from_numpy(b.obs[j])
            loss = self.model.loss(
                prev,
                obs[:, :-1],
                torch.from_numpy(b.act[j]),
                obs[:, 1:],
                torch.from_numpy(b.rew[j]),
            )
            self.model_opt.zero_grad(set_to_none=True)
            loss.backward()
            self.model_opt.step()
            total += float(loss.detach())
        return total / steps

    def change_pairs(self, confidence: float = 0.5) -> np.ndarray:
        """Interactions j whose strategy differs from j-1's by the decoder's posteriors, where
        both posteriors are sure (max >= ``confidence``): an interaction that does not tell the
        strategies apart says nothing about a change."""
        n = min(len(self.P), self.buffer.n)
        if n < 2:
            return np.zeros(0, int)
        category, sure = self.P[:n].argmax(-1), self.P[:n].max(-1) >= confidence
        changed = (category[1:] != category[:-1]) & sure[1:] & sure[:-1]
        return np.flatnonzero(changed) + 1

    def sample_batches(
        self, n_updates: int, beta: float
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n_updates`` RL batches at once, each ``batch_interactions x batch_steps``
        transitions (one vectorised gather instead of Python work per update)."""
        b, h = self.buffer, self.horizon
        m, k = self.cfg.batch_interactions, self.cfg.batch_steps
        j = self.rng.integers(0, b.n, (n_updates, m))  # [U, M]
        m_recent = round(m * self.cfg.recent_fraction)
        if m_recent:  # part of each batch from the newest interactions (see AgentConfig)
            lo = max(0, b.n - self.cfg.recent_interactions)
            j[:, :m_recent] = self.rng.integers(lo, b.n, (n_updates, m_recent))
        j = j[..., None]  # [U, M, 1]
        t = self.rng.integers(0, h, (n_updates, m, k))  # [U, M, K]
        j = np.broadcast_to(j, t.shape)
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
            lz = last[..., None]
            z_acted, z2_acted = z_cur, z_cur
            if self.filtering:  # the per-step latents the policy acted on (module docstring)
                z_acted = self._filtered(j, t, z_cur)
                z2_acted = self._filtered(j, np.minimum(t + 1, h), z_cur)
            x = np.concatenate([s, z_acted] + ([z_prev] if self.n_latents == 2 else []), -1)
            z2_cur = np.where(lz, z_next, z2_acted)
            z2_prev = np.where(lz, z_cur, z_prev)
            x2 = np.concatenate([s2, z2_cur] + ([z2_prev] if self.n_latents == 2 else []), -1)
        shape = (n_updates, m * k)
        return (
            torch.from_numpy(np.ascontiguousarray(x, np.float32).reshape(*shape, -1)),
            torch.from_numpy(np.ascontiguousarray(b.act[j, t]).reshape(*shape, -1)),
            torch.from_numpy(np.ascontiguousarray(r, np.float32).reshape(shape)),
            torch.from_numpy(np.ascontiguousarray(x2, np.float32).reshape(*shape, -1)),
        )

    def _filtered(self, j: np.ndarray, t: np.ndarray, z_encoder: np.ndarray) -> np.ndarray:
        """The filter's latent at step t of stored interaction j (the encoder's where it was
        not running)."""
        cats = self.ZF[j, t]
        if self.continuous_filter:
            if not len(self.filter_candidates):  # not running yet: every row is the encoder's
                return z_encoder
            chosen = self.filter_candidates[np.maximum(cats, 0)]
        else:
            chosen = np.eye(self.zdim, dtype=np.float32)[np.maximum(cats, 0)]
        return np.where(cats[..., None] >= 0, chosen, z_encoder)

    def _stability_rewards(
        self, j: np.ndarray, t: np.ndarray, last: np.ndarray, s2: np.ndarray
    ) -> np.ndarray:
        """The stability (or SMiRL) term of each sampled transition, before weighting by b."""
        if self.cfg.method == "smirl":
            return self.buffer.aux[j, t]
        if self.cfg.latent == "partial":
            return -s2[..., -1]
        if self.uses_posterior:
            return -self.stability_scale * self._posterior_distance(j) * last
        d = self._distance(self.Z[j], self.Z[j + 1])
        if self.cfg.latent != "true":
            d = np.where(j >= 1, d, 0.0)  # z^0 is "no history", not a strategy
        return -self.stability_scale * d * last

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        state = {
            "sac": self.sac.state_dict(),
            "buffer": self.buffer.state_dict(),
            "Z": self.Z.copy(),
            "smirl": self.smirl.state_dict(),
            "rng": self.rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
            "update_credit": self._update_credit,
            "category_map": self.category_map.copy(),
            "posteriors": self.P.copy(),
            "filter": {
                "ZF": self.ZF.copy(),
                "scale": self.filter_scale,
                "in_use": self.filter_in_use.copy(),
                "candidates": self.filter_candidates.copy(),
                "norm": self.filter_norm,
            },
        }
        if self.model is not None:
            state["model"] = self.model.state_dict()
            state["model_opt"] = self.model_opt.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.sac.load_state_dict(state["sac"])
        self.buffer.load_state_dict(state["buffer"])
        self.Z = np.array(state["Z"], np.float32)
        self.smirl.load_state_dict(state["smirl"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        self._update_credit = float(state["update_credit"])
        self.category_map = np.asarray(state.get("category_map", np.arange(self.zdim)))
        self.P = np.asarray(state.get("posteriors", np.zeros((0, self.zdim))), np.float32)
        if self.model is not None:
            self.model.load_state_dict(state["model"])
            self.model_opt.load_state_dict(state["model_opt"])
        if self.filtering:
            f = state["filter"]
            self.ZF = np.asarray(f["ZF"], np.int16)
            self.filter_scale, self.filter_in_use = f["scale"], np.asarray(f["in_use"], int)
            cands = f.get("candidates", np.zeros((0, self.zdim)))
            self.filter_candidates = np.asarray(cands, np.float32)
            self.filter_norm = f.get("norm")
            if len(self.ZF) != self.buffer.n:  # saved without the filter: start it as a run would
                self._start_filter_late()
        self._reset_live()

    def _start_filter_late(self) -> None:
        """The filter's state for a checkpoint saved without it: what a run with the filter
        would hold at this point (no ZF rows yet before ``latent_filter_start``, else the state
        of a refresh)."""
        n = self.buffer.n
        self.filter_scale = None
        self.ZF = np.full((n, self.horizon + 1), -1, np.int16)
        if n > 0 and n >= self.cfg.latent_filter_start:
            self._refresh_filter()
