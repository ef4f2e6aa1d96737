"""The learning benchmark's table mode refuses folders that hold no runs, with a clear error."""

from __future__ import annotations

import json
import shutil
from argparse import Namespace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from benchmark_scripts import ScriptRun, load_script
from benchmark_scripts import run_script as run_in_process
from fast_settings import FAST_AGENT

FAST_SET = [f"{k}={v}" for k, v in FAST_AGENT.items()]


def run_script(*args: str) -> ScriptRun:
    """``bench_learning.py ARGS``, in this process (an exception, a traceback, is raised)."""
    return run_in_process("bench_learning", *args)


def test_from_runs_without_runs_exits_2_and_says_why(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()  # a sweep folder: its runs sit one level down
    result = run_script("--from-runs", str(tmp_path))
    assert result.returncode == 2
    assert "no finished runs" in result.stderr and "runs/ folder" in result.stderr


def test_from_runs_missing_folder_exits_2(tmp_path: Path) -> None:
    result = run_script("--from-runs", str(tmp_path / "absent"))
    assert result.returncode == 2
    assert "not a folder" in result.stderr


def test_damaged_files_of_a_run_are_named_not_a_traceback(tmp_path: Path) -> None:
    collected = Path(__file__).resolve().parents[1] / "results" / "main-r-avx2" / "runs"
    run = tmp_path / "runs" / "r0"
    shutil.copytree(collected / "circle-3__sili-bschedule__s0", run)
    assert run_script("--from-runs", str(tmp_path / "runs")).returncode == 0  # a collected run
    for name, text, why in [
        ("summary.json", "{bad", "summary.json is damaged (JSONDecodeError"),
        ("summary.json", "{}", "summary.json is damaged (no final_task_reward"),
        ("config.json", "{bad", "config.json is damaged (JSONDecodeError"),
    ]:
        kept = (run / name).read_text()
        (run / name).write_text(text)
        result = run_script("--from-runs", str(tmp_path / "runs"))
        assert result.returncode == 2 and why in result.stderr, result.stderr
        (run / name).write_text(kept)
    out = tmp_path / "out" / "circle-3-sili-s0"  # where --out would train seed 0
    out.mkdir(parents=True)
    for name in ("config.json", "summary.json"):  # named before any run trains
        (out / name).write_text("{bad")
        both = ["--methods", "sili", "--seeds", "0,1", "--interactions", "2"]
        result = run_script(*both, "--out", str(out.parent))
        assert result.returncode == 2 and f"{name} is damaged" in result.stderr
        assert not (out.parent / "circle-3-sili-s1").exists()  # seed 1 did not train first
        (out / name).unlink()


def test_a_method_given_twice_is_refused_before_training(tmp_path: Path) -> None:
    result = run_script("--methods", "sili,sac,sili", "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert "--methods sili,sac,sili: sili given twice" in result.stderr
    assert not (tmp_path / "out").exists()


def test_run_one_resumes_and_extends_a_recorded_run(tmp_path: Path) -> None:
    """A recorded run is continued with --resume alone (sili train refuses --task with it)."""
    bench = load_script("bench_learning")
    args = Namespace(out=str(tmp_path), interactions=2, latent=None, set=FAST_SET)
    run = bench.run_one("circle-3", "sac", 0, args)
    args.interactions = 3
    assert bench.run_one("circle-3", "sac", 0, args) == run
    assert json.loads((run / "summary.json").read_text())["interactions"] == 3
    # a shorter budget on the same folder is refused before anything runs, never shortened
    shorter = ["--task", "circle-3", "--methods", "sac", "--seeds", "0", "--out", str(tmp_path)]
    result = run_script(*shorter, "--interactions", "2")
    assert result.returncode == 2 and "is set to 3" in result.stderr
    # other settings on the same folder: refused, not the recorded run reused as if it had them
    sets = [x for item in FAST_SET for x in ("--set", item)]
    result = run_script(*shorter, "--interactions", "3", *sets, "--set", "sac.lr=0.01")
    assert result.returncode == 2 and "holds a run of other settings (agent.sac.lr" in result.stderr
    assert run_script(*shorter, "--interactions", "3", *sets).returncode == 0  # its own: reused
    result = run_script(*shorter, "--interactions", "3", *sets, "--set", "sac.precision=bfloat16")
    assert result.returncode == 2  # a machine's setting, given, is checked as any other
    assert "(agent.sac.precision: 'float32' there, 'bfloat16' asked)" in result.stderr


def test_seeds_trained_on_other_kernels_are_one_configuration() -> None:
    bench = load_script("bench_learning")
    run = {"task": "circle-3", "seed": 0, "threads": 1, "agent": {"matmul": "aten", "hidden": 8}}
    other = {**run, "seed": 1, "threads": 2, "agent": {"matmul": "onednn", "hidden": 8}}
    wider = {**run, "agent": {"matmul": "aten", "hidden": 16}}
    assert bench.variant_of(run) == bench.variant_of(other) != bench.variant_of(wider)


def _rows(*rows: tuple[str, str, float, float, str]) -> pd.DataFrame:
    cols = ["task", "method", "final_task_reward", "final_stability", "variant"]
    return pd.DataFrame(rows, columns=cols)


def test_targets_are_judged_per_task_and_configuration() -> None:
    check = load_script("bench_learning").check_targets
    same = [("c", "sili", -5.0, 1.0, "a"), ("c", "oracle", -4.5, 1.0, "o")]
    met = check(_rows(*same, ("c", "sili", -5.0, 0.95, "a")))
    assert [m for _, m, _ in met] == [True, True]
    assert "2 of 2" in met[0][2]
    # a second configuration of SILI in the folder: nothing is averaged across them
    mixed = check(_rows(*same, ("c", "sili", -50.0, 0.0, "b")))
    assert len(mixed) == 1 and mixed[0][1] is None and "sili" in mixed[0][2]
    # two tasks are judged apart: the Driving rows do not join Circle's
    two = check(_rows(*same, ("d", "sili", -0.2, 1.0, "x"), ("d", "oracle", 0.0, 1.0, "y")))
    assert [w.split(":")[0] for w, _, _ in two] == ["c", "c", "d", "d"]
    # Oracle's reward of 0 is no cost to take 15% of: not judged, never "met"
    assert two[3][1] is None and "not judged" in two[3][2]


def test_two_thirds_of_the_seeds_must_hold() -> None:
    check = load_script("bench_learning").check_targets
    seeds = [("c", "sili", -5.0, s, "a") for s in (1.0, 1.0, 0.2, 0.1, 1.0)]
    (held,) = check(_rows(*seeds))
    assert held[1] is False and "3 of 5" in held[2] and "(4 of 5)" in held[0]


def test_stable_by_is_the_interaction_ending_the_first_held_window() -> None:
    """The game's first interaction (no strategy before it to keep) is in no window."""
    bench = load_script("bench_learning")
    changed = [0] * 30 + [1] + [0] * 99
    df = pd.DataFrame({"interaction": range(130), "strategy_changed": changed})
    assert bench.stable_by(df, 10) == 10  # interactions 1..10
    assert bench.stable_by(df, 100) == 100  # 99 of interactions 1..100 kept
    assert bench.stable_by(df[:100], 100) != bench.stable_by(df[:100], 100)  # 0 is in no window
    df["strategy_changed"] = [i % 5 == 0 for i in range(130)]  # 80% kept
    assert np.isnan(bench.stable_by(df, 10))


def test_out_that_is_a_file_is_refused_before_training(tmp_path: Path) -> None:
    taken = tmp_path / "notes.txt"
    taken.write_text("mine")
    for out in (taken, taken / "sub"):  # a folder inside a file cannot be made either
        result = run_script(
            "--methods", "sac", "--seeds", "0", "--interactions", "2", "--out", str(out)
        )
        assert result.returncode == 2
        assert f"--out {out}: {taken} is not a folder" in result.stderr
        assert taken.read_text() == "mine"


def test_a_failed_run_shows_the_trainers_error_as_text(tmp_path: Path) -> None:
    bench = load_script("bench_learning")
    args = Namespace(out=str(tmp_path), interactions=2, latent=None, set=["no_such_setting=1"])
    with pytest.raises(SystemExit) as failed:
        bench.run_one("circle-3", "sac", 0, args)
    message = str(failed.value.code)
    # the trainer's own line, not a bytes object's repr (b"sili train: ...")
    assert "sili train failed:\nsili train: error: unknown setting 'no_such_setting'" in message
