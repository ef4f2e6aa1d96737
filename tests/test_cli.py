"""The ``sili`` command line: bad input exits 2 with a message; good input prints a result."""

import argparse
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_helpers import sili as sili_in_process
from fast_settings import FAST_ARGS

from sili_robots.agent.config import LARGEST_INT
from sili_robots.commands.common import NAME_MAX, counted, path_arg, positive_int, threads_arg
from sili_robots.commands.sweep import ray_address
from sili_robots.policies import scripted_policy
from sili_robots.rollout import run_interactions
from sili_robots.runs import MAX_THREADS
from sili_robots.tasks import make_task

GRID = Path(__file__).resolve().parents[1] / "results" / "paper-grid"
MAIN_JOB = GRID.parent / "main-job-zen4"  # a collection of two finished runs


def _sili(*args):
    return subprocess.run(
        [sys.executable, "-m", "sili_robots.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_rollout_prints_result():
    out = _sili("rollout", "circle-3", "--interactions", "5")
    assert out.returncode == 0, out.stderr
    assert "unchanged (after the first): 1.000" in out.stdout


def test_version_and_an_options_own_arguments_in_its_usage():
    import sili_robots

    assert sili_in_process("--version").stdout.strip() == f"sili {sili_robots.__version__}"
    usage = sili_in_process("train", "--help").stdout
    assert "--beta-anneal START END LENGTH [DELAY]\n" in usage  # one segment, not nargs' "..."
    assert "[DELAY] [START" not in usage


def test_unknown_task_exits_2_with_choices():
    out = _sili("rollout", "circle-4")
    assert out.returncode == 2
    assert "unknown task 'circle-4'" in out.stderr and "circle-3" in out.stderr
    assert "Traceback" not in out.stderr


def test_non_positive_count_exits_2():
    out = _sili("rollout", "circle-3", "--interactions", "0")
    assert out.returncode == 2 and "need an integer >= 1" in out.stderr


def test_a_parse_error_is_one_line_naming_the_value_and_the_choices():
    out = _sili("train", "--task", "circle-3", "--method", "foo")
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()  # no usage block before it
    assert (
        line.startswith("sili train: error:")
        and "'foo'" in line
        and "sili" in line.split("'foo'")[1]
    )


def test_bad_input_a_user_types_names_the_command_the_value_and_what_is_allowed(tmp_path):
    (tmp_path / "a-file").write_text("")
    (tmp_path / "notes.html").write_text("<html>mine</html>")
    for args, line in (
        (
            ["bounds", "driving", "--policy", "x"],  # an argument the sub-command does not take
            "sili bounds: error: unrecognized arguments: --policy x (see sili bounds --help)",
        ),
        (
            ["--policy", "bounds", "driving"],  # one before the sub-command is sili's own
            "sili: error: unrecognized arguments: --policy (see sili --help)",
        ),
        (
            ["train", "--resume", str(tmp_path / "nowhere")],
            f"sili train: error: {tmp_path / 'nowhere'} does not exist; give a run directory",
        ),
        (
            ["train", "--task", "circle-3", "--out", str(tmp_path / "a-file")],
            f"sili train: error: {tmp_path / 'a-file'} is a file; give --out a directory",
        ),
        (
            ["train", "--task", "circle-3", "--controller", "osc", "--out", str(tmp_path / "r")],
            "sili train: error: task 'circle-3' takes no argument controller (--controller, "
            "--env-kwarg); its arguments: horizon, outside_margin, near_moves (variant is fixed by "
            "the name)",
        ),
        (
            ["rollout", "driving", "--policy", "blind", "--interactions", "1"],
            "sili rollout: error: no 'blind' policy for sili/Driving-v0; allowed there: ",
        ),
        (
            ["rollout", DOORS, "--policy", "oracle", "--interactions", "1"],
            "sili rollout: error: no 'oracle' policy for TwoDoorsEnv; allowed there: random, still",
        ),
        (
            ["bounds", DOORS],  # references are stored for the registered tasks
            f"sili bounds: error: argument task: {DOORS!r} is a task class; sili bounds plays the "
            "registered tasks' scripted policies; on a task class, sili rollout TASK --policy",
        ),
        (
            ["preview", "circle-3", "--out", str(tmp_path / "notes.html")],  # not a preview's
            f"sili preview: error: --out {tmp_path / 'notes.html'} exists and is not a preview;",
        ),
        (
            ["preview", "circle-3", "--out", str(tmp_path / "a-file")],
            f"sili preview: error: --out {tmp_path / 'a-file'}: give a file name ending in .html",
        ),
        (
            ["preview", "circle-3", "--png", str(tmp_path / "p.jpg")],
            f"sili preview: error: --png {tmp_path / 'p.jpg'}: give a file name ending in .png",
        ),
        (
            ["eval", ""],  # an unset variable, say: not the current directory
            "sili eval: error: argument run_dir: an empty path; give a directory or file name",
        ),
        (
            ["train", "--task", "circle-3", "--interactions", "99999999999999999999"],
            "sili train: error: argument --interactions: 99999999999999999999 is not allowed: "
            "need an integer <= 2147483647",
        ),
        (
            ["train", "--task", "circle-3", "--threads", "1025"],  # OpenMP dies on far more
            "sili train: error: argument --threads: 1025 is not allowed: need an integer <= 1024",
        ),
        (
            ["plot", str(tmp_path), "--smooth", str(2**63)],
            f"sili plot: error: argument --smooth: {2**63} is not allowed: need an integer <= "
            "2147483647",
        ),
        (
            ["eval", "~nosuchuser-sili/run"],  # the shell leaves ~NAME of no user as it is
            "sili eval: error: argument run_dir: ~nosuchuser-sili/run: '~nosuchuser-sili' names no "
            "user with a home on this machine",
        ),
        (
            ["bounds", "circle-3", "--write", ""],  # before its games, not a table and no file
            "sili bounds: error: argument --write: an empty path; give a directory or file name",
        ),
        (
            ["train", "--task", "circle-3", "--beta-schedule", "", "--out", str(tmp_path / "r")],
            "sili train: error: --beta-schedule '': '' is not INTERACTION:VALUE",
        ),
        (
            ["preview", DOORS],
            f"sili preview: error: argument task: {DOORS!r} is a task class; sili preview draws",
        ),
        (
            ["train", "--task", "examples/two_doors.py:TwoDoorsEnv"],  # a path, not a module
            "sili train: error: argument --task: unknown task 'examples/two_doors.py:TwoDoorsEnv'"
            "; allowed: circle-3, ",
        ),
    ):
        done = sili_in_process(*args)
        assert done.returncode == 2 and done.stderr.startswith(line), (args, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()
    assert (tmp_path / "notes.html").read_text() == "<html>mine</html>"
    done = sili_in_process("train", "--task", "x/y:Z")
    assert "; or a task class of your own as package.module:ClassName" in done.stderr
    done = sili_in_process("rollout", DOORS, "--policy", "still", "--interactions", "3")
    assert done.returncode == 0 and "task reward per interaction (after the first): " in done.stdout
    done = sili_in_process("rollout", "circle-3", "--policy", "random", "--interactions", "3")
    env = make_task("circle-3")
    played = run_interactions(env, scripted_policy(env, "random"), 3, seed=0)
    env.close()
    later = np.mean([s.task_reward for s in played[1:]])  # as sili bounds counts
    assert f"mean task reward per interaction (after the first): {later:.3f}" in done.stdout
    assert abs(later - np.mean([s.task_reward for s in played])) > 1e-3  # the first differs
    done = sili_in_process(
        "rollout", "circle-3", "--env-kwarg", "horizon=10", "--interactions", "2"
    )
    assert done.returncode == 0 and "task=circle-3 horizon=10 policy=stabilizing" in done.stdout
    done = sili_in_process("rollout", "circle-3", "--controller", "osc")
    assert done.returncode == 2 and "task 'circle-3' takes no argument controller" in done.stderr


DOORS = "sili_robots.examples.two_doors:TwoDoorsEnv"


def _main(*args: str) -> tuple[int, str, str]:
    res = sili_in_process(*args)
    return res.returncode, res.stdout, res.stderr


@pytest.mark.parametrize("bad", ["-1", str(2**32), "1.5"])
@pytest.mark.parametrize("command", ["train", "rollout", "bounds", "preview"])
def test_a_bad_seed_exits_2_naming_it_and_the_range(tmp_path, command, bad):
    task = ["--task", "circle-3"] if command == "train" else ["circle-3"]
    code, _, err = _main(command, *task, "--seed", bad, "--out", str(tmp_path / "o"))
    assert code == 2 and f"'{bad}' is not a seed: give an integer in [0, 4294967295]" in err
    assert not (tmp_path / "o").exists()  # train: no run directory left behind


def test_the_largest_seed_is_taken_and_a_bool_is_no_count():
    """2**32 - 1 is the last seed numpy, torch and gymnasium all take; True is not 1."""
    from sili_robots.build import make_run_config
    from sili_robots.errors import ConfigError
    from sili_robots.runs import RunConfig

    code, _, err = _main("rollout", "circle-3", "--seed", str(2**32 - 1), "--interactions", "1")
    assert code == 0, err
    with pytest.raises(ConfigError, match=r"interactions must be an integer in \[0, 2147483647\]"):
        make_run_config("circle-3", "sac", 0, True)
    record = make_run_config("circle-3", "sac", 0, 5).to_dict()
    with pytest.raises(ConfigError, match=r"checkpoint_every must be an integer in \[1, 2147483"):
        RunConfig.from_dict({**record, "checkpoint_every": True})
    for name, high in (
        ("interactions", 2**31 - 1),
        ("checkpoint_every", 2**31 - 1),
        ("threads", 1024),
    ):
        assert getattr(RunConfig.from_dict({**record, name: high}), name) == high
        with pytest.raises(ConfigError, match=rf"{name} must be an integer in \[., {high}\]"):
            RunConfig.from_dict({**record, name: high + 1})  # a damaged config.json, say


def test_sweep_refuses_bad_seeds_a_task_twice_and_a_latent_no_method_takes(tmp_path):
    sweep = ["sweep", "--out", str(tmp_path / "s"), "--dry-run", "--methods"]
    code, _, err = _main(*sweep, "oracle", "--tasks", "circle-3", "--seeds", "-1")
    assert code == 2 and "seed -1 is not allowed" in err
    code, _, err = _main(*sweep, "oracle", "--tasks", "sili/Circle3-v1,circle-3")
    assert code == 2 and "'sili/Circle3-v1' and 'circle-3' are the same task or share" in err
    doors = "sili_robots.examples.two_doors:TwoDoorsEnv,sili_robots.examples:two_doors.TwoDoorsEnv"
    code, _, err = _main(*sweep, "sac", "--tasks", doors)  # one class written two ways
    assert code == 2 and "share the file name 'sili_robots-examples-two_doors-TwoDoorsEnv'" in err
    code, _, err = _main(*sweep, "sac", "--tasks", "circle-3", "--latent", "continuous")
    assert code == 2 and "--latent applies to methods sili, lili, stable only" in err
    mixed = ["sac,lili", "--tasks", "circle-3", "--latent", "continuous"]
    code, out, _ = _main(*sweep, *mixed)  # SAC learns no latent: not named after one
    assert code == 0 and "circle-3__sac__s0\tnew" in out and "lili-continuous__s0" in out, out
    code, out, _ = _main(*sweep, *mixed, "--overwrite")  # nothing on disk: nothing removed
    assert code == 0 and "removed" not in out and "circle-3__sac__s0\tnew" in out, out
    assert not (tmp_path / "s").exists()  # a dry run writes nothing


@pytest.mark.parametrize(
    "args",
    [
        ["sweep", "--tasks", "circle-3", "--methods", "oracle", "--interactions", "1", "--out"],
        ["sweep", "--tasks", "circle-3", "--methods", "oracle", "--dry-run", "--out"],
        ["collect", "SRC", "--into"],
        ["bounds", "circle-3", "--interactions", "300", "--write"],
        ["preview", "circle-3", "--out"],
        ["preview", "circle-3", "--out", "p.html", "--png"],
        ["plot", "SRC", "--out"],
    ],
    ids=["sweep", "sweep-dry-run", "collect", "bounds", "preview-html", "preview-png", "plot"],
)
def test_an_output_path_that_cannot_be_written_exits_2_before_any_work(tmp_path, args):
    (tmp_path / "file").write_text("")
    blocked = tmp_path / "file" / "out"  # under a regular file: no directory can be made
    args = [a.replace("SRC", str(tmp_path)).replace("p.html", f"{tmp_path}/p.html") for a in args]
    code, out, err = _main(*args, str(blocked))
    assert code == 2 and f"{blocked}: cannot write there" in err, err
    assert out == "" and "Traceback" not in err  # nothing computed first


def test_train_into_or_resuming_a_folder_that_cannot_be_written_exits_2(tmp_path, monkeypatch):
    """A read-only folder (root writes anywhere: its refusal is made here) failed with a
    traceback when training claimed it."""
    import tempfile

    run, empty = tmp_path / "run", tmp_path / "empty"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1"]
    args += ["--set", "hidden=8", "--no-progress"]
    assert _main(*args, "--out", str(run))[0] == 0
    empty.mkdir()
    made = tempfile.TemporaryFile

    def read_only(*a, dir=None, **kw):
        if dir is not None and Path(dir) in (run, empty):
            raise PermissionError(13, "Permission denied")
        return made(*a, dir=dir, **kw)

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
    code, _, err = _main(*args, "--out", str(empty))
    assert code == 2 and f"--out {empty}: cannot write there (Permission denied)" in err, err
    code, _, err = _main("train", "--resume", str(run), "--interactions", "2")
    assert code == 2 and f"--resume {run}: cannot write there (Permission denied)" in err, err
    assert "Traceback" not in err


def test_a_path_option_expands_a_tilde_the_shell_left(tmp_path, monkeypatch):
    """``--out=~/runs``: bash leaves this ~ alone; trained into ./~ but read from $HOME before."""
    import shutil

    from sili_robots.cache import cache_dir

    kernels = cache_dir() / "kernels.json"  # this machine's choice, not timed again
    (tmp_path / "cache").mkdir()
    if kernels.is_file():
        shutil.copy(kernels, tmp_path / "cache")
    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    code, _, err = _main("train", "--task", "circle-3", "--method", "sac", "--interactions", "1",
                         "--set", "hidden=8", "--no-progress", "--out=~/runs/t")  # fmt: skip
    assert code == 0, err
    assert (tmp_path / "home" / "runs" / "t" / "summary.json").is_file()
    assert not (tmp_path / "~").exists()


def test_a_suggested_command_quotes_a_path_as_a_shell_takes_it_back(tmp_path):
    run = tmp_path / "with space" / "r"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1"]
    args += ["--set", "hidden=8", "--no-progress", "--out", str(run)]
    assert _main(*args)[0] == 0
    code, _, err = _main(*args)
    assert code == 2 and f"--resume '{run}' continues it" in err, err


def test_bad_input_found_after_the_output_check_leaves_no_directory(tmp_path):
    new = tmp_path / "new" / "sweep"
    code, _, err = _main(
        "sweep", "--tasks", "circle-3,sili/Circle3-v1", "--methods", "sac", "--out", str(new)
    )
    assert code == 2 and "same task" in err
    code, _, err = _main("collect", str(tmp_path), "--into", str(new))
    assert code == 2 and "holds no runs" in err
    assert not (tmp_path / "new").exists()


def test_beta_options_set_b_as_given():
    from sili_robots.agent.schedule import Schedule
    from sili_robots.cli import _parse, build_parser
    from sili_robots.commands.train import config_from_args

    def b(*options):
        argv = ["train", "--task", "circle-3", "--method", "sili", *options]
        return config_from_args(_parse(build_parser(), argv)).agent.sili.beta

    assert b("--beta", "0.7") == 0.7
    assert b("--beta-anneal", "0.1", "0.6", "10", "5") == Schedule(((5, 0.1), (15, 0.6)))
    assert b("--beta-anneal", "0.9", "0.2", "4") == Schedule(((0, 0.9), (4, 0.2)))
    assert b("--beta-schedule", "250:0,300:0.5") == Schedule(((250, 0.0), (300, 0.5)))


#: a run that a broken refusal would train is over in seconds
BRIEF = ["--interactions", "1", "--no-progress"]


def test_beta_and_a_set_of_b_together_exit_2(tmp_path):
    train = ["train", "--task", "circle-3", "--out", str(tmp_path / "r"), *BRIEF]
    code, _, err = _main(*train, "--beta", "0.3", "--set", "sili.beta=0.7")
    assert code == 2 and "give one of --beta and --set sili.beta, not both" in err


def test_an_option_and_a_setting_of_the_same_thing_together_exit_2(tmp_path):
    train = ["train", "--task", "sawyer-reach", "--out", str(tmp_path / "r"), *BRIEF]
    code, _, err = _main(*train, "--latent", "discrete", "--set", "latent=continuous")
    assert code == 2 and "give one of --latent and --set latent, not both" in err
    both = ["--controller", "mink", "--env-kwarg", 'controller="osc"']
    code, _, err = _main(*train, *both)
    assert code == 2 and "give one of --controller and --env-kwarg controller" in err
    sweep = ["sweep", "--tasks", "sawyer-reach", "--methods", "sac", "--out", str(tmp_path / "s")]
    code, _, err = _main(*sweep, *both, "--dry-run")
    assert code == 2 and "give one of --controller and --env-kwarg controller" in err
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()


def test_a_reader_that_stops_early_ends_the_command_quietly():
    """``sili ... | head``: no traceback; exit 1, the output was cut short."""
    cmd = [sys.executable, "-m", "sili_robots.cli", "rollout", "circle-3", "--interactions", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # before it prints anything
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 1 and err == "", err


def test_a_broken_pipe_that_is_not_stdout_is_a_failure(monkeypatch):
    """Only a closed stdout is the reader stopping; another pipe (the browser's) failing is an
    error and keeps its traceback."""
    from sili_robots.commands import rollout

    def broken(_args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(rollout, "run", broken)
    with pytest.raises(BrokenPipeError):
        sili_in_process("rollout", "circle-3")


def test_an_allocation_is_sized_as_numpy_sizes_it():
    """torch's byte count reads as numpy's allocation error writes a size (its strings for
    these sizes): 3 figures, a unit up where rounding reaches 1024 of one."""
    from sili_robots.cli import _binary_size

    sizes = (1, 1023, 1024, 1_048_575, 92_000_000_000, 1000 * 2**30, 2**62, 2**70)
    assert [_binary_size(n) for n in sizes] == [
        "1 bytes",
        "1023 bytes",
        "1.00 KiB",
        "1.00 MiB",
        "85.7 GiB",
        "1000. GiB",
        "4.00 EiB",
        "1024. EiB",
    ]


def test_an_agent_too_large_for_memory_is_one_line_and_other_errors_keep_their_trace(monkeypatch):
    """torch's own allocation failure (2**62 bytes is past any address space) becomes a line
    naming the size and the settings that size the agent; any other RuntimeError still raises."""
    import torch

    from sili_robots.commands import train

    monkeypatch.setattr(train, "run", lambda _args: torch.empty(2**62, dtype=torch.uint8))
    done = sili_in_process("train", "--task", "circle-3")
    assert done.returncode == 1
    assert done.stderr == (
        "sili train: error: out of memory (4.00 EiB were asked for); the settings that size "
        "the agent (hidden, model.dim, sac.batch_interactions, sac.batch_steps, model.batch) or "
        "its batches per interaction (sac.updates_per_step) may be too large for this machine\n"
    )
    monkeypatch.setattr(train, "run", lambda _args: np.empty(2**57))  # numpy's own wording
    done = sili_in_process("train", "--task", "circle-3")
    assert done.returncode == 1 and "out of memory (1.00 EiB were asked for)" in done.stderr

    def fails(_args):
        raise RuntimeError("mat1 and mat2 shapes cannot be multiplied")

    monkeypatch.setattr(train, "run", fails)
    with pytest.raises(RuntimeError, match="shapes cannot be multiplied"):
        sili_in_process("train", "--task", "circle-3")


def test_a_schedule_for_a_setting_that_takes_one_number_names_those_that_take_one(tmp_path):
    train = ["train", "--task", "circle-3", "--out", str(tmp_path / "r")]
    code, _, err = _main(*train, "--set", "addons.recent.fraction=0:0,10:0.5")
    assert code == 2 and "recent.fraction takes one number, not a schedule (0:0,10:0.5)" in err
    assert "take schedules: sac.lr, sac.gamma," in err and "sili.beta" in err


def test_a_task_argument_that_names_another_task_exits_2(tmp_path):
    """Circle's variant is what the name says: circle-3 cannot train Circle (8 Goals)."""
    train = ["train", "--task", "circle-3", "--out", str(tmp_path / "r")]
    for value in ('"8"', "8"):
        code, _, err = _main(*train, "--env-kwarg", f"variant={value}")
        assert code == 2 and "circle-3 fixes variant='3'" in err and "circle-8" in err
    code, _, err = _main(*train, "--env-kwarg", "variant=3")  # its own name, as a number
    assert code == 2 and "so variant=3 (int 3, not str '3') is not allowed" in err
    assert not (tmp_path / "r").exists()
    make_task("circle-3", variant="3").close()  # its own value is no other task


def test_resuming_a_run_whose_record_was_lost_exits_2(tmp_path):
    run = tmp_path / "r"
    train = ["train", "--task", "circle-3", "--interactions", "4", "--checkpoint-every", "2"]
    assert _main(*train, *FAST_ARGS, "--no-progress", "--out", str(run))[0] == 0
    metrics = run / "metrics.csv"
    kept = metrics.read_text().splitlines()
    metrics.write_text("\n".join(kept[:3]) + "\n")  # 2 of the checkpoint's 4 rows
    code, _, err = _main("train", "--resume", str(run), "--interactions", "6", "--no-progress")
    assert code == 2 and "checkpoint is at interaction 4 but its metrics.csv holds 2 rows" in err
    metrics.write_text("\n".join(kept[:4]) + "\n")  # only the last row lost
    code, _, err = _main("train", "--resume", str(run), "--interactions", "6", "--no-progress")
    assert code == 2 and "checkpoint is at interaction 4 but its metrics.csv holds 3 rows" in err
    metrics.unlink()
    code, _, err = _main("train", "--resume", str(run), "--interactions", "6", "--no-progress")
    assert code == 2 and "metrics.csv is missing" in err


def test_files_a_command_would_write_are_checked_before_its_work(tmp_path):
    """Not a bounds file, a folder for a file, a collection into its own source: exit 2 first."""
    for text in ("[1, 2]", "{}", "{half"):
        target = tmp_path / "b.json"
        target.write_text(text)
        code, out, err = _main("bounds", "circle-3", "--interactions", "20", "--write", str(target))
        assert code == 2 and "is not a bounds file" in err and out == ""  # no games played
        assert target.read_text() == text
    code, _, err = _main("claims", str(tmp_path), "--write", str(tmp_path))
    assert code == 2 and f"--write {tmp_path} is a directory" in err
    code, _, err = _main("collect", "--into", str(tmp_path), str(tmp_path))
    assert code == 2 and "is also a source" in err


def test_more_bad_input_exits_2_with_one_line_naming_it(tmp_path):
    import json
    import socket

    from sili_robots.sweep.state import training_worker

    binary = tmp_path / "binary.md"
    binary.write_bytes(bytes(range(128, 256)))
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "sweep.json").write_text('{"invocations": []}')
    out = str(tmp_path / "o")
    for args, said in (
        (["sweep", "--tasks", "circle-3", "--methods", "sili", "--beta", "0.1,0.1000001",
          "--out", out, "--dry-run"], "two runs of this sweep would be named circle-3__sili-b0.1"),
        (["sweep", "--tasks", "circle-3", "--methods", "sac", "--out", out, "--backend", "ray",
          "--ray-address", "localhost:99999", "--dry-run"], "(PORT up to 65535)"),
        (["preview", "circle-3", "--checkpoint", ""], "--checkpoint: an empty path"),
        (["grid", "--fraction", "0.01", "--sweep-dir", out, "--into", out, "--dry-run"],
         "--sweep-dir and --into are both"),
        (["claims", str(GRID), "--write", str(binary)], "is not a text file"),
        (["sweep", "--resume", str(sweep), "--dry-run"], "is damaged (no invocation recorded)"),
    ):  # fmt: skip
        code, _, err = _main(*args)
        assert code == 2 and said in err and "Traceback" not in err, (args, err)
        assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists()
    for pid in (0, -1, 10**20):  # a damaged worker.json names no process that trains the run
        (tmp_path / "worker.json").write_text(
            json.dumps({"pid": pid, "host": socket.gethostname()})
        )
        assert training_worker(tmp_path) is None


def test_a_claim_whose_pid_another_process_took_since_is_stale(tmp_path):
    """A sweep killed with SIGKILL leaves its workers' claims; once their pids are reused
    (a reboot, a new container) the run is not refused for an unrelated process."""
    import json
    import socket

    from sili_robots.sweep.state import process_started, training_claim, training_worker

    claim = tmp_path / "worker.json"
    with training_claim(tmp_path):
        recorded = json.loads(claim.read_text())
        assert recorded["started"] == process_started(os.getpid()) is not None
        assert training_worker(tmp_path) == os.getpid()
    with training_claim(tmp_path):  # a process that took the folder over keeps its claim
        taken = {"pid": 1, "host": "elsewhere", "started": None}
        claim.write_text(json.dumps(taken))
    assert json.loads(claim.read_text()) == taken
    claim.unlink()
    sleeper = subprocess.Popen(["sleep", "60"])
    try:
        host = socket.gethostname()
        for pid, started, trained_by in (
            (sleeper.pid, process_started(sleeper.pid), sleeper.pid),  # the process that claimed
            (sleeper.pid, recorded["started"], None),  # a claim of a process gone: reused pid
            (sleeper.pid, None, sleeper.pid),  # where start times cannot be read: the pid alone
        ):
            claim.write_text(json.dumps({"pid": pid, "host": host, "started": started}))
            assert training_worker(tmp_path) == trained_by
    finally:
        sleeper.kill()
        sleeper.wait()


def test_read_outs_name_a_damaged_summary_and_read_a_sweep_they_cannot_write(tmp_path, monkeypatch):
    import json
    import shutil

    from sili_robots.plot_data import load_results
    from sili_robots.sweep import results

    collection = tmp_path / "collection"
    shutil.copytree(MAIN_JOB, collection)
    assert "2 runs done" in sili_in_process("runs", collection).stdout
    summary = collection / "runs" / "s1" / "summary.json"
    summary.write_text(json.dumps({**json.loads(summary.read_text()), "final_task_reward": "x"}))
    bad = sili_in_process("runs", collection)
    assert bad.returncode == 2 and "summary.json is damaged (a value of final_task" in bad.stderr
    summary.write_text("[1, 2]")
    for command in (
        ["runs"],
        ["claims"],
        ["plot", "--out", str(tmp_path / "f"), "--formats", "png"],
    ):
        bad = sili_in_process(command[0], collection, *command[1:])
        assert bad.returncode == 2 and "summary.json is damaged (not a JSON object)" in bad.stderr
    shutil.copy(collection / "runs" / "s2" / "summary.json", summary)
    record = json.loads(summary.read_text())
    summary.write_text(json.dumps({**record, "final_stability": None}))  # a 1-interaction run's
    assert sili_in_process("runs", collection).returncode == 0
    (collection / "sweep.json").write_text("{}")  # read as a sweep, whose tables are rebuilt

    def read_only(_sweep_dir):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(results, "write_tables", read_only)
    read = load_results(collection)  # its runs as they are, nothing written
    assert sorted(set(read["run"])) == ["s1", "s2"] and len(read) == 2 * 600


def test_ctrl_c_while_the_commands_load_is_one_line(monkeypatch, capsys):
    """The commands import torch and the simulators' bindings (a second or two): a Ctrl-C then
    printed a traceback through them."""
    import sili_robots.cli as cli

    def loading():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", loading)
    assert cli.main(["runs", "."]) == 130
    assert capsys.readouterr().err == "sili: interrupted\n"


def test_beta_anneal_refuses_a_fifth_word():
    from sili_robots.commands.train import beta_anneal
    from sili_robots.errors import ConfigError

    beta_anneal([["0", "0.5", "100", "10"]])
    with pytest.raises(ConfigError, match="START END LENGTH"):
        beta_anneal([["0", "0.5", "100", "10", "99"]])


def test_the_largest_allowed_integer_is_accepted():
    """An integer option takes its largest allowed value itself (the bound is inclusive)."""
    assert threads_arg(str(MAX_THREADS)) == MAX_THREADS
    assert positive_int(str(LARGEST_INT)) == LARGEST_INT
    # on the command line: the option is taken, the next check (no --task) is what refuses
    out = sili_in_process("train", "--threads", MAX_THREADS, "--interactions", LARGEST_INT)
    assert out.returncode == 2
    assert "is not allowed" not in out.stderr and "--task is required" in out.stderr


def test_a_name_of_exactly_name_max_bytes_is_a_path_one_more_is_refused():
    """A path option takes a name as long as file systems allow (NAME_MAX bytes), not one more."""
    longest = "r" * NAME_MAX
    assert path_arg(f"runs/{longest}") == Path("runs", longest)
    with pytest.raises(argparse.ArgumentTypeError, match=f"{NAME_MAX + 1} bytes"):
        path_arg(f"runs/{longest}r")


def test_the_largest_port_is_an_address_one_more_is_refused():
    """``--ray-address`` takes every TCP port, 65535 the largest."""
    assert ray_address("localhost:65535") == "localhost:65535"
    assert ray_address("ray://10.0.0.2:65535") == "ray://10.0.0.2:65535"
    with pytest.raises(argparse.ArgumentTypeError, match="PORT up to 65535"):
        ray_address("localhost:65536")


def test_collect_refuses_a_summary_of_zero_interactions(tmp_path):
    """A damaged summary.json saying 0 interactions was collected as a finished run."""
    source = tmp_path / "source"
    shutil.copytree(MAIN_JOB, source)
    summary = source / "runs" / "s1" / "summary.json"
    summary.write_text(json.dumps({**json.loads(summary.read_text()), "interactions": 0}))
    into = tmp_path / "into"
    done = sili_in_process("collect", source, "--into", into)
    assert done.returncode == 2
    assert f"{summary} is damaged (interactions 0 is not a count)" in done.stderr
    assert not (into / "runs").exists()


def test_collect_refuses_into_its_own_source_given_by_another_path(tmp_path, monkeypatch):
    """A collection into itself, named once relative and once absolute, was not refused."""
    shutil.copytree(MAIN_JOB, tmp_path / "c")
    monkeypatch.chdir(tmp_path)
    done = sili_in_process("collect", "c", "--into", tmp_path / "c")
    assert done.returncode == 2
    assert "is also a source (c); collect elsewhere" in done.stderr


def test_runs_lists_only_the_seeds_of_done_runs(tmp_path):
    """An unfinished run's seed was listed among the done runs' seeds."""
    collection = tmp_path / "collection"
    shutil.copytree(MAIN_JOB, collection)
    seed = json.loads((collection / "runs" / "s2" / "config.json").read_text())["run"]["seed"]
    done_seed = json.loads((collection / "runs" / "s1" / "config.json").read_text())["run"]["seed"]
    assert seed != done_seed
    (collection / "runs" / "s2" / "summary.json").unlink()  # still training
    out = sili_in_process("runs", collection, "--csv")
    assert out.returncode == 0, out.stderr
    table = pd.read_csv(io.StringIO(out.stdout))
    assert table.done.tolist() == [1] and table.unfinished.tolist() == [1]
    assert table.seeds.astype(str).tolist() == [str(done_seed)]


def test_runs_of_an_empty_folder_exits_2_saying_why(tmp_path):
    """An empty folder printed an empty table, exit 0, instead of the reason."""
    empty = sili_in_process("runs", tmp_path)
    assert empty.returncode == 2 and "holds no runs (no runs/*/config.json)" in empty.stderr


def _mean_after_first(seed):
    env = make_task("circle-3")
    try:
        played = run_interactions(env, scripted_policy(env, "random"), 3, seed=seed)
    finally:
        env.close()
    return np.mean([s.task_reward for s in played[1:]])


def test_rollout_plays_the_game_of_the_seed_given():
    """--seed was ignored: every seed printed seed 0's numbers."""
    assert f"{_mean_after_first(5):.3f}" != f"{_mean_after_first(0):.3f}"
    done = sili_in_process(
        "rollout", "circle-3", "--policy", "random", "--interactions", "3", "--seed", "5"
    )
    assert done.returncode == 0, done.stderr
    line = f"mean task reward per interaction (after the first): {_mean_after_first(5):.3f}"
    assert line in done.stdout


def test_eval_plays_100_interactions_by_default(tmp_path):
    """The documented default of 100 evaluation interactions was not what ran."""
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "3", *FAST_ARGS, "--no-progress"]
    assert sili_in_process(*args, "--out", run).returncode == 0
    done = sili_in_process("eval", run)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["interactions"] == 100


def test_counts_are_said_in_the_plural_but_for_one():
    assert [counted(n, "run") for n in (0, 1, 2)] == ["0 runs", "1 run", "2 runs"]
