"""The README's main command end to end (a few interactions): two seeds' verdicts and the line
across them, the pointer to the longer recipe when neither held, and that the recipe it names is a
command that runs."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
from pathlib import Path

from fast_settings import FAST_ARGS

from sili_robots.cli import main
from sili_robots.runs import read_config

ROOT = Path(__file__).resolve().parents[1]


def test_main_job_names_a_working_recipe_when_it_does_not_hold(tmp_path):
    out = tmp_path / "main"
    env = {**os.environ, "SILI_MAIN_INTERACTIONS": "4", "SILI_MAIN_OUT": str(out)}
    done = subprocess.run(
        ["bash", "scripts/main.sh", *FAST_ARGS, "--no-progress"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "SILI ran 4 interactions, too few to tell whether it holds" in done.stderr
    assert "SILI worked in 0 of 2 seeds (held the opponent in 90% or more" in done.stderr
    evaluation = json.loads(done.stdout[done.stdout.rindex('{\n  "run_dir"') :])
    seeds = sorted((out / "runs").iterdir())
    assert [read_config(r).seed for r in seeds] == [0, 1]  # two seeds, one per core
    assert evaluation["run_dir"] == str(seeds[0]) and evaluation["interactions"] == 20
    main_cfg = read_config(seeds[0])  # the main job itself: the delayed b on the small agent
    assert main_cfg.agent.sac.precision == "float32"  # (FAST_ARGS shrink the networks)
    assert main_cfg.agent.sili.beta.points == ((250, 0.0), (300, 0.5))
    recipe = re.search(r"(\.venv/bin/sili train .*?--out \S+)", done.stderr.replace("\n", " "))
    assert recipe, done.stderr[-2000:]
    args = shlex.split(recipe.group(1))[1:]
    assert args[args.index("--interactions") + 1] == "2000"  # the paper grid's budget
    args[args.index("--interactions") + 1] = "3"
    args[args.index("--out") + 1] = str(tmp_path / "recipe")
    assert main([*args, *FAST_ARGS, "--no-progress"]) == 0
    cfg = read_config(tmp_path / "recipe")
    assert cfg.task_id == main_cfg.task_id == "sili/Circle3-v1"  # the main job's own task
    assert cfg.agent.sili.beta.points == ((250, 0.0), (300, 0.5))  # the delayed b
    assert cfg.agent.sac.precision == "float32"  # as the grid ran it


def test_the_main_jobs_output_folder_is_given_by_its_variable_only(tmp_path):
    for option in (["--out", str(tmp_path / "elsewhere")], [f"--ou={tmp_path / 'elsewhere'}"]):
        done = subprocess.run(
            ["bash", "scripts/main.sh", *option],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 2
        assert f"give the output folder as SILI_MAIN_OUT=DIR, not {option[0]}" in done.stderr
    assert not (tmp_path / "elsewhere").exists()


def test_the_main_jobs_dry_run_lists_its_runs_and_trains_nothing(tmp_path):
    out = tmp_path / "main"
    done = subprocess.run(
        ["bash", "scripts/main.sh", "--dry-run"],
        cwd=ROOT,
        env={**os.environ, "SILI_MAIN_OUT": str(out)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.count("circle-3__sili-bschedule") == 2  # its two seeds, one line each
    assert not list(out.glob("runs/*/metrics.csv"))
    assert "does not exist" not in done.stderr  # no verdict on runs that were never trained
    done = subprocess.run(
        ["bash", "scripts/main.sh", "--help"],
        cwd=ROOT,
        env={**os.environ, "SILI_MAIN_OUT": str(tmp_path / "help")},  # no runs there
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0 and "usage: sili sweep" in done.stdout, done.stderr[-2000:]
