"""Benchmark scripts refuse bad input before they measure anything, and read collected runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from benchmark_scripts import run_script
from fast_settings import FAST_ARGS

from sili_robots.cli import main

ROOT = Path(__file__).resolve().parents[1]
COLLECTED_RUN = ROOT / "results" / "main-r-avx2" / "runs" / "circle-3__sili-bschedule__s0"


def test_filter_usage_reads_a_collected_runs_gzipped_metrics() -> None:
    result = run_script("latent_filter_usage", str(COLLECTED_RUN), "--start", "0")
    assert result.returncode == 0, result.stderr  # it read metrics.csv alone
    run, interactions = result.stdout.splitlines()[-1].split()[:2]
    assert run == str(COLLECTED_RUN) and interactions == "1000"


def test_fewer_steps_than_environments_is_refused() -> None:
    result = run_script("bench_env_throughput", "--steps", "3", "--num-envs", "4")
    assert result.returncode == 2  # every vectorised rate was 0 steps/s
    assert "--steps 3 is fewer than --num-envs 4" in result.stderr


def test_an_unknown_memory_config_is_refused_before_the_first_measurement() -> None:
    result = run_script("bench_refresh_memory", "--configs", "continuous,nope")
    assert result.returncode == 2
    assert "unknown config 'nope'; allowed: continuous, filter" in result.stderr
    assert "continuous:" not in result.stdout  # nothing measured (minutes at the default)


def test_grouping_settings_are_checked_before_the_first_fit(tmp_path: Path) -> None:
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--out", str(run), "--no-progress", *FAST_ARGS]
    assert main([*args, "--interactions", "4"]) == 0
    for bad, why in [
        (["--threshold", "-5"], "model.merge_threshold must be >= 0, got -5.0"),
        (["--bonus", "nan"], "model.usage_bonus must be >= 0, got nan"),
    ]:
        result = run_script("bench_latent_grouping", str(run), "--steps", "1", *bad)
        assert result.returncode == 2 and why in result.stderr, result.stderr
        assert "reference" not in result.stdout  # no fit ran
    (run / "checkpoint.pt").unlink()
    result = run_script("bench_latent_grouping", str(run), "--steps", "1")
    assert result.returncode == 2 and "has no checkpoint" in result.stderr


def test_timing_budgets_that_cannot_be_measured_are_refused_before_any_timing() -> None:
    """A Lift block of 0 steps divided by zero, and Lift's timed steps past its horizon failed
    an assert after the rounds before it; one Driving interaction times no reset (0.00 ms)."""
    for args, said in (
        (["--block", "2"], "--block 2: give at least 3"),
        (["--block", "3000", "--rounds", "1"], "must stay under its horizon of 1000"),
        (["--rounds", "10"], "Lift would play 100 x 10 steps"),
    ):
        result = run_script("bench_sawyer_speed", *args)
        assert result.returncode == 2 and said in result.stderr
        assert "machine:" not in result.stdout  # before anything was timed
    result = run_script("bench_driving", "--interactions", "1")
    assert result.returncode == 2 and "give at least 2 (resets are timed)" in result.stderr


def test_the_matmul_timing_names_the_machine_it_ran_on() -> None:
    script = ROOT / "benchmarks" / "bench_sac_speed.py"  # as a user runs it: a process, timed
    result = subprocess.run(
        [sys.executable, str(script), "--matmul-only"], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("machine: ") and "GFLOP/s" in result.stdout


def test_robosuites_lift_logs_nothing_into_the_sawyer_speed_table(capfd) -> None:
    """robosuite's controller loader logged each config file it read, at INFO, between the
    machine line and the table (in process: the whole script takes a minute on 2 busy cores)."""
    from benchmark_scripts import load_script

    step, _, reset_s = load_script("bench_sawyer_speed").lift_blocks(0)
    step(1)
    out, err = capfd.readouterr()
    assert reset_s > 0 and "INFO" not in out + err, out + err
