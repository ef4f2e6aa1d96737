"""The latent cache: z^j for every stored interaction, their categories and their refresh.

z^j = E(tau^{j-1}) is computed once when interaction j begins and kept in ``Z`` (Z[0] is the
all-zero "no history" latent). The cache is recomputed with the current encoder every
``model.refresh_every`` interactions, so RL batches use up-to-date latents without running the
encoder inside every gradient step.

Discrete latents: categories whose decoder heads predict the same behaviour are mapped to one
(``merge_threshold``, see ``latent.category_groups``), then renamed to agree as much as possible
with the cached ones (a maximum matching on the old-by-new confusion matrix): training may
shuffle which category stands for which strategy, and the policy should not have to relearn it.
A rename permutes the latent model itself (the encoder's outputs, the decoder's heads and their
optimiser state), so the encoder gives the new names from then on.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from sili_robots.agent.buffer import InteractionBuffer
from sili_robots.agent.latent import (
    LatentModel,
    category_groups,
    decoder_targets,
    target_scale,
    transitions,
)

REFRESH_CHUNK = 512  # interactions per batch when recomputing latents over the replay


def padded_size(m: int) -> int:
    """A batch of ``m`` rows runs as the next power of two up to 64, else the next multiple of
    64: at most 14 shapes for chunks of up to 512, and at most 63 extra rows."""
    return 1 << max(m - 1, 0).bit_length() if m <= 64 else -(-m // 64) * 64


def pad_rows(idx: np.ndarray) -> np.ndarray:
    """``idx`` with its last entry repeated up to ``padded_size`` entries."""
    return np.pad(idx, (0, padded_size(len(idx)) - len(idx)), mode="edge")


def in_chunks(fn: Callable[[np.ndarray], np.ndarray], n: int, width: int) -> np.ndarray:
    """``fn`` over stored interactions 0..n-1 in chunks of ``REFRESH_CHUNK``, rows concatenated.
    Each chunk is padded (``pad_rows``; the extra rows dropped), so a run's refreshes use at most
    14 batch shapes: every new shape leaves memory behind (oneDNN's kernels for it and the
    allocator's fragments), and a new last chunk at each refresh grew a run by gigabytes."""
    parts = [np.zeros((0, width), np.float32)] if n == 0 else []
    for start in range(0, n, REFRESH_CHUNK):
        idx = np.arange(start, min(start + REFRESH_CHUNK, n))
        parts.append(fn(pad_rows(idx))[: len(idx)])
    return np.concatenate(parts)


def interactions_target_scale(obs: torch.Tensor, rew: torch.Tensor) -> torch.Tensor:
    """``target_scale`` of stored interactions obs [N, H+1, o] (rew [N, H])."""
    return target_scale(decoder_targets(obs[:, :-1], obs[:, 1:], rew))


def replay_target_scale(buffer: InteractionBuffer) -> torch.Tensor:
    """Per-output standard deviation of the decoder's targets over the whole replay."""
    n = buffer.n
    return interactions_target_scale(
        torch.from_numpy(buffer.obs[:n]), torch.from_numpy(buffer.rew[:n])
    )


class LatentCache:
    """Z[j] = z^j for j = 0..n (Z[0]: no history), with the category mapping of its refresh."""

    def __init__(
        self,
        model: LatentModel | None,
        buffer: InteractionBuffer,
        kind: str,
        dim: int,
        rng: np.random.Generator,
        merge_threshold: float = 0.0,
        sample: bool = False,
        optimizer: torch.optim.Optimizer | None = None,
    ) -> None:
        self.model, self.buffer, self.kind, self.dim = model, buffer, kind, dim
        self.rng, self.merge_threshold, self.sample = rng, merge_threshold, sample
        self.optimizer = optimizer  # the model's: a rename moves its state too
        self.Z = np.zeros((1, dim), np.float32)
        #: discrete latents: category -> the category standing for its behaviour group
        self.category_map = np.arange(dim)
        self.relabels = 0  # how often a refresh renamed categories (diagnostics)

    def append(self, z: np.ndarray) -> None:
        self.Z = np.concatenate([self.Z, z[None]])

    def encode(self, idx: np.ndarray) -> np.ndarray:
        """z^{j+1} = E(tau^j) for each j in ``idx`` (a Gumbel-max sample with ``sample``)."""
        return self.grouped(self._encode_ungrouped(idx))

    def raw_categories(self, idx: np.ndarray) -> np.ndarray:
        """Discrete latents: the encoder's own category of each interaction in ``idx``, before
        categories whose decoder heads predict alike are merged (diagnostics: which of the two
        joined the strategies)."""
        return self._encode_ungrouped(idx).argmax(-1)

    @torch.no_grad()
    def _encode_ungrouped(self, idx: np.ndarray) -> np.ndarray:
        b = self.buffer
        traj = transitions(
            torch.from_numpy(b.obs[idx]), torch.from_numpy(b.act[idx]), torch.from_numpy(b.rew[idx])
        )
        return self.model.encode(traj, sample=self.sample).numpy()

    def grouped(self, z: np.ndarray) -> np.ndarray:
        """Discrete latents: each category replaced by its behaviour group's category."""
        if self.kind != "discrete":
            return z
        return np.eye(self.dim, dtype=np.float32)[self.category_map[z.argmax(-1)]]

    def refresh(self) -> None:
        """Recompute every cached latent with the current encoder (module docstring)."""
        n = self.buffer.n
        discrete = self.kind == "discrete" and n > 0
        if discrete:
            self.category_map = np.arange(self.dim)  # encode raw categories first
        new = in_chunks(self.encode, n, self.dim)
        if discrete:
            if self.merge_threshold > 0:
                self.category_map = self._behaviour_groups(new.argmax(-1))
                new = self.grouped(new)
            new = self._match_names(new)
        self.Z = np.concatenate([self.Z[:1], new])

    def _match_names(self, new: np.ndarray) -> np.ndarray:
        n, k = self.buffer.n, self.dim
        old_c, new_c = self.Z[1 : n + 1].argmax(-1), new.argmax(-1)
        confusion = np.zeros((k, k))
        np.add.at(confusion, (old_c, new_c), 1.0)
        rows, cols = linear_sum_assignment(-confusion)
        perm = np.empty(k, int)
        perm[rows] = cols  # new name i <- old model category perm[i]
        if np.array_equal(perm, np.arange(k)):
            return new
        self.model.relabel(torch.from_numpy(perm), self.optimizer)
        self.category_map = np.argsort(perm)[self.category_map[perm]]
        self.relabels += 1
        return new[:, perm]

    def _behaviour_groups(self, categories: np.ndarray, reference: int = 64) -> np.ndarray:
        """category -> group leader, from the decoder heads' predictions on up to ``reference``
        stored interactions (unused categories map to themselves)."""
        b = self.buffer
        idx = self.rng.choice(b.n, min(reference, b.n), replace=False)
        obs, act, rew = (torch.from_numpy(x[idx]) for x in (b.obs, b.act, b.rew))
        scale = interactions_target_scale(obs, rew)
        distances = self.model.head_distances(obs[:, :-1], act, scale)
        counts = np.bincount(categories, minlength=self.dim)
        used = [int(c) for c in np.argsort(-counts, kind="stable") if counts[c] > 0]
        mapping = np.arange(self.dim)
        for c, leader in category_groups(distances, used, self.merge_threshold).items():
            mapping[c] = leader
        return mapping

    def state_dict(self) -> dict:
        return {"Z": self.Z.copy(), "category_map": self.category_map.copy()}

    def load_state_dict(self, state: dict) -> None:
        self.Z = np.array(state["Z"], np.float32)
        self.category_map = np.asarray(state.get("category_map", np.arange(self.dim)))
