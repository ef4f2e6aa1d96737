"""A run folder that another process takes between a trainer's first look and its claim: the
trainer refuses it, and that process's files stay (``sweep.state.training_claim``)."""

from __future__ import annotations

import json
import os
import socket
import subprocess

import pytest
from fast_settings import FAST_AGENT, FAST_ARGS

import sili_robots.api as api
import sili_robots.commands.train as train_command
import sili_robots.sweep.runner as runner
from sili_robots import SILI
from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.sweep.state import check_not_trained, training_claim, training_worker


@pytest.fixture
def other_process():
    """A live process on this host, standing in for another trainer."""
    proc = subprocess.Popen(["sleep", "60"])
    yield proc.pid
    proc.kill()
    proc.wait()


def _claim(run_dir, pid):
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "worker.json").write_text(json.dumps({"pid": pid, "host": socket.gethostname()}))


def test_a_run_finished_in_the_folder_while_the_task_was_built_is_not_trained_over(
    tmp_path, monkeypatch, capsys
):
    out = tmp_path / "run"
    theirs = '{"run": "another run"}'

    def meanwhile(cfg, agent):  # a slow task constructor; another `sili train` starts and ends
        out.mkdir(exist_ok=True)
        (out / "config.json").write_text(theirs)

    monkeypatch.setattr(train_command, "_check_builds", meanwhile)
    args = ["train", "--task", "circle-3", "--interactions", "2", "--out", str(out), *FAST_ARGS]
    assert main([*args, "--no-progress"]) == 2
    assert f"{out} already holds a run" in capsys.readouterr().err
    assert (out / "config.json").read_text() == theirs
    assert not (out / "worker.json").exists()


def test_overwrite_does_not_clear_a_folder_another_trainer_claimed_meanwhile(
    tmp_path, monkeypatch, capsys, other_process
):
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.json").write_text("{}")

    def meanwhile(cfg, agent):  # another trainer claims the folder while the task builds
        _claim(out, other_process)

    monkeypatch.setattr(train_command, "_check_builds", meanwhile)
    args = ["train", "--task", "circle-3", "--interactions", "2", "--out", str(out), *FAST_ARGS]
    assert main([*args, "--overwrite", "--no-progress"]) == 2
    assert f"being trained by process {other_process}" in capsys.readouterr().err
    assert (out / "config.json").read_text() == "{}"  # its files, not cleared
    assert json.loads((out / "worker.json").read_text())["pid"] == other_process


def test_a_sweep_leaves_a_run_claimed_after_its_check_to_its_trainer(
    tmp_path, monkeypatch, capsys, other_process
):
    out = tmp_path / "sweep"
    taken = out / "runs" / "circle-3__sac__s1"
    record = runner.record_invocation

    def meanwhile(sweep_dir, spec):  # `sili train --resume` claims a run after the check
        _claim(taken, other_process)
        record(sweep_dir, spec)

    monkeypatch.setattr(runner, "record_invocation", meanwhile)
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1"]
    assert main([*args, "--interactions", "2", "--out", str(out), "--no-progress", *FAST_ARGS]) == 1
    assert f"being trained by process {other_process}" in capsys.readouterr().err
    assert json.loads((taken / "worker.json").read_text())["pid"] == other_process
    assert not (taken / "metrics.csv").exists() and not (taken / "error.txt").exists()
    assert (out / "runs" / "circle-3__sac__s0" / "summary.json").is_file()  # the other trained


def test_the_api_neither_trains_over_nor_clears_a_run_that_appeared_before_its_claim(
    tmp_path, monkeypatch
):
    run_dir = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run_dir)
    make = api.make_run_dir

    def meanwhile(path, name):  # another process starts and ends a run there
        make(path, name)
        (path / "config.json").write_text("theirs")

    monkeypatch.setattr(api, "make_run_dir", meanwhile)
    with pytest.raises(ConfigError, match="already holds a run"):
        model.learn(2)
    assert (run_dir / "config.json").read_text() == "theirs"  # not cleared as a stopped start
    monkeypatch.setattr(api, "make_run_dir", make)
    (run_dir / "config.json").unlink()
    assert len(model.learn(2).agent.Z) == 2 + 1  # as it was made: 2 interactions, z^1..z^3


def test_a_claim_written_on_another_host_names_no_local_trainer(tmp_path):
    """Without the host check, a local process that happens to hold that pid blocked the run."""
    claim = {"pid": os.getpid(), "host": "another-machine.invalid", "started": None}
    (tmp_path / "worker.json").write_text(json.dumps(claim))
    assert training_worker(tmp_path) is None
    check_not_trained(tmp_path)  # nothing raised: nobody here trains it


def test_a_claim_naming_no_process_names_no_trainer(tmp_path):
    """A damaged claim of pid 0 (os.kill(0, 0) signals this process group, and succeeds), a
    negative pid or one past the kernel's largest (os.kill overflows) blocks nothing."""
    for pid in (0, -1, 2**31):  # os.kill would overflow on the last
        _claim(tmp_path, pid)
        assert training_worker(tmp_path) is None, pid
        check_not_trained(tmp_path)  # nobody trains it


def test_ending_a_claim_leaves_a_newer_claim_of_another_process(tmp_path, other_process):
    """Our claim cleared as stale meanwhile and another trainer's written: ours ending leaves
    theirs, which still protects their run."""
    with training_claim(tmp_path):
        assert training_worker(tmp_path) == os.getpid()
        _claim(tmp_path, other_process)
    assert training_worker(tmp_path) == other_process
    (tmp_path / "worker.json").unlink()
    with training_claim(tmp_path):
        pass
    assert not (tmp_path / "worker.json").exists()  # our own is removed when the block ends
