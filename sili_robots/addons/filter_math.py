"""The latent filter's mathematics: the encoder's z^j as a prior, corrected step by step by how
well the decoder explains the interaction played so far under each alternative.

Why. z^j = E(tau^{j-1}) is fixed before interaction j begins. When it is wrong (the opponent
moved after an ending the encoder read as a hold) the policy pursues the wrong strategy for the
whole interaction, while the rewards it is receiving already tell the strategies apart after a
step or two. Measured on Circle (3 Goals), such an interaction costs -45 to -73 against -8 to
-12, and a policy that cannot afford that keeps a margin at the circle's edge
(benchmarks/RESULTS.md). The filter is the Bayes posterior over the categories in use:

    log p(k | tau^{j-1}, tau^j_{<t}) = log prior_k + sum_{u<t} log N(target_u; D_k(s_u, a_u), sigma)

with prior (1 - eps) on the encoder's category and eps spread over every category in use
(eps = ``latent_filter``), and sigma the decoder's own residual scale per output on recent
interactions (its best head), so an inaccurate decoder corrects little, or, with
``latent_filter_noise`` s > 0, s times the targets' standard deviation. The residual treats the
steps of an interaction as independent evidence, but the decoder's errors within one are
correlated (a small bias over all of its steps), and at that scale such biases add up to a
switch away from a right z^j. Each step's
log-likelihood is floored at ``-LOGLIK_FLOOR`` so one state the decoder never saw cannot decide
alone. The policy acts on the posterior's argmax at step t; the critic learns on the same
per-step latents, recomputed with the current model whenever the encoder's are.

Measured on Circle (3 Goals), 3 seeds x 3,000 interactions (benchmarks/RESULTS.md): learning
starts faster and a wrong z^j is corrected within 2-6 steps, but the final task reward is worse
than without the filter (-11.1 against -7.6): the categories split one strategy over several
heads, and the filter hops between them on noise in outputs every head predicts alike. Off by
default.

Continuous latents have no heads to choose between, so the alternatives are latents the encoder
has produced: the medoids of ``FILTER_CANDIDATES`` k-means clusters of every cached z (one per
strategy seen, and more), each an actual encoder output, so the policy never acts on a latent
off the encoder's range. The options at step t are the encoder's z^j (prior 1 - eps) and the
candidates (eps shared), each scored by the Gaussian likelihood of the steps so far under
D(s, a, z) (in target units: a continuous decoder is trained on standardised targets, see
``target_norm``). A candidate of the strategy z^j already stands for predicts nearly the same,
so with a broad enough noise scale it cannot overturn the prior; where it does win, it is a
latent near z^j, so the policy's input moves little.

Measured on Circle (3 Goals), 3 seeds x 3,000 interactions, continuous latents with eps 0.01,
noise 0.25, from interaction 1,600 (benchmarks/RESULTS.md, arm R): a slip (the opponent moved,
z^j still names the held location) is found at step 2-3 and costs about 12 instead of 83; the
filter left a right z^j in 7 and 1 of ~1,400 interactions on two seeds and 36 on the third
(mostly while its policy was learning to reach a location it had just moved the opponent to);
and the final task reward is within 15% of Oracle's (-5.00 against -4.39).
"""

from __future__ import annotations

import warnings

import numpy as np
import torch
from scipy.cluster.vq import kmeans2

from sili_robots.agent.latent import LatentModel, decoder_targets, target_scale

#: per-step log-likelihood floor (nats): no single transition outweighs this much evidence
LOGLIK_FLOOR = 10.0
#: the residual scale never drops below this fraction of the targets' own standard deviation
SCALE_FLOOR = 1e-2
#: continuous latents: how many encoder latents (k-means medoids) the filter may switch to
FILTER_CANDIDATES = 8


@torch.no_grad()
def step_logliks(
    model: LatentModel,
    obs: torch.Tensor,
    act: torch.Tensor,
    next_obs: torch.Tensor,
    rew: torch.Tensor,
    scale: torch.Tensor,
) -> np.ndarray:
    """[..., k]: each category's Gaussian log-likelihood of each transition's [s' - s, r]
    (``LatentModel.step_log_likelihoods``), floored."""
    ll = model.step_log_likelihoods(obs, act, next_obs, rew, scale)
    return ll.clamp(min=-LOGLIK_FLOOR).numpy()


@torch.no_grad()
def residual_scale(
    model: LatentModel,
    obs: torch.Tensor,
    act: torch.Tensor,
    rew: torch.Tensor,
    in_use: np.ndarray,
) -> torch.Tensor:
    """Per output, the root-mean-square error of the decoder on interactions obs [N, H+1, o]
    (act [N, H, a], rew [N, H]), each under the category in use that explains it best."""
    prev, nxt = obs[:, :-1], obs[:, 1:]
    target = decoder_targets(prev, nxt, rew)
    ref = target_scale(target)
    heads = model._heads(prev, act)[..., torch.from_numpy(in_use), :]  # [N, H, k', out]
    sq = (heads - target.unsqueeze(-2)).pow(2)
    best = (sq / ref.pow(2)).sum(-1).sum(1).argmin(-1)  # [N]
    rows = sq[torch.arange(len(best)), :, best]  # [N, H, out]
    rms = rows.reshape(-1, rows.shape[-1]).mean(0).sqrt()
    return torch.maximum(rms, SCALE_FLOOR * ref)


def log_prior(prior: np.ndarray, in_use: np.ndarray, eps: float) -> np.ndarray:
    """[N, k] log prior from encoder latents ``prior`` [N, k] (an all-zero row: no prediction,
    uniform over ``in_use``); -inf outside the categories in use."""
    n, k = prior.shape
    uniform = np.zeros(k)
    uniform[in_use] = 1.0 / len(in_use)
    p = np.tile(eps * uniform, (n, 1))
    has = prior.any(-1)
    p[has, prior[has].argmax(-1)] += 1.0 - eps
    p[~has] = uniform
    with np.errstate(divide="ignore"):
        return np.log(p)


def decided(log_posterior: np.ndarray) -> np.ndarray:
    """The argmax over the last axis, -1 where the maximum is shared: between tied options
    (a "no history" prior before any evidence) the policy keeps the encoder's latent."""
    best = log_posterior.max(-1, keepdims=True)
    tied = (log_posterior == best).sum(-1) > 1
    return np.where(tied, -1, log_posterior.argmax(-1))


def filtered_categories(logp: np.ndarray, ll: np.ndarray) -> np.ndarray:
    """[N, T+1] int: the posterior's argmax (``decided``) before each of T steps and after the
    last one, from log priors ``logp`` [N, k] and per-step log-likelihoods ``ll`` [N, T, k]."""
    n, _, k = ll.shape
    cum = np.concatenate([np.zeros((n, 1, k)), np.cumsum(ll, axis=1)], axis=1)
    return decided(logp[:, None, :] + cum)


def first_departure(cats: np.ndarray) -> int:
    """The first step at which the latent acted on (``ZF`` row, or the live one) differs from the
    one the interaction started on; -1 if it never does."""
    moved = np.flatnonzero(np.asarray(cats) != cats[0])
    return int(moved[0]) if len(moved) else -1


def medoid_candidates(z: np.ndarray, k: int, seed: int) -> np.ndarray:
    """[<= k, d]: the latent of ``z`` [N, d] nearest to each of k k-means centres (k-means++
    seeded by ``seed``, so a refresh is reproducible), duplicates dropped, in order of first
    occurrence in ``z``."""
    k = min(k, len(np.unique(z, axis=0)))
    with warnings.catch_warnings():  # an empty cluster only means fewer distinct candidates
        warnings.simplefilter("ignore")
        centres, _ = kmeans2(z.astype(np.float64), k, minit="++", seed=np.random.default_rng(seed))
    nearest = ((z[None] - centres[:, None]) ** 2).sum(-1).argmin(-1)
    return z[np.unique(nearest)]


def option_log_prior(n_candidates: int, eps: float) -> np.ndarray:
    """[1 + C]: log prior of the options (the encoder's z^j, then the candidates)."""
    return np.log(np.array([1.0 - eps] + [eps / n_candidates] * n_candidates))


TargetNorm = tuple[torch.Tensor, torch.Tensor]


def target_norm(obs: torch.Tensor, rew: torch.Tensor) -> TargetNorm:
    """Per-output mean and standard deviation of the decoder's targets on interactions
    obs [N, H+1, o] (rew [N, H]): a continuous decoder is trained on targets standardised by
    its batch (``LatentModel.loss``), and batches are drawn uniformly from the replay, so the
    replay's statistics turn its output back into (s' - s, r)."""
    prev, nxt = obs[:, :-1], obs[:, 1:]
    target = decoder_targets(prev, nxt, rew)
    return target.reshape(-1, target.shape[-1]).mean(0), target_scale(target)


def continuous_predictions(
    model: LatentModel, obs: torch.Tensor, act: torch.Tensor, z: torch.Tensor, norm: TargetNorm
) -> torch.Tensor:
    """D(s, a, z) in the units of (s' - s, r)."""
    mean, std = norm
    return model.decode(obs, act, z) * std + mean


@torch.no_grad()
def continuous_step_logliks(
    model: LatentModel,
    obs: torch.Tensor,
    act: torch.Tensor,
    next_obs: torch.Tensor,
    rew: torch.Tensor,
    options: torch.Tensor,
    scale: torch.Tensor,
    norm: TargetNorm,
) -> np.ndarray:
    """[N, T, K]: the Gaussian log-likelihood (targets in units of ``scale``, constants dropped)
    of each transition of obs [N, T, o] under D(s, a, z) for each of the options [N, K, d] (one
    decoder pass per option, so the activations stay the size of one batch), floored."""
    target = decoder_targets(obs, next_obs, rew)
    ll = [
        -0.5
        * (
            ((continuous_predictions(model, obs, act, options[:, i], norm) - target) / scale) ** 2
        ).sum(-1)
        for i in range(options.shape[1])
    ]
    return torch.stack(ll, -1).clamp(min=-LOGLIK_FLOOR).numpy()


@torch.no_grad()
def continuous_residual_scale(
    model: LatentModel,
    obs: torch.Tensor,
    act: torch.Tensor,
    rew: torch.Tensor,
    candidates: torch.Tensor,
    norm: TargetNorm,
) -> torch.Tensor:
    """Per output, the root-mean-square error of D(s, a, z) on interactions obs [N, H+1, o],
    each under the candidate latent [C, d] that explains it best (as ``residual_scale`` takes
    the best head), floored like it. Under its own z^j the decoder fits outputs the strategy
    does not touch (the ego's own motion) far more tightly than under another latent of the
    same strategy; at that scale the filter would leave a right z^j on such noise."""
    prev, nxt = obs[:, :-1], obs[:, 1:]
    target = decoder_targets(prev, nxt, rew)
    ref = target_scale(target)
    sq = torch.stack(
        [
            (continuous_predictions(model, prev, act, c.expand(len(obs), -1), norm) - target) ** 2
            for c in candidates
        ],
        2,
    )  # [N, H, C, out]
    best = (sq / ref.pow(2)).sum(-1).sum(1).argmin(-1)  # [N]
    rows = sq[torch.arange(len(best)), :, best]  # [N, H, out]
    rms = rows.reshape(-1, rows.shape[-1]).mean(0).sqrt()
    return torch.maximum(rms, SCALE_FLOOR * ref)
