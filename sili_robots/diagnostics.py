"""Where learning fails: latent usage statistics from a run's per-interaction metrics.

Row j of ``metrics.csv`` holds ``latent_category`` = argmax of z^{j+1} = E(tau^j), the agent's
prediction of the *next* interaction's strategy, so it is compared with row j+1's true strategy.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def purity(pred: np.ndarray, true: np.ndarray) -> float:
    """Fraction of items whose predicted category's most frequent true label is their label."""
    true = np.asarray(true)
    return float(
        sum(pd.Series(true[pred == c]).value_counts().iloc[0] for c in np.unique(pred)) / len(pred)
    )


def change_agreement(pred: np.ndarray, true: np.ndarray) -> float:
    """Fraction of consecutive pairs where "the prediction changed" equals "the truth changed"."""
    pred, true = np.asarray(pred), np.asarray(true)
    return float(np.mean((pred[1:] != pred[:-1]) == (true[1:] != true[:-1])))


def latent_diagnostics(df: pd.DataFrame, window: int = 100) -> dict[str, float]:
    """Over the last ``window`` interactions: how the predicted latent relates to the truth.

    - ``latent_entropy``: entropy (nats) of the predicted-category histogram (0 = one category).
    - ``latent_purity``: fraction of interactions whose predicted category's most frequent true
      strategy is their true strategy (1 = every category stands for one strategy).
    - ``latent_change_agreement``: fraction where "my latent changed" equals "the true
      strategy changed".
    - ``stability_reward_paid``: mean stability reward the agent received per interaction.
    """
    out = {"stability_reward_paid": float(df["stability_reward"].tail(window).mean())}
    if len(df) < 2 or (df["latent_category"] < 0).all():
        return out
    pred = df["latent_category"].to_numpy()[:-1][-window:]
    has_latent = pred >= 0  # -1: no discrete latent on that row
    if not has_latent.any():
        return out
    pred = pred[has_latent]
    true = df["strategy_id"].to_numpy()[1:][-window:][has_latent]
    pred_changed = df["latent_changed"].to_numpy()[:-1][-window:][has_latent].astype(bool)
    true_changed = df["strategy_changed"].to_numpy()[1:][-window:][has_latent].astype(bool)
    counts = np.bincount(pred)
    p = counts[counts > 0] / counts.sum()
    out.update(
        {
            "latent_entropy": float(-(p * np.log(p)).sum()),
            "latent_purity": purity(pred, true),
            "latent_change_agreement": float(np.mean(pred_changed == true_changed)),
        }
    )
    return out
