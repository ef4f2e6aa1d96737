"""``sili bounds``: the scripted policies' reward and true stability per task, the packaged
bounds file ``sili plot`` draws from, and the bound lines in the figures."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from cli_helpers import sili as sili_in_process
from matplotlib.collections import LineCollection

from sili_robots.bounds import (
    BOUNDS_FILE,
    compute_bounds,
    format_table,
    read_bounds_file,
    stored_bounds,
)
from sili_robots.cli import main
from sili_robots.plotting import beta_sweep, learning_curves, overview
from sili_robots.tasks import TASKS
from sili_robots.tasks.registry import all_versions, other_task_arguments, title_arguments

REQUIRED = ("random", "still", "oracle", "stabilizing")


def test_json_output_has_the_four_bounds_and_matches_the_policies(capsys):
    assert main(["bounds", "circle-3", "--interactions", "6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["task"] == "circle-3" and out["task_id"] == "sili/Circle3-v1"
    assert (out["interactions"], out["seed"]) == (6, 0) and out["games"] >= 1  # self-describing
    bounds = out["bounds"]
    assert set(REQUIRED) <= set(bounds) and set(bounds) <= {*REQUIRED, "blind", "tracking"}
    for b in bounds.values():
        assert set(b) == {"task_reward", "stability"} and 0.0 <= b["stability"] <= 1.0
    assert bounds["still"] == {"task_reward": -50.0, "stability": 0.0}  # 1 away for 50 steps
    assert bounds["stabilizing"]["stability"] == 1.0 and bounds["oracle"]["stability"] == 0.0
    assert bounds["oracle"]["task_reward"] > -5 > -45 > bounds["random"]["task_reward"]


def test_table_output_names_every_policy(capsys):
    assert main(["bounds", "sili/CircleUnequal-v0", "--interactions", "4", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "circle-unequal-v0 (sili/CircleUnequal-v0): 4 interactions in 2 games from seed 3" in out
    for kind in (*REQUIRED, "blind", "tracking"):
        assert f"\n  {kind} " in out


@pytest.mark.parametrize("task", [t for t in TASKS if t != "driving"])
def test_bounds_work_for_every_task(task):
    result = compute_bounds(task, interactions=4, games=2)
    assert set(REQUIRED) <= set(result["bounds"])
    assert result["interactions"] == 4 and result["games"] == 2


def test_bounds_work_for_driving_in_its_own_process():
    """libsumo runs one simulation per process: Driving's bounds get a process of their own."""
    args = ["bounds", "driving", "--interactions", "4", "--json"]
    out = subprocess.run(
        [sys.executable, "-m", "sili_robots.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    bounds = json.loads(out.stdout)["bounds"]
    assert set(bounds) == set(REQUIRED)
    assert bounds["oracle"]["task_reward"] == 0.0  # the oracle never collides


@pytest.mark.parametrize(
    "args, message",
    [
        (["nope"], "unknown task 'nope'; allowed: circle-3"),
        (["circle-3", "--interactions", "0"], "--interactions must be an integer in [2, 2147"),
        (["circle-3", "--interactions", "-3"], "got '-3'"),
        (["circle-3", "--interactions", "1e20"], "got '1e20'"),
        (["circle-3", "--interactions", "10" * 10], "got '1010101010"),  # it ran until killed
        (["circle-3", "--games", "0"], "--games must be an integer in [1, 2147483647], got '0'"),
        (["circle-3", "--games", "3" + "0" * 9], "got '3000000000'"),
        (  # the second game's seed would be 2**32, not a seed
            ["circle-3", "--interactions", "4", "--games", "2", "--seed", "4294967295"],
            "--seed 4294967295 gives 2 games the seeds 4294967295 to 4294967296, past the largest "
            "seed 4294967295: give --seed 4294967294 or lower, or fewer --games",
        ),
        (
            ["circle-3", "--seed", "4294967290"],
            "gives 12 games the seeds 4294967290 to 4294967301"
            ", past the largest seed 4294967295: give --seed 4294967284 or lower, or --games 6 or",
        ),
        (  # before any task's games: circle-3's 12 fit and were played and printed first
            ["--all", "--interactions", "40", "--seed", "4294967284", "--json"],
            "gives 16 games the seeds 4294967284 to 4294967299",  # circle-8's
        ),
        (["circle-3", "--games", "-1"], "got '-1'\n"),  # the user's count, not the default's
        (["circle-3", "--interactions", "4", "--games", "3"], "must be >= 6 for 3 games"),
        ([], "give either a TASK (e.g. circle-3) or --all"),
    ],
)
def test_bad_input_exits_2_with_one_line(args, message):
    done = sili_in_process("bounds", *args)  # argparse's errors too
    err = done.stderr
    assert done.returncode == 2 and err.startswith("sili bounds: error: ") and message in err
    assert len(err.strip().splitlines()) == 1 and done.stdout == ""


def test_packaged_bounds_cover_every_version_and_agree_with_a_fresh_run():
    data = read_bounds_file()
    assert data["command"] == "sili bounds --all --write"
    assert set(data["tasks"]) == {s.gym_id for s in all_versions()}
    for entry in data["tasks"].values():
        assert set(REQUIRED) <= set(entry["bounds"])
    stored = data["tasks"]["sili/Circle3-v1"]
    fresh = compute_bounds("circle-3", stored["interactions"], stored["seed"], stored["games"])
    assert fresh == stored


def test_the_packaged_bounds_show_what_each_v1_makes_possible():
    def b(task_id, kind):
        return stored_bounds(task_id)[kind]

    assert b("sili/Circle3-v1", "oracle")["stability"] <= 0.5  # v0: 1.0
    assert b("sili/Circle3-v0", "oracle")["stability"] == 1.0
    assert b("sili/Circle3-v1", "stabilizing")["stability"] == 1.0
    for kind in ("still", "random"):
        assert b("sili/SawyerReach-v1", kind)["stability"] <= 0.5
    assert b("sili/SawyerReach-v1", "stabilizing")["stability"] == 1.0
    unequal = "sili/CircleUnequal-v1"
    assert b(unequal, "blind")["task_reward"] > b(unequal, "tracking")["task_reward"]
    assert b("sili/SpeakerListener-v1", "stabilizing")["stability"] == 1.0
    assert stored_bounds("sili/Nope-v3") == {}


def test_write_adds_to_a_bounds_file(tmp_path, capsys):
    path = tmp_path / "bounds.json"
    assert main(["bounds", "circle-3", "--interactions", "4", "--write", str(path)]) == 0
    assert main(["bounds", "sili/Circle3-v0", "--interactions", "4", "--write", str(path)]) == 0
    data = json.loads(path.read_text())
    assert set(data["tasks"]) == {"sili/Circle3-v0", "sili/Circle3-v1"}
    assert data["command"] == f"sili bounds circle-3-v0 --interactions 4 --write {path}"
    assert f"wrote {path}" in capsys.readouterr().err  # stdout: the results alone
    args = ["bounds", "circle-3", "--interactions", "4", "--json", "--write", str(path)]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["task"] == "circle-3"  # one JSON document
    assert BOUNDS_FILE.is_file()
    packaged = BOUNDS_FILE.read_bytes()
    try:
        for counts in (["--interactions", "4"], ["--games", "3"], ["--seed", "1"]):
            assert main(["bounds", "circle-3", *counts, "--write"]) == 2
            err = capsys.readouterr().err
            assert "are measured at the default counts" in err and f"with {' '.join(counts)}" in err
    finally:  # a broken refusal must not leave the package's own file rewritten
        written = BOUNDS_FILE.read_bytes()
        if written != packaged:
            BOUNDS_FILE.write_bytes(packaged)
    assert written == packaged
    from argparse import Namespace

    from sili_robots.commands.bounds import _check_packaged_counts
    from sili_robots.errors import ConfigError
    from sili_robots.tasks import task_spec

    default = Namespace(write=str(BOUNDS_FILE), interactions="1000", games="12", seed=0)
    _check_packaged_counts(default, [task_spec("circle-3")])  # the defaults, typed: taken
    with pytest.raises(ConfigError, match="with --games 12 give"):  # Circle 8's is 16
        _check_packaged_counts(default, [task_spec("circle-8")])


# -- the bound lines in the figures -----------------------------------------------------------
def _results(task, task_id, n=20, method="sac"):
    rng = np.random.default_rng(0)
    rows = []
    for seed in (0, 1):
        for i in range(n):
            rows.append(
                {
                    "run": f"{task}__{method}__s{seed}",
                    "task": task,
                    "task_id": task_id,
                    "method": method,
                    "latent": "discrete",
                    "seed": seed,
                    "controller": "",
                    "config_beta": 0.0,
                    "interaction": i,
                    "task_reward": -20 + i + rng.normal(),
                    "stability_reward": 0.0,
                    "true_stability": float(rng.random() < 0.5),
                }
            )
    return pd.DataFrame(rows)


def _bound_lines(ax):
    out = {}
    for c in ax.collections:
        if isinstance(c, LineCollection) and c.get_gid() == "bound":
            (segment,) = c.get_segments()
            assert segment[0][1] == segment[1][1]  # horizontal
            out[c.get_label()] = segment[0][1]
    return out


@pytest.mark.parametrize(
    "task, task_id", [("circle-3", "sili/Circle3-v1"), ("circle-3", "sili/Circle3-v0")]
)
def test_learning_curves_draw_the_bounds_of_the_runs_task_version(task, task_id):
    stored = stored_bounds(task_id)
    fig = learning_curves(_results(task, task_id), task, smooth=2)
    axes = {ax.get_gid(): ax for ax in fig.axes}
    for metric, key in (("task_reward", "task_reward"), ("true_stability", "stability")):
        drawn = _bound_lines(axes[metric])
        assert drawn == {f"bound: {k}": v[key] for k, v in stored.items()}
        lo, hi = axes[metric].get_ylim()
        assert all(lo <= y <= hi for y in drawn.values())  # every bound is in view
        labels = " ".join(t.get_text() for t in axes[metric].texts if t.get_gid() == "bound_label")
        for kind, values in stored.items():  # every bound named, with its value
            assert kind in labels and f"{values[key]:.2f}" in labels
    assert _bound_lines(axes["stability_reward"]) == {}
    assert task_id in fig.get_suptitle()
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "SAC" in legend and "bound: oracle" in legend


def test_results_of_two_versions_get_both_bounds_labelled_and_overview_draws_them():
    old, new = "sili/Circle3-v0", "sili/Circle3-v1"
    df = pd.concat(
        [_results("circle-3", old), _results("circle-3", new, method="lili")], ignore_index=True
    )
    fig = learning_curves(df, "circle-3", smooth=2)
    drawn = _bound_lines(fig.axes[0])
    assert drawn["bound: oracle (v0)"] == stored_bounds(old)["oracle"]["task_reward"]
    assert drawn["bound: oracle (v1)"] == stored_bounds(new)["oracle"]["task_reward"]
    sawyer = "sili/SawyerReach-v1"
    grid = overview(_results("sawyer-reach", sawyer)).axes
    assert set(_bound_lines(grid[0])) == {f"bound: {k}" for k in stored_bounds(sawyer)}


def test_runs_of_two_versions_of_a_task_are_never_averaged_together():
    old, new = "sili/Circle3-v0", "sili/Circle3-v1"
    v0 = _results("circle-3", old)
    v1 = _results("circle-3", new).assign(run=lambda d: d.run + "-new", task_reward=-40.0)
    fig = learning_curves(pd.concat([v0, v1], ignore_index=True), "circle-3", smooth=1)
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "SAC (v0)" in legend and "SAC (v1)" in legend
    reward = {line.get_label(): line.get_ydata() for line in fig.axes[0].get_lines()}
    assert np.allclose(reward["SAC (v1)"], -40.0)  # not pulled towards the v0 runs


# -- runs given other task arguments ------------------------------------------------------------
def test_other_task_arguments_are_those_the_version_does_not_build_by_default():
    v1, v0 = "sili/SawyerReach-v1", "sili/SawyerReach-v0"
    assert other_task_arguments(v1, {"controller": "mink"}) == {}  # the constructor's default
    assert other_task_arguments(v1, {"start_z": 0.9}) == {}  # the version's own argument
    assert other_task_arguments(v0, {"start_z": 0.9}) == {"start_z": 0.9}
    assert other_task_arguments(v1, {"controller": "osc"}) == {"controller": "osc"}
    assert other_task_arguments("my_tasks:Task", {"n": 1}) == {"n": 1}  # not registered
    assert other_task_arguments("sili/Driving-v0", {"backend": "traci"}) == {}  # same SUMO
    assert other_task_arguments("sili/Driving-v0", {"horizon": 5}) == {"horizon": 5}


def test_runs_given_another_controller_get_no_bounds_and_a_curve_of_their_own():
    sawyer = "sili/SawyerReach-v1"
    mink = _results("sawyer-reach", sawyer)
    osc = _results("sawyer-reach", sawyer).assign(
        run=lambda d: d.run + "-osc", controller="osc", task_args='{"controller": "osc"}'
    )
    both = learning_curves(pd.concat([mink, osc], ignore_index=True), "sawyer-reach", smooth=1)
    ax = {a.get_gid(): a for a in both.axes}["task_reward"]
    assert {line.get_label() for line in ax.get_lines()} == {"SAC [default]", "SAC [osc]"}
    assert set(_bound_lines(ax)) == {f"bound: {k}" for k in stored_bounds(sawyer)}  # mink's
    assert f"{sawyer} (its default task arguments)" in both.get_suptitle()
    said = [t.get_text() for t in ax.texts if t.get_gid() == "bound_label"]
    assert said and all("[default task args]" in t for t in said)  # on the panel, as overview
    assert all(
        "[default" not in t.get_text() for t in learning_curves(mink, "sawyer-reach").axes[0].texts
    )
    alone = learning_curves(osc, "sawyer-reach", smooth=1)
    assert _bound_lines(alone.axes[0]) == {} and "scripted policies" not in alone.get_suptitle()
    assert alone.get_suptitle().startswith("Sawyer-Reach (controller=osc): ")
    assert alone.get_suptitle().endswith(
        "no bounds: they were measured with the task's default arguments"
    )


def test_runs_given_another_task_argument_are_not_averaged_with_the_default_ones():
    v1 = "sili/Circle3-v1"
    wide = _results("circle-3", v1).assign(
        run=lambda d: d.run + "-wide", task_args='{"outside_margin": 0.3}', task_reward=-40.0
    )
    df = pd.concat([_results("circle-3", v1), wide], ignore_index=True)
    ax = learning_curves(df, "circle-3", smooth=1).axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert set(lines) == {"SAC", "SAC [outside_margin=0.3]"}
    assert (lines["SAC [outside_margin=0.3]"].get_ydata() == -40.0).all()


def test_a_table_from_before_task_arguments_were_recorded_reads_them_from_the_controller():
    sawyer = "sili/SawyerReach-v1"
    osc = _results("sawyer-reach", sawyer).assign(controller="osc")  # no task_args column
    assert _bound_lines(learning_curves(osc, "sawyer-reach", smooth=1).axes[0]) == {}
    mink = _results("sawyer-reach", sawyer).assign(controller="mink")
    drawn = _bound_lines(learning_curves(mink, "sawyer-reach", smooth=1).axes[0])
    assert set(drawn) == {f"bound: {k}" for k in stored_bounds(sawyer)}


def test_the_b_sweep_draws_a_line_per_task_arguments():
    parts = []
    for margin, args in ((0.1, ""), (0.3, '{"outside_margin": 0.3}')):
        for b in (0.0, 0.5):
            parts.append(
                _results("circle-3", "sili/Circle3-v1", method="sili").assign(
                    run=lambda d, m=margin, b=b: d.run + f"-b{b}-m{m}",
                    config_beta=b,
                    beta_scheduled=False,
                    profile="package",
                    task_args=args,
                    task_reward=-10.0 if args else -20.0,
                )
            )
    fig = beta_sweep(pd.concat(parts, ignore_index=True), "circle-3", window=5)
    ax = {a.get_gid(): a for a in fig.axes}["task_reward"]
    lines = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
    lines.pop("_nolegend_", None)  # the error bars' caps
    assert lines.keys() == {"SILI", "SILI [outside_margin=0.3]"}
    assert list(lines["SILI [outside_margin=0.3]"]) == [-10.0, -10.0]


def test_a_bounds_table_names_the_controller_even_at_its_default():
    """An ablation's tables side by side say which controller each measured; other tasks (and
    a user's class) name only the arguments given."""
    mink = {"task": "sawyer-reach", "task_id": "sili/SawyerReach-v1", "bounds": {}}
    mink |= {"interactions": 4, "games": 2, "seed": 0}
    osc = mink | {"task_args": {"controller": "osc"}}
    assert format_table(mink).startswith("sawyer-reach (sili/SawyerReach-v1, controller='mink'):")
    assert format_table(osc).startswith("sawyer-reach (sili/SawyerReach-v1, controller='osc'):")
    circle = mink | {"task": "circle-3", "task_id": "sili/Circle3-v1"}
    assert format_table(circle).startswith("circle-3 (sili/Circle3-v1): 4 interactions")
    assert title_arguments("sili/SawyerReach-v0", {"horizon": 9}) == {
        "controller": "mink",
        "horizon": 9,
    }
    doors = "sili_robots.examples.two_doors:TwoDoorsEnv"
    assert title_arguments(doors, {"horizon": 9}) == {"horizon": 9}


def test_bounds_of_another_controller_are_its_own_and_never_stored(tmp_path):
    """A controller ablation's references: measured with the controller asked for."""
    small = ["sawyer-reach", "--interactions", "4", "--games", "2", "--json"]
    mink, osc = (sili_in_process("bounds", *small, "--controller", c) for c in ("mink", "osc"))
    assert mink.returncode == osc.returncode == 0, osc.stderr
    mink, osc = json.loads(mink.stdout), json.loads(osc.stdout)
    assert osc["task_args"] == {"controller": "osc"}  # said with the numbers
    # OSC's target leads by at most 5 cm, so its greedy chase is slower than mink's
    assert osc["bounds"]["oracle"]["task_reward"] < mink["bounds"]["oracle"]["task_reward"] - 1
    for args, said in (
        (["--all", "--controller", "osc"], "apply to one TASK, not to --all"),
        (
            ["sawyer-reach", "--controller", "osc", "--write", str(tmp_path / "b.json")],
            "--write stores each task version at its default arguments, not controller='osc';",
        ),
        (["circle-3", "--controller", "osc"], "task 'circle-3' takes no argument controller"),
    ):
        done = sili_in_process("bounds", *args)
        assert done.returncode == 2 and said in done.stderr, done.stderr
    assert not (tmp_path / "b.json").exists()


def test_bounds_all_write_keeps_the_tasks_done_when_stopped(tmp_path, monkeypatch):
    """`sili bounds --all --write` takes minutes: a Ctrl-C on a late task keeps the earlier ones."""
    import sili_robots.bounds as bounds

    measured = []

    def stopped_on_the_third(task_id, *args, **kwargs):
        if len(measured) == 2:
            raise KeyboardInterrupt
        measured.append(task_id)
        return real(task_id, *args, **kwargs)

    real = bounds.compute_bounds
    monkeypatch.setattr(bounds, "compute_bounds", stopped_on_the_third)
    path = tmp_path / "b.json"
    args = ["bounds", "--all", "--interactions", "2", "--games", "1", "--write", str(path)]
    assert main(args) == 130
    assert sorted(json.loads(path.read_text())["tasks"]) == sorted(measured)


def test_a_task_taken_by_write_as_its_file_is_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for args, said in (
        (["--write", "circle-3"], "--write took 'circle-3' as its FILE: give TASK before --write"),
        (["--write"], "or --all, not both or neither\n"),
        (["circle-3", "--all"], "or --all, not both or neither\n"),
        (["--all", "--games", "600"], "got 1000 (circle-3's default); give --interactions\n"),
    ):
        done = sili_in_process("bounds", *args)
        assert done.returncode == 2 and said in done.stderr, done.stderr
    assert not (tmp_path / "circle-3").exists()


@pytest.mark.parametrize(
    ("seed", "said"), [(-1, "seed -1 is not allowed"), (1.5, "seed 1.5 is not")]
)
def test_compute_bounds_checks_its_seed_as_the_cli_does(seed, said):
    from sili_robots.errors import ConfigError

    with pytest.raises(ConfigError, match=said):  # 1.5 was taken as 1
        compute_bounds("circle-3", 2, seed, 1)


def test_the_default_games_stay_a_multiple_of_the_strategies_when_interactions_are_few():
    """Every first strategy as often as the others: 9 games of Circle (3 Goals) in 20
    interactions, not 10."""
    from sili_robots.bounds import check_counts, default_games

    assert check_counts(20, None, 3) == (20, 9)
    assert check_counts(30, None, 8) == (30, 8)
    assert default_games("circle-3", 20) == 9


def test_a_bound_with_a_value_that_is_not_finite_is_not_drawn(tmp_path):
    from sili_robots.bounds import write_bounds_file

    path = tmp_path / "bounds.json"
    bounds = {
        "random": {"task_reward": -5.0, "stability": float("nan")},
        "still": {"task_reward": -3.0, "stability": 1.0},
    }
    write_bounds_file([{"task_id": "sili/Circle3-v1", "bounds": bounds}], path)
    assert set(stored_bounds("sili/Circle3-v1", path)) == {"still"}


def test_the_recorded_command_keeps_a_seed_other_than_the_default(tmp_path):
    """A bounds file records the command that wrote it, with every count and seed it was given."""
    path = tmp_path / "bounds.json"
    args = ["bounds", "circle-3", "--interactions", 4, "--games", 2, "--seed", 7]
    out = sili_in_process(*args, "--write", path)
    assert out.returncode == 0, out.stderr
    data = json.loads(path.read_text())
    assert data["command"] == (
        f"sili bounds circle-3 --interactions 4 --games 2 --seed 7 --write {path}"
    )
    assert data["tasks"]["sili/Circle3-v1"]["seed"] == 7
