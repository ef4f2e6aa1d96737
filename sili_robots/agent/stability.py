"""SILI's stability reward, used by training and metrics alike, and where the agent credits it
(``SILIAgent._stability_rewards``).

R_stable = -d(z^j, z^{j+1}): d is 0/1 on the category for discrete latents, Euclidean for
continuous ones, "the true strategy changed" for the ``true`` diagnostic. z^0 is "no history",
not a strategy, so the change into z^1 costs nothing (except for ``true``, where z^0 is known).

Credit (``sili.credit``):

- ``boundary`` (default): the change z^j -> z^{j+1} is caused by what the ego did in interaction
  j, so ``scale`` x R_stable is paid on j's last step, whose successor lies in interaction j+1
  (scale defaults to H: the paper's per-step term summed over an interaction).
- ``per_step`` (the paper's text): every step of interaction j is paid -d(z^j, z^{j-1}).

Partial observation: R_stable = -flag of the next observation on every step (its last element).
"""

from __future__ import annotations

import numpy as np


def latent_distance(za: np.ndarray, zb: np.ndarray, kind: str) -> np.ndarray:
    """d(z, z') per row."""
    if kind == "discrete":
        return (za.argmax(-1) != zb.argmax(-1)).astype(np.float32)
    if kind == "true":
        return (np.abs(za - zb).max(-1) > 1e-6).astype(np.float32)
    return np.linalg.norm(za - zb, axis=-1).astype(np.float32)


def change_after(Z: np.ndarray, j: np.ndarray, kind: str) -> np.ndarray:
    """d(z^j, z^{j+1}) for stored interactions j (Z[j] = z^j, Z[0] = no history)."""
    d = latent_distance(Z[j], Z[j + 1], kind)
    return d if kind == "true" else np.where(j >= 1, d, 0.0).astype(np.float32)


def partial_reward(next_obs: np.ndarray) -> np.ndarray:
    """Partial observation: -flag of each next observation ("the strategy changed")."""
    return -next_obs[..., -1]
