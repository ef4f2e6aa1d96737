"""The one-line result of a run: held or not, and its reward against the task's references."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pandas as pd
import pytest
from fast_settings import FAST_ARGS

from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.runs import read_config
from sili_robots.verdict import NONE_WORKED, across_seeds, held, random_only, verdict, worked
from sili_robots.verdict import main as verdict_main


def test_train_prints_the_verdict_against_the_stored_references(tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "4", "--out", str(run)]
    assert main([*args, *FAST_ARGS, "--no-progress"]) == 0
    printed = capsys.readouterr()
    json.loads(printed.out)  # stdout stays one JSON document for tools
    last = printed.err.strip().splitlines()[-1]
    assert last.startswith(
        "SILI ran 4 interactions, too few to tell whether it holds the opponent (the verdict "
        "reads the last 50): the opponent kept its strategy in "
    )
    assert "of those after the first (standing still: 0%) and earned" in last
    assert "standing still: -50.0" in last
    assert "the scripted stabilizing policy that sees z: -4.0" in last
    assert "random actions" not in last  # 3 random interactions, then 1 of its policy
    for window in (0, -1, 2.5, "5"):  # 0 earned nan, -1 read all but the first
        with pytest.raises(ConfigError, match=f"window must be an integer >= 1, got {window!r}"):
            verdict(run, window)
    with pytest.raises(ConfigError, match="give a list of run directories to judge, got"):
        across_seeds(str(run))  # (was walked letter by letter)
    metrics = pd.read_csv(run / "metrics.csv")
    metrics["strategy_changed"] = 0
    metrics["task_reward"] = -7.25
    metrics["interaction"] += 10  # as the last 4 of a longer game: each one counts
    metrics.to_csv(run / "metrics.csv", index=False)
    assert not held(run) and not worked(run)  # 4 kept of the 50 a verdict reads
    line = verdict(run, window=4)
    assert line.startswith("SILI held the opponent (kept its strategy in 100% of its last 4 ")
    assert "earned -7.2 per interaction" in line
    assert held(run, window=4)
    metrics.loc[metrics.index[0], "strategy_changed"] = 1  # 3 of 4 kept: 75% < 90%
    metrics.to_csv(run / "metrics.csv", index=False)
    assert not held(run, window=4) and held(run, window=3)
    line = verdict(run, window=4)
    assert line.startswith("SILI did not hold the opponent (kept its strategy in 75% of its last")
    assert ", 90% needed; standing still: 0%)" in line
    assert worked(run, window=3)  # held at -7.25, above standing still's -50.0
    metrics["task_reward"] = -55.3  # held by parking away from the goal: below standing still
    metrics.to_csv(run / "metrics.csv", index=False)
    assert held(run, window=3) and not worked(run, window=3)
    ten = pd.concat([metrics] * 3, ignore_index=True).head(10)
    ten["interaction"], ten["task_reward"], ten["strategy_changed"] = range(20, 30), -7.25, 0
    ten.loc[3, "strategy_changed"] = 1  # 9 of 10 kept: exactly 90% holds
    ten.to_csv(run / "metrics.csv", index=False)
    assert held(run, window=10) and worked(run, window=10)
    assert verdict(run, window=10).startswith("SILI held the opponent (kept its strategy in 90%")


def test_a_run_that_never_left_its_random_actions_says_its_policy_has_not_trained(tmp_path, capsys):
    """A run no longer than ``sac.random_interactions`` trained no policy: its verdict read like
    the method's failure, and ``sili eval`` scored the untrained policy without a word."""
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "3"]
    assert main([*args, *FAST_ARGS, "--set", "random_interactions=5", "--out", str(run)]) == 0
    note = "all its 3 interactions were random actions (sac.random_interactions=5)"
    assert note + ": they say nothing" in capsys.readouterr().err.strip().splitlines()[-1]
    assert verdict(run).endswith(f"; {note}: they say nothing of its policy")
    assert main(["eval", str(run), "--interactions", "2"]) == 0
    assert f"{run}: its policy has not trained: {note}" in capsys.readouterr().err
    exact = tmp_path / "exact"  # as long as its random phase: SAC updated after the last one
    args = [*args, *FAST_ARGS, "--set", "random_interactions=3", "--out", str(exact)]
    assert main(args) == 0
    assert verdict(exact).endswith("interactions were random actions (sac.random_interactions=3)"
                                   ": they say nothing of its policy")  # fmt: skip
    capsys.readouterr()
    assert main(["eval", str(exact), "--interactions", "2"]) == 0
    assert "has not trained" not in capsys.readouterr().err
    cfg = read_config(run)
    assert (
        random_only(cfg, 1) == "its one interaction was random actions (sac.random_interactions=5)"
    )
    assert random_only(cfg, 6) == ""


def test_true_stability_leaves_out_the_games_first_interaction_everywhere(tmp_path):
    """Interaction 0 has no strategy before it to keep: counted as kept, a 3-interaction run
    that lost the opponent once would report 67% where ``sili bounds`` counts 50%."""
    from sili_robots.metrics import kept_fraction
    from sili_robots.sweep.results import results_table
    from sili_robots.training import write_summary

    run = tmp_path / "sweep" / "runs" / "r"
    args = ["train", "--task", "circle-3", "--interactions", "3", "--out", str(run)]
    assert main([*args, *FAST_ARGS, "--no-progress"]) == 0
    metrics = pd.read_csv(run / "metrics.csv").assign(strategy_changed=[0, 1, 0])
    metrics.to_csv(run / "metrics.csv", index=False)
    assert write_summary(run)["final_stability"] == 0.5
    assert kept_fraction(metrics.head(1)) is None  # nothing to judge
    assert "3 interactions, too few to tell" in verdict(run) and "50% of those after" in verdict(
        run
    )
    table = results_table(tmp_path / "sweep")
    assert table["true_stability"].isna().tolist() == [True, False, False]  # plots start at 1
    assert table["true_stability"].iloc[1:].tolist() == [0.0, 1.0]


def test_the_verdict_counts_the_interactions_it_judged_and_never_rounds_a_miss_up(tmp_path):
    """A run of exactly the window's length is judged on one fewer (its game's first keeps
    nothing): it said "of its last 50"; 44 of 49 kept (89.8%) printed "90%, 90% needed"."""
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "3", "--out", str(run)]
    assert main([*args, *FAST_ARGS, "--no-progress"]) == 0
    rows = pd.read_csv(run / "metrics.csv")
    fifty = pd.concat([rows] * 17, ignore_index=True).head(50)
    fifty["interaction"], fifty["strategy_changed"] = range(50), 0
    fifty.loc[[10, 20, 30, 40, 45], "strategy_changed"] = 1  # 44 of the 49 after the first
    fifty.to_csv(run / "metrics.csv", index=False)
    line = verdict(run)
    assert line.startswith(
        "SILI did not hold the opponent (kept its strategy in 89.8% of its last 49 interactions, "
        "90% needed"
    )
    assert ": not seed 0 (89.8%, -" in across_seeds([run])[0]
    longer = pd.concat([fifty] * 10, ignore_index=True).assign(interaction=range(500))
    longer["strategy_changed"] = [0] * 450 + [1] * 50  # 449 of the 499 after the first: 89.98%
    longer.to_csv(run / "metrics.csv", index=False)
    assert "kept its strategy in 89.98% of its last 499 interactions" in verdict(run, window=500)


def test_a_run_with_other_task_arguments_is_not_read_against_the_defaults_references(
    tmp_path, capsys
):
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "4", "--out", str(run)]
    assert main([*args, "--env-kwarg", "outside_margin=0.5", *FAST_ARGS, "--no-progress"]) == 0
    metrics = pd.read_csv(run / "metrics.csv").assign(strategy_changed=0, task_reward=-60.0)
    metrics.to_csv(run / "metrics.csv", index=False)
    line = verdict(run, window=4)
    assert "standing still" not in line and "stabilizing" not in line
    assert line.endswith(
        "(no references are stored for this task and its arguments: reward not judged; "
        "`sili bounds circle-3 --env-kwarg outside_margin=0.5` measures them)"
    )
    assert worked(run, window=4)  # no stored standing-still reward to fall below
    (run / "metrics.csv").rename(run / "kept.csv")
    metrics.to_csv(run / "metrics.csv.gz", index=False)  # as `sili collect` keeps a run
    assert verdict(run, window=4) == line
    (run / "metrics.csv.gz").unlink()
    assert verdict_main([str(run)]) == 2  # one line, no traceback
    assert "has no metrics.csv (nor its gzipped copy)" in capsys.readouterr().err
    metrics.head(0).to_csv(run / "metrics.csv", index=False)  # stopped before its first
    assert verdict_main([str(run)]) == 2
    assert "has logged no interaction yet" in capsys.readouterr().err


def test_a_users_task_is_not_offered_sili_bounds(tmp_path):
    """sili bounds plays the registered tasks: a user's task's verdict says no more than that
    it has no references."""
    run = tmp_path / "doors"
    args = ["train", "--task", "sili_robots.examples.two_doors:TwoDoorsEnv", "--method", "sac"]
    assert main([*args, "--interactions", "2", "--out", str(run), "--set", "hidden=8"]) == 0
    assert verdict(run, window=2).endswith(
        "(no references are stored for this task and its arguments: reward not judged); all its "
        "2 interactions were random actions (sac.random_interactions=20): they say nothing of its "
        "policy"
    )


def test_a_run_given_its_versions_own_arguments_is_read_against_the_references(tmp_path):
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "4", "--out", str(run)]
    # 0.1 is Circle3-v1's own margin: the dynamics the references were measured on
    assert main([*args, "--env-kwarg", "outside_margin=0.1", *FAST_ARGS, "--no-progress"]) == 0
    assert "standing still: -50.0" in verdict(run, window=4)


def _trained(tmp_path, seed: int, task_reward: float, changed: int):
    """A short run whose record then reads as 50 interactions of the given outcome."""
    run = tmp_path / f"s{seed}"
    args = ["train", "--task", "circle-3", "--interactions", "4", "--seed", str(seed)]
    assert main([*args, "--out", str(run), *FAST_ARGS, "--no-progress"]) == 0
    metrics = pd.concat([pd.read_csv(run / "metrics.csv")] * 13).head(50)
    metrics = metrics.assign(interaction=range(50), strategy_changed=changed)
    metrics.assign(task_reward=task_reward).to_csv(run / "metrics.csv", index=False)
    return run


def test_the_line_across_seeds_counts_the_runs_that_worked_and_picks_the_best(tmp_path, capsys):
    held_low = _trained(tmp_path, 2, -30.0, changed=0)
    lost = _trained(tmp_path, 0, -10.0, changed=1)
    held_high = _trained(tmp_path, 3, -20.0, changed=0)
    line, best = across_seeds([held_low, lost, held_high])
    assert line == (
        "SILI worked in 2 of 3 seeds (held the opponent in 90% or more of its last 50 "
        "interactions and earned more than standing still's -50.0): seed 2 (100%, -30.0 per "
        "interaction), seed 3 (100%, -20.0 per interaction); not seed 0 (0%, -10.0 per "
        "interaction)"
    )
    # the best-earning run that worked: not the best-earning one, nor the first that worked
    assert best == held_high
    capsys.readouterr()
    assert verdict_main([str(lost), str(held_low), str(held_high)]) == 0
    printed = capsys.readouterr()
    assert printed.out.strip() == str(held_high) and printed.err.strip() == line
    assert verdict_main([str(lost)]) == NONE_WORKED  # the first seed's run to look at
    printed = capsys.readouterr()
    assert printed.out.strip() == str(lost) and "SILI worked in 0 of 1 seeds" in printed.err
    short, _ = across_seeds([held_low], window=60)  # not judged on fewer than it reads
    assert short.endswith(
        "not seed 2 (100%, -30.0 per interaction; 50 interactions, too few to tell)"
    )
    assert verdict_main(["--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: python -m sili_robots.verdict RUN_DIR")
    other = tmp_path / "lili"
    args = ["train", "--task", "circle-3", "--method", "lili", "--interactions", "2", "--seed", "0"]
    assert main([*args, "--out", str(other), *FAST_ARGS, "--no-progress"]) == 0
    capsys.readouterr()
    assert verdict_main([str(lost), str(other)]) == 2  # another variant (of the same seed)
    err = capsys.readouterr().err
    assert "is not another seed of" in err and "differ only in the seed" in err
    assert "interactions (" in err and ", method ('sili' vs 'lili')" in err  # top-level first
    driving = tmp_path / "driving"
    args = ["train", "--task", "driving", "--method", "sac", "--interactions", "1"]
    assert main([*args, "--out", str(driving), *FAST_ARGS, "--no-progress"]) == 0
    capsys.readouterr()
    assert verdict_main([str(lost), str(driving)]) == 2
    err = capsys.readouterr().err
    assert "task ('circle-3' vs 'driving')" in err and " more differ (runs judged" in err
    assert verdict_main([str(lost), str(lost)]) == 2  # the same run twice is not two seeds
    assert "seeds [0, 0]: runs judged together are one run per seed" in capsys.readouterr().err
    assert verdict_main([]) == 2  # no traceback, and not "none worked"
    assert "give the run directories to judge together" in capsys.readouterr().err
    assert verdict_main([str(tmp_path)]) == 2
    assert "is not a run directory" in capsys.readouterr().err


def test_seeds_trained_with_another_machines_kernels_are_judged_together(tmp_path):
    first, second = _trained(tmp_path, 0, -20.0, changed=0), _trained(tmp_path, 1, -20.0, 0)
    config = json.loads((second / "config.json").read_text())
    config["run"]["agent"]["matmul"] = (
        "onednn" if config["run"]["agent"]["matmul"] == "aten" else "aten"
    )
    sac = config["run"]["agent"]["sac"]
    sac["precision"] = "float32" if sac["precision"] == "bfloat16" else "bfloat16"
    config["run"]["threads"] = 2
    (second / "config.json").write_text(json.dumps(config))
    line, _ = across_seeds([first, second])
    assert line.startswith("SILI worked in 2 of 2 seeds")


def test_a_window_of_exactly_90_percent_holds_wherever_its_changes_fall():
    """The verdicts' plain mean and first_stable's windows agree at the threshold: 9 kept of 10
    (or 90 of 100) holds, however floating point would sum the window's fractions."""
    from sili_robots.metrics import first_stable

    rng = np.random.default_rng(0)
    for window in (10, 50, 100):
        for _ in range(50):
            stability = np.ones(window)
            stability[rng.choice(window, window // 10, replace=False)] = 0.0
            assert first_stable(stability, window) == 0, stability
    assert first_stable(np.r_[np.zeros(2), np.ones(8)], 10) is None  # 80%


def test_the_command_that_measures_the_references_names_the_arguments_played():
    """Another controller is given as --controller; another value as a shell-safe JSON
    --env-kwarg; an earlier version by its versioned name."""
    from sili_robots.build import make_run_config
    from sili_robots.verdict import _no_reference

    said = {
        ("sawyer-reach", "controller", "osc"): "`sili bounds sawyer-reach --controller osc`",
        ("circle-3-v0", "outside_margin", 0.5): (
            "`sili bounds circle-3-v0 --env-kwarg outside_margin=0.5`"
        ),
        ("speaker-listener", "speaker", (0.5, -1.0)): (
            "`sili bounds speaker-listener --env-kwarg 'speaker=[0.5, -1.0]'`"
        ),
    }
    for (task, key, value), command in said.items():
        cfg = make_run_config(task, "sac", env_kwargs={key: value})
        assert _no_reference(cfg).endswith(f"reward not judged; {command} measures them")
    # as a shell splits it, it runs (one interaction after each game's first)
    assert main([*shlex.split(command.strip("`"))[1:], "--interactions", "2"]) == 0
