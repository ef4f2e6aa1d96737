"""Where learning fails: latent usage statistics from a run's per-interaction metrics.

Row j of ``metrics.csv`` holds ``latent_category`` = argmax of z^{j+1} = E(tau^j), the agent's
prediction of the *next* interaction's strategy, so it is compared with row j+1's true strategy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from sili_robots.agent.agent import SILIAgent


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


def change_masks(df: pd.DataFrame, start: int = 0) -> dict[str, np.ndarray]:
    """Per row j (the interaction played with z^j) from ``start`` on: how the latent met the
    true strategy.

    ``latent_changes``: z^j differs from z^{j-1}. A true change at row j (``strategy_id``
    differs from row j-1's) was caused by interaction j-1, so the latent *foresaw* it when
    z^j = E(tau^{j-1}) differs from z^{j-1}, i.e. when ``latent_category`` of row j-1 differs
    from row j-2's. ``late``: the latent showed it one interaction later, after playing against
    the moved opponent (row j against j-1). ``false_alarms``: z^j differs from z^{j-1} with no
    true change at row j, and it is not such a late catch-up either (no true change at row
    j-1). Rows 0 and 1 have no latent change (there is no z^{j-1} to compare).

    Categories are compared as logged: across a refresh of the cached latents (every
    ``model.refresh_every`` interactions) the two rows come from different encoders, so there
    a relabelling counts as a change the agent's own ``latent_changed`` does not show.
    """
    sid = df["strategy_id"].to_numpy()
    cat = df["latent_category"].to_numpy()
    n = len(df)
    keys = ("true_changes", "latent_changes", "foreseen", "late", "false_alarms")
    out = {k: np.zeros(n, bool) for k in keys}
    if n >= 3:
        true = np.r_[False, sid[1:] != sid[:-1]]
        latent = np.r_[False, False, cat[1:-1] != cat[:-2]]  # z^j differs from z^{j-1}
        late = np.r_[False, cat[1:] != cat[:-1]]  # z^{j+1} differs from z^j
        out["true_changes"], out["latent_changes"] = true, latent
        out["foreseen"] = true & latent
        out["late"] = true & late & ~latent
        out["false_alarms"] = latent & ~true & ~np.r_[False, true[:-1]]
    return {k: v[start:] for k, v in out.items()}


def latent_diagnostics(df: pd.DataFrame, window: int = 100) -> dict[str, float]:
    """Over the last ``window`` interactions: how the predicted latent relates to the truth.

    - ``latent_entropy``: entropy (nats) of the predicted-category histogram (0 = one category).
    - ``latent_purity``: fraction of interactions whose predicted category's most frequent true
      strategy is their true strategy (1 = every category stands for one strategy).
    - ``latent_change_agreement``: fraction where "my latent changed" equals "the true
      strategy changed".
    - ``stability_reward_paid``: mean of the ``stability_reward`` column: -d(z^j, z^{j+1})
      before b and the credit (``boundary`` pays scale x that, H by default; ``per_step`` that
      on every step of the next interaction), or for the partial latent minus the flagged
      steps (``InteractionStats``).
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


def foresight_by_exit(
    df: pd.DataFrame, end_radius: np.ndarray, clear_inside: float = 0.9, start: int = 0
) -> dict[str, int]:
    """Counts of ``change_masks``, the true changes split by how the interaction that caused
    them ended (Circle): clearly inside (``end_radius`` below ``clear_inside``: a move on
    purpose) or near the edge (a slip). ``end_radius[j]`` is interaction j's final distance
    from the centre; a true change at row j was caused by row j-1."""
    masks = change_masks(df, start)
    true, seen = masks["true_changes"], masks["foreseen"]
    inside = np.r_[np.nan, np.asarray(end_radius)[: len(df) - 1]][start:] < clear_inside
    return {
        "true_changes": int(true.sum()),
        "foreseen": int(seen.sum()),
        "late": int(masks["late"].sum()),
        "inside": int((true & inside).sum()),
        "foreseen_inside": int((seen & inside).sum()),
        "edge": int((true & ~inside).sum()),
        "foreseen_edge": int((seen & ~inside).sum()),
        "false_alarms": int(masks["false_alarms"].sum()),
    }


def filter_corrections(df: pd.DataFrame, start: int = 0) -> dict[str, float]:
    """How the within-interaction filter (``latent_filter``, column ``filter_step``) met the
    opponent's moves, from interaction ``start`` on.

    Row j was played against a moved opponent when its ``strategy_id`` differs from row j-1's;
    there a correction (``filter_step`` >= 0) is what the filter is for (where z^j foresaw the
    move none was needed; such rows are not told apart here). On the other rows a correction is
    a false alarm: the policy left a right z^j.
    """
    sid = df["strategy_id"].to_numpy()
    step = df["filter_step"].to_numpy() if "filter_step" in df else np.full(len(df), -1)
    reward = df["task_reward"].to_numpy()
    moved = np.r_[False, sid[1:] != sid[:-1]][start:]
    step, reward = step[start:], reward[start:]
    corrected = step >= 0

    def mean(x: np.ndarray) -> float:
        return float(x.mean()) if len(x) else float("nan")

    return {
        "moved": int(moved.sum()),
        "moved_corrected": int((moved & corrected).sum()),
        "median_step_moved": float(np.median(step[moved & corrected]))
        if (moved & corrected).any()
        else float("nan"),
        "reward_moved": mean(reward[moved]),
        "held": int((~moved).sum()),
        "false_alarms": int((~moved & corrected).sum()),
        "reward_false_alarms": mean(reward[~moved & corrected]),
        "reward_held": mean(reward[~moved]),
    }


def strategies_per_category(categories: np.ndarray, strategy_ids: np.ndarray) -> dict[int, dict]:
    """category -> {true strategy id: interactions}: a category holding one strategy separates
    it; one holding several in like shares does not."""
    categories, strategy_ids = np.asarray(categories), np.asarray(strategy_ids).astype(int)
    return {
        int(c): pd.Series(strategy_ids[categories == c]).value_counts().sort_index().to_dict()
        for c in np.unique(categories)
    }


def category_strategies(agent: SILIAgent, window: int) -> tuple[dict[int, dict], dict[int, dict]]:
    """Over the agent's last ``window`` stored interactions: the true strategies behind each
    discrete latent category as the encoder gives it, and after categories whose decoder heads
    predict alike are merged; tells an encoder that does not separate the strategies from a merge
    that joined categories that did. Empty for an agent without discrete latents."""
    latents, n = agent.latents, agent.buffer.n
    if latents.kind != "discrete":
        return {}, {}
    idx = np.arange(max(n - window, 0), n)
    strategies = agent.buffer.strategy_id[idx]
    raw = latents.raw_categories(idx)
    return (
        strategies_per_category(raw, strategies),
        strategies_per_category(latents.category_map[raw], strategies),
    )
