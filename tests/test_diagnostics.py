"""Latent diagnostics from a run's metrics: what they report and when they stay silent."""

import numpy as np
import pandas as pd
import pytest

from sili_robots.diagnostics import (
    change_agreement,
    change_masks,
    filter_corrections,
    foresight_by_exit,
    latent_diagnostics,
    purity,
    strategies_per_category,
)


def _metrics(categories, strategies, stability_reward=0.0):
    categories, strategies = np.asarray(categories), np.asarray(strategies)
    changed_true = np.r_[0, (strategies[1:] != strategies[:-1]).astype(int)]
    # row j: z^{j+1} (category j) differs from z^j (category j-1)
    changed_latent = np.r_[0, (categories[1:] != categories[:-1]).astype(int)]
    return pd.DataFrame(
        {
            "latent_category": categories,
            "strategy_id": strategies,
            "strategy_changed": changed_true,
            "latent_changed": changed_latent,
            "stability_reward": stability_reward,
        }
    )


def test_purity_and_change_agreement():
    assert purity(np.array([5, 5, 7, 7]), np.array([0, 0, 1, 1])) == 1.0
    assert purity(np.array([5, 5, 5, 5]), np.array([0, 0, 1, 2])) == 0.5
    assert change_agreement(np.array([1, 1, 2]), np.array([0, 0, 1])) == 1.0
    assert change_agreement(np.array([1, 2, 2]), np.array([0, 0, 1])) == 0.0


def test_a_latent_that_predicts_the_next_strategy_is_pure_and_agrees():
    strategies = [0, 0, 1, 1, 2, 2, 2, 0]
    categories = [3, 4, 4, 9, 9, 9, 3, 3]  # row j predicts row j+1's strategy (3=0, 4=1, 9=2)
    out = latent_diagnostics(_metrics(categories, strategies, -0.25), window=100)
    assert out["latent_purity"] == 1.0
    assert out["latent_change_agreement"] == 1.0
    assert out["stability_reward_paid"] == pytest.approx(-0.25)


def test_a_window_without_latents_reports_no_latent_statistics():
    # a run whose early rows had categories but whose last window has none (-1)
    categories = [0, 1, 2] + [-1] * 10
    paid = np.r_[np.full(8, -1.0), np.zeros(5)]  # paid early, not in the window
    out = latent_diagnostics(_metrics(categories, [0, 1, 2] + [0] * 10, paid), window=5)
    assert "latent_purity" not in out and "latent_entropy" not in out
    assert out["stability_reward_paid"] == 0.0


def test_rows_without_a_latent_are_left_out_of_a_mixed_window():
    strategies = [0, 0, 1, 1, 2, 2, 2, 0]
    categories = [3, 4, 4, 9, 9, 9, 3, 3]
    mixed = _metrics(categories, strategies)
    mixed.loc[2:3, "latent_category"] = -1
    out = latent_diagnostics(mixed, window=100)
    assert out["latent_purity"] == 1.0  # computed on the rows that have a latent


def change_detection(df, start=0):
    return {k: int(v.sum()) for k, v in change_masks(df, start).items()}


def test_change_detection_credits_the_latent_that_foresaw_the_change():
    strategies = [0, 0, 0, 1, 1, 1, 1, 1, 1]
    # interaction 2 moved the opponent (true change at row 3). Row j's category is z^{j+1}:
    # foreseen = row 2 differs from row 1; a latent that needed to see the moved opponent
    # changes at row 3 instead; row 6 changes with no true change (a false alarm at row 7)
    foresaw = [5, 5, 7, 7, 7, 7, 7, 7, 7]
    late = [5, 5, 5, 7, 7, 7, 2, 2, 2]
    assert change_detection(_metrics(foresaw, strategies)) == {
        "true_changes": 1,
        "latent_changes": 1,
        "foreseen": 1,
        "late": 0,
        "false_alarms": 0,
    }
    assert change_detection(_metrics(late, strategies)) == {
        "true_changes": 1,
        "latent_changes": 2,
        "foreseen": 0,
        "late": 1,
        "false_alarms": 1,
    }
    # from interaction 4 on, the change at row 3 is left out
    assert change_detection(_metrics(late, strategies), start=4)["true_changes"] == 0


def test_foresight_by_exit_splits_true_changes_by_how_the_causing_interaction_ended():
    strategies = [0, 0, 1, 1, 2, 2, 2]
    # row 1 ended clearly inside and moved the opponent (foreseen: row 1's category changes);
    # row 3 slipped at the edge (radius 0.97) and the latent missed it
    categories = [5, 6, 6, 6, 8, 8, 8]
    radius = np.array([1.05, 0.5, 1.05, 0.97, 1.05, 1.05, 1.05])
    assert foresight_by_exit(_metrics(categories, strategies), radius) == {
        "true_changes": 2,
        "foreseen": 1,
        "late": 1,
        "inside": 1,
        "foreseen_inside": 1,
        "edge": 1,
        "foreseen_edge": 0,
        "false_alarms": 0,
    }
    assert foresight_by_exit(_metrics(categories, strategies), radius, start=3)["inside"] == 0


def test_filter_corrections_split_moves_from_false_alarms():
    df = pd.DataFrame(
        {
            "strategy_id": [0, 0, 1, 1, 2, 2, 2],
            "filter_step": [-1, 3, 2, -1, -1, 5, -1],
            "task_reward": [-5.0, -6.0, -9.0, -5.0, -30.0, -7.0, -5.0],
        }
    )
    out = filter_corrections(df, start=1)
    # moves before rows 2 (corrected at step 2) and 4 (not corrected); false alarms at 1 and 5
    assert out["moved"] == 2 and out["moved_corrected"] == 1
    assert out["median_step_moved"] == 2.0
    assert out["reward_moved"] == pytest.approx(-19.5)
    assert out["held"] == 4 and out["false_alarms"] == 2
    assert out["reward_false_alarms"] == pytest.approx(-6.5)
    assert out["reward_held"] == pytest.approx(-5.75)
    assert filter_corrections(df.drop(columns="filter_step"))["false_alarms"] == 0  # no filter


def test_strategies_per_category_counts_each_interaction_under_its_category():
    split = strategies_per_category(np.array([3, 3, 1, 3, 1]), np.array([0, 2, 0, 0, 0.0]))
    assert split == {1: {0: 2}, 3: {0: 2, 2: 1}}


def test_latent_entropy_is_in_nats():
    """Of the categories predicted in the window: ln 2 for two used equally, 0 for one."""
    two = latent_diagnostics(_metrics([3, 4, 3, 4, 3], [0, 1, 0, 1, 0]), window=100)
    assert two["latent_entropy"] == pytest.approx(np.log(2))
    one = latent_diagnostics(_metrics([3, 3, 3, 3, 3], [0, 0, 0, 0, 0]), window=100)
    assert one["latent_entropy"] == pytest.approx(0.0)


def test_a_correction_at_step_0_is_a_correction():
    """A filter that corrected at step 0 was counted as never correcting."""
    df = pd.DataFrame(
        {
            "strategy_id": [0, 0, 1, 1],
            "filter_step": [-1, -1, 0, 0],
            "task_reward": [1.0, 2.0, 3.0, 4.0],
        }
    )
    out = filter_corrections(df)
    assert out["moved"] == 1 and out["moved_corrected"] == 1 and out["median_step_moved"] == 0.0
    assert out["false_alarms"] == 1 and out["reward_false_alarms"] == 4.0
