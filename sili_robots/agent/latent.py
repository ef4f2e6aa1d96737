"""The latent strategy model: encoder E(tau^{j-1}) -> z^j, decoder D(s, a, z^j) -> (s' - s, r).

Encoder aggregation (a design choice the paper leaves open): each transition (s, a, r, s') of
the previous interaction goes through the same 2 x 256 MLP, and the set of features is pooled by
mean *and* max before a linear head. The pooling is permutation-invariant, uses every timestep
(no fixed subsample that could miss the one informative step), and max-pooling lets one step,
e.g. the last one whose end position decides the opponent's next move, dominate a feature. The
time fraction t/H is part of s, so order is still available when it matters.

``readouts`` are further functions of the per-step features handed to the head beside the
pooled ones; the ``last_step`` add-on (sili_robots/addons/last_step.py) uses one to read the last
transition unpooled.

Decoder. Continuous latents are concatenated to (s, a). For discrete latents the decoder has one
output head per category on a shared trunk and the one-hot z selects the head: D(s, a, z) =
sum_k z_k D_k(s, a). This departs from the paper's decoder, which takes z as an input: a one-hot
input shifts the first layer per category, the heads share every hidden feature and differ in the
output layer. The heads give every category's error in one pass (the ``expected`` estimator's
exact expectation) and let categories that predict alike be compared (``category_groups``).

Training objective for discrete latents (``estimator``):

* ``expected`` (default): the expected squared error under the encoder's categorical q(z|tau),
  sum_k q_k * err_k, computed exactly over the k categories, plus a small bonus for using many
  categories across a batch (entropy of the batch-mean q). Measured on Circle (3 Goals) data the
  paper's straight-through Gumbel estimator collapsed to one category (the decoder learns to
  ignore a z that is noise at first, and then the encoder gets no signal); the exact expectation
  with the usage bonus recovers the true strategy (purity 0.97 where Gumbel stayed at 0.4-0.5).
* ``marginal``: the exact marginal likelihood -log sum_k q_k p(tau^j | k) (an EM-like
  objective whose head gradients are weighted by the posterior); measured on the same data it
  found 2-3 clusters but did not beat ``expected`` (purity 0.37-0.69).
* ``gumbel``: the paper's straight-through Gumbel-Softmax (temperature 1): one-hot forward, soft
  gradient backward.

Continuous latents are tanh of the encoder's output (``squash``; the paper profile takes the raw
output: the paper bounds nothing). Nothing in the
reconstruction keeps that output small, and once it is large tanh passes no gradient back:
measured on Circle (3 Goals), one seed's encoder outputs reached |16|-|22| in every dimension,
so z^j sat at the corners of the box and flipped sign between interactions with no change of
strategy (benchmarks/RESULTS.md). ``preact_penalty`` adds lambda * mean(output^2), negligible
while the output is O(1) and strong once it saturates.

Targets are standardised per dimension within each batch, so the usage bonus weighs the same
against the reconstruction whatever the task's reward scale.

Same strategy, several categories. Gradient training of a mixture of decoder heads has local
optima where two strategies share one head; a larger usage bonus avoids them by spreading the
data over more categories than there are strategies, which on its own would make one strategy
show up as several categories and the stability reward pay for changes that did not happen.
``category_groups`` undoes that split by behaviour: two categories are the same strategy when no
output of their decoder heads differs by more than ``threshold`` target standard deviations
(root mean square over states the agent visited). Measured on 500 Circle (3 Goals) interactions
of a SILI run (benchmarks/bench_latent_grouping.py, 2 seeds): the usage bonus 0.03 gave purity
0.76 and change agreement 0.74; 0.1 gave purity 0.90 but change agreement 0.72; grouping at 0.5
kept the purity and raised the agreement to 0.83 (numbers in benchmarks/RESULTS.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from sili_robots.agent.matmul import Linear
from sili_robots.agent.networks import mlp

ESTIMATORS = ("marginal", "expected", "gumbel")
#: most elements of the heads' pairwise differences ``head_distances`` holds at once (256 MB;
#: a row of categories at least): they grow with ``dim`` squared, and a ``model.dim`` of a few
#: hundred ran out of memory
DISTANCE_ELEMENTS = 1 << 26


def gumbel_straight_through(logits: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """One-hot of argmax(logits + g) forward; softmax((logits + g) / T) gradient backward."""
    gumbels = -torch.empty_like(logits).exponential_().log()
    soft = F.softmax((logits + gumbels) / temperature, dim=-1)
    hard = F.one_hot(soft.argmax(-1), logits.shape[-1]).to(soft.dtype)
    return hard - soft.detach() + soft


class LatentModel(nn.Module):
    """Encoder and decoder trained jointly on consecutive interaction pairs (j-1, j)."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        latent_dim: int,
        hidden: int,
        kind: str,
        estimator: str = "expected",
        usage_bonus: float = 0.1,
        preact_penalty: float = 0.0,
        squash: bool = True,
        readouts: Sequence[Callable[[torch.Tensor], torch.Tensor]] = (),
        matmul: str = "aten",
    ) -> None:
        super().__init__()
        if kind not in ("discrete", "continuous"):
            raise ValueError(f"latent model kind must be discrete or continuous, got {kind!r}")
        if estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
        self.kind, self.estimator, self.usage_bonus = kind, estimator, usage_bonus
        self.preact_penalty, self.squash = preact_penalty, squash
        self.readouts = list(readouts)
        self.latent_dim = latent_dim
        tr_dim = 2 * obs_dim + act_dim + 1
        self.phi = nn.Sequential(
            Linear(tr_dim, hidden, matmul),
            nn.ReLU(),
            Linear(hidden, hidden, matmul),
            nn.ReLU(),
        )
        self.head = Linear((2 + len(self.readouts)) * hidden, latent_dim, matmul)
        self.out_dim = obs_dim + 1
        if kind == "discrete":
            self.decoder = mlp(obs_dim + act_dim, latent_dim * self.out_dim, hidden, matmul=matmul)
        else:
            self.decoder = mlp(obs_dim + act_dim + latent_dim, self.out_dim, hidden, matmul=matmul)

    @torch.no_grad()
    def relabel(self, perm: torch.Tensor, optimizer: torch.optim.Optimizer | None = None) -> None:
        """Rename categories: new category i is old category ``perm[i]`` (encoder output and
        decoder head move together, so the model computes the same function). The optimizer's
        per-parameter state (Adam's moments) moves with them, or each renamed category would
        go on with another's step sizes."""
        if self.kind != "discrete":
            raise ValueError("only discrete latents have categories to relabel")
        last = self.decoder[-1]
        for param, per_category in (
            (self.head.weight, 1),
            (self.head.bias, 1),
            (last.weight, self.out_dim),
            (last.bias, self.out_dim),
        ):
            state = optimizer.state.get(param, {}) if optimizer is not None else {}
            moved = [param, *(v for v in state.values() if v.shape == param.shape)]
            for tensor in moved:
                rows = tensor.unflatten(0, (self.latent_dim, per_category))
                tensor.copy_(rows[perm].flatten(0, 1))

    @torch.no_grad()
    def head_distances(
        self, obs: torch.Tensor, act: torch.Tensor, scale: torch.Tensor
    ) -> torch.Tensor:
        """[k, k]: the largest over outputs of the RMS difference between two categories'
        predictions on the states ``obs`` / actions ``act``, in units of ``scale`` per output."""
        heads = self._heads(obs, act).reshape(-1, self.latent_dim, self.out_dim) / scale
        n, k, out = heads.shape
        rows = max(1, DISTANCE_ELEMENTS // (n * k * out))  # all k at the default sizes
        blocks = []
        for i in range(0, k, rows):
            diff = heads[:, i : i + rows].unsqueeze(2) - heads.unsqueeze(1)  # [N, rows, k, out]
            blocks.append(diff.pow_(2).mean(0).sqrt().amax(-1))  # in place: one block held
        return torch.cat(blocks)

    @torch.no_grad()
    def step_log_likelihoods(
        self,
        obs: torch.Tensor,
        act: torch.Tensor,
        next_obs: torch.Tensor,
        rew: torch.Tensor,
        scale: torch.Tensor,
    ) -> torch.Tensor:
        """[..., k]: log p(s' - s, r | s, a, k) of each transition under each category's decoder
        head, a unit-variance Gaussian on targets in units of ``scale`` (constants dropped)."""
        target = decoder_targets(obs, next_obs, rew) / scale
        heads = self._heads(obs, act) / scale  # [..., k, out]
        return -0.5 * (heads - target.unsqueeze(-2)).pow(2).sum(-1)

    def encode_logits(self, traj: torch.Tensor) -> torch.Tensor:
        """``traj``: [N, H, tr_dim] -> raw encoder output [N, latent_dim]."""
        h = self.phi(traj)
        parts = [h.mean(1), h.amax(1), *(readout(h) for readout in self.readouts)]
        return self.head(torch.cat(parts, dim=-1))

    def _continuous(self, out: torch.Tensor) -> torch.Tensor:
        """A continuous z from the raw encoder output: tanh of it, or itself (``squash``)."""
        return torch.tanh(out) if self.squash else out

    def encode(self, traj: torch.Tensor, sample: bool = False) -> torch.Tensor:
        """The latent z; ``sample`` draws a Gumbel-max one-hot instead of the most likely
        category (the z^j acted on and cached, ``model.sample``)."""
        out = self.encode_logits(traj)
        if self.kind == "continuous":
            return self._continuous(out)
        if sample:
            return gumbel_straight_through(out)
        return F.one_hot(out.argmax(-1), self.latent_dim).to(out.dtype)

    def _decoder(self, x: torch.Tensor) -> torch.Tensor:
        """The decoder MLP on rows of any leading shape, run on their 2-D view: its in-place
        ReLUs on a 3-D layer output (itself a view) would make autograd copy the slices and
        zero-fill a buffer in every backward pass (7% of a latent-model update)."""
        return self.decoder(x.reshape(-1, x.shape[-1])).unflatten(0, x.shape[:-1])

    def _heads(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """Per-category predictions [..., k, out] of a discrete decoder."""
        out = self._decoder(torch.cat([obs, act], dim=-1))
        return out.unflatten(-1, (self.latent_dim, self.out_dim))

    def decode(self, obs: torch.Tensor, act: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Predicted [s' - s, r] from s, a and z (z broadcast over the time axis); a continuous
        decoder's come standardised as in ``loss`` (filter_math.continuous_predictions: units)."""
        z = z.unsqueeze(-2).expand(*obs.shape[:-1], z.shape[-1])
        if self.kind == "discrete":
            return (z.unsqueeze(-1) * self._heads(obs, act)).sum(-2)
        return self._decoder(torch.cat([obs, act, z], dim=-1))

    def loss(
        self,
        prev_traj: torch.Tensor,
        obs: torch.Tensor,
        act: torch.Tensor,
        next_obs: torch.Tensor,
        rew: torch.Tensor,
    ) -> torch.Tensor:
        """Negative log-likelihood (unit-variance Gaussian on standardised targets) of
        interaction j given z^j = E(tau^{j-1}): the paper's max-likelihood objective."""
        target = decoder_targets(obs, next_obs, rew)
        mean = target.reshape(-1, target.shape[-1]).mean(0)
        scale = target_scale(target)
        target = (target - mean) / scale
        logits = self.encode_logits(prev_traj)
        if self.kind == "continuous":
            pred = self.decode(obs, act, self._continuous(logits))
            return F.mse_loss(pred, target) + self.preact_penalty * logits.pow(2).mean()
        heads = (self._heads(obs, act) - mean) / scale  # [B, H, k, out]
        err = (heads - target.unsqueeze(-2)).pow(2).mean(-1).mean(1)  # [B, k]
        if self.estimator == "marginal":
            # -log sum_k q_k p(tau^j | k); log p = -0.5 * H * err: err averages the outputs too,
            # so each output is a Gaussian of variance out_dim (the mixture's weights sharpen
            # out_dim times more slowly than under unit variance)
            log_lik = -0.5 * obs.shape[1] * err
            log_q = F.log_softmax(logits, dim=-1)
            nll = -torch.logsumexp(log_q + log_lik, dim=-1).mean() / obs.shape[1]
            usage = log_q.exp().mean(0)
            return nll + self.usage_bonus * (usage * torch.log(usage + 1e-8)).sum()
        if self.estimator == "gumbel":
            z = gumbel_straight_through(logits)
            return (z * err).sum(-1).mean()
        q = F.softmax(logits, dim=-1)
        usage = q.mean(0)
        usage_entropy = -(usage * torch.log(usage + 1e-8)).sum()
        return (q * err).sum(-1).mean() - self.usage_bonus * usage_entropy


def decoder_targets(obs: torch.Tensor, next_obs: torch.Tensor, rew: torch.Tensor) -> torch.Tensor:
    """What the decoder predicts: [s' - s, r] per step."""
    return torch.cat([next_obs - obs, rew.unsqueeze(-1)], dim=-1)


def target_scale(target: torch.Tensor) -> torch.Tensor:
    """Per-output standard deviation of ``decoder_targets`` (1 where constant, or of a single
    transition, as a batch of one interaction of one step is: left as is)."""
    flat = target.reshape(-1, target.shape[-1])
    if len(flat) < 2:  # no spread to measure (torch would warn and give NaN)
        return torch.ones(flat.shape[-1], dtype=flat.dtype)
    std = flat.std(0)
    return torch.where(std > 1e-4, std, torch.ones_like(std))


def category_groups(distances: torch.Tensor, used: list[int], threshold: float) -> dict[int, int]:
    """Map each used category to its group's leader. ``used`` is ordered most used first; each
    category joins the first leader closer than ``threshold``, else leads a group of its own
    (leaders rather than single linkage, so a chain of near pairs cannot join two strategies)."""
    rep = {c: c for c in used}
    for i, a in enumerate(used):
        for b in used[:i]:
            if rep[b] == b and float(distances[a, b]) < threshold:
                rep[a] = b
                break
    return rep


def transitions(obs: torch.Tensor, act: torch.Tensor, rew: torch.Tensor) -> torch.Tensor:
    """Stack an interaction's (s, a, r, s') rows: obs [N, H+1, o], act [N, H, a], rew [N, H]."""
    return torch.cat([obs[:, :-1], act, rew.unsqueeze(-1), obs[:, 1:]], dim=-1)
