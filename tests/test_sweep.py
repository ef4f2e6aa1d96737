"""``sili sweep`` on the local process pool: real runs, the results table, TensorBoard scalars,
resume after a SIGKILLed worker, a failing run isolated, bad input."""

import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch
from cli_helpers import sili as sili_in_process
from fast_settings import FAST_AGENT as FAST
from fast_settings import FAST_ARGS
from process_helpers import killing_its_worker_once, metrics_rows, signal_when, wait_for
from rich.console import Console

from sili_robots import SILI
from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.evaluation import load_trained
from sili_robots.runs import RunConfig
from sili_robots.stopping import SAME_STOP_S
from sili_robots.sweep import LocalBackend, RayBackend, SweepSpec, expand, run_sweep
from sili_robots.sweep import tensorboard as tb
from sili_robots.sweep.progress import SweepProgress, logged_interactions
from sili_robots.sweep.results import results_table
from sili_robots.sweep.state import recorded_specs, sweep_lock, write_invocations
from sili_robots.sweep.worker import Job
from sili_robots.training import train
from sili_robots.verdict import verdict


def _spec(**kw):
    base = {
        "tasks": ["circle-3"],
        "methods": ["sili", "sac"],
        "seeds": [0, 1],
        "interactions": 8,
        "agent_overrides": FAST,
        "checkpoint_every": 4,
    }
    return SweepSpec(**{**base, **kw})


def _sili(*args, timeout=300):
    return subprocess.run(
        [sys.executable, "-m", "sili_robots.cli", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _without_wall_time(df):
    return df.drop(columns="wall_time").reset_index(drop=True)


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    """2 methods x 2 seeds on Circle (3 Goals), 8 interactions each, two workers."""
    out = tmp_path_factory.mktemp("sweep")
    report = run_sweep(_spec(), out, LocalBackend(workers=2), progress=False)
    return out, report


def test_local_sweep_runs_every_run_in_its_own_process(tiny_sweep):
    out, report = tiny_sweep
    names = ["circle-3__sili-bschedule__s0", "circle-3__sili-bschedule__s1", "circle-3__sac__s0"]
    assert report.ok and set(names) < set(report.outcomes)
    assert all(o.status == "done" for o in report.outcomes.values())
    pids = {o.pid for o in report.outcomes.values()}
    assert len(pids) == 4 and os.getpid() not in pids  # one fresh process per run
    for name in report.planned:
        run_dir = out / "runs" / name
        assert (run_dir / "summary.json").is_file()
        assert len(pd.read_csv(run_dir / "metrics.csv")) == 8
        assert report.outcomes[name].verdict == verdict(run_dir)  # the worker's, for the display


def test_a_sweep_run_is_the_run_sili_train_would_make(tiny_sweep, tmp_path):
    out, _ = tiny_sweep
    cfg = {r.name: r.config for r in expand(_spec())}["circle-3__sili-bschedule__s1"]
    train(cfg, tmp_path / "ref", progress=False)
    ref = pd.read_csv(tmp_path / "ref" / "metrics.csv")
    got = pd.read_csv(out / "runs" / "circle-3__sili-bschedule__s1" / "metrics.csv")
    pd.testing.assert_frame_equal(_without_wall_time(ref), _without_wall_time(got))


def test_results_table_has_a_row_per_run_per_interaction(tiny_sweep):
    out, report = tiny_sweep
    exact = {"float_precision": "round_trip"}  # the values written, to the bit
    table = pd.read_csv(out / "results.csv", **exact)
    assert len(table) == 4 * 8
    assert table.groupby("run")["interaction"].apply(list).map(lambda x: x == list(range(8))).all()
    for name in report.planned:
        rows = table[table["run"] == name].reset_index(drop=True)
        metrics = pd.read_csv(out / "runs" / name / "metrics.csv", **exact)
        pd.testing.assert_frame_equal(
            rows[metrics.columns], metrics, check_dtype=False, check_exact=True
        )
        cfg = RunConfig.from_dict(
            json.loads((out / "runs" / name / "config.json").read_text())["run"]
        )
        assert (rows["task"] == cfg.task).all() and (rows["method"] == cfg.method).all()
        assert (rows["seed"] == cfg.seed).all()
        b = cfg.agent.sili.beta  # a schedule's b is the value it ends at
        assert (rows["config_beta"] == (b.points[-1][1] if hasattr(b, "points") else b)).all()
    kept = (1 - table["strategy_changed"]).where(table["interaction"] > 0)  # 0 keeps nothing
    np.testing.assert_array_equal(table["true_stability"], kept)
    assert table["finished"].all()
    runs = pd.read_csv(out / "runs.csv").set_index("run")
    assert (runs["status"] == "done").all() and (runs["interactions_logged"] == 8).all()
    summary = json.loads((out / "runs" / "circle-3__sac__s1" / "summary.json").read_text())
    assert runs.loc["circle-3__sac__s1", "final_task_reward"] == pytest.approx(
        summary["final_task_reward"]
    )


def test_rerunning_a_finished_sweep_skips_every_run(tiny_sweep, capsys):
    out, _ = tiny_sweep
    before = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/metrics.csv")}
    capsys.readouterr()
    report = run_sweep(_spec(), out, LocalBackend(workers=2), progress=False)
    assert sorted(report.skipped) == sorted(report.planned) and not report.outcomes and report.ok
    assert "sweep: 4 done (4 of them earlier), 0 failed, 0 not run" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in out.glob("runs/*/metrics.csv")} == before
    assert main(["sweep", "--resume", str(out), "--dry-run"]) == 0
    listed = capsys.readouterr().out
    assert "circle-3__sac__s1\tdone" in listed and "4 runs" in listed


def _scalars_and_metrics(run_dir):
    """The run's TensorBoard scalars (an event reader) and its metrics.csv, side by side;
    checks that reward/task mirrors the metrics, step for step."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir / "tb"))
    acc.Reload()
    metrics = pd.read_csv(run_dir / "metrics.csv")
    task = acc.Scalars("reward/task")
    assert [e.step for e in task] == list(range(len(metrics)))
    np.testing.assert_allclose([e.value for e in task], metrics["task_reward"], rtol=1e-6)
    return acc, metrics


@pytest.mark.skipif(not tb.available(), reason="tensorboard is not installed")
def test_tensorboard_scalars_mirror_the_metrics(tiny_sweep):
    out, _ = tiny_sweep
    acc, metrics = _scalars_and_metrics(out / "runs" / "circle-3__sili-bschedule__s0")
    assert len(metrics) == 8
    stable = acc.Scalars("stability/true")
    assert [e.step for e in stable] == list(range(1, 8))  # interaction 0 keeps nothing
    np.testing.assert_allclose([e.value for e in stable], 1 - metrics["strategy_changed"][1:])
    assert [e.step for e in acc.Scalars("loss/critic")] == list(
        metrics.index[metrics["critic_loss"].notna()]
    )


@pytest.mark.skipif(not tb.available(), reason="tensorboard is not installed")
def test_a_sweep_run_trained_on_by_hand_keeps_its_scalars_in_step(tiny_sweep, tmp_path):
    import shutil

    out, _ = tiny_sweep
    run_dir = tmp_path / "run"
    shutil.copytree(out / "runs" / "circle-3__sili-bschedule__s0", run_dir)
    scalars = {p: p.read_bytes() for p in (run_dir / "tb").iterdir()}
    assert main(["train", "--resume", str(run_dir), "--interactions", "2"]) == 2  # shorter
    assert {p: p.read_bytes() for p in (run_dir / "tb").iterdir()} == scalars  # left as they were
    assert main(["train", "--resume", str(run_dir), "--interactions", "10", "--no-progress"]) == 0
    _, metrics = _scalars_and_metrics(run_dir)
    assert len(metrics) == 10


def test_failing_run_is_reported_and_the_others_complete(tmp_path):
    """A run that fails (a controller the CLI would refuse up front, given through the API)
    is recorded and reported; the others finish, and a resume retries only the failed one."""
    out = tmp_path / "sweep"
    spec = _spec(tasks=["circle-3", "sawyer-reach"], methods=["sac"], seeds=[0], interactions=4)
    report = run_sweep(
        replace(spec, controllers=["bogus"]), out, LocalBackend(workers=2), progress=False
    )
    assert report.outcomes["circle-3__sac__s0"].status == "done"
    assert report.failed == {
        "sawyer-reach-bogus__sac__s0": "ConfigError: unknown controller 'bogus'; "
        "allowed: mink, osc, joint_velocity"
    }
    assert len(pd.read_csv(out / "runs" / "circle-3__sac__s0" / "metrics.csv")) == 4
    assert (
        "unknown controller"
        in (out / "runs" / "sawyer-reach-bogus__sac__s0" / "error.txt").read_text()
    )
    runs = pd.read_csv(out / "runs.csv").set_index("run")
    assert runs.loc["circle-3__sac__s0", "status"] == "done"
    assert runs.loc["sawyer-reach-bogus__sac__s0", "status"] == "failed"
    assert "unknown controller 'bogus'" in runs.loc["sawyer-reach-bogus__sac__s0", "error"]
    res = _sili("sweep", "--resume", out, "--dry-run")
    assert "sawyer-reach-bogus__sac__s0\tnew (failed before, see its error.txt)" in res.stdout
    assert "circle-3__sac__s0\tdone\n" in res.stdout
    res = _sili("sweep", "--resume", out, "--workers", 1, "--no-progress")
    assert res.returncode == 1, res.stderr
    assert json.loads(res.stdout)["failed"] == report.failed
    assert "failed sawyer-reach-bogus__sac__s0: ConfigError: unknown controller" in res.stderr
    assert "Traceback" not in res.stderr


def test_killed_worker_is_reported_and_the_sweep_resumes_its_run(tmp_path):
    out = tmp_path / "sweep"
    args = ["--tasks", "circle-3", "--methods", "sili", "--seeds", "0,1", "--interactions", 40]
    args += ["--checkpoint-every", 5, "--workers", 2, "--no-progress", *FAST_ARGS]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", "sweep", *map(str, args), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    victim = out / "runs" / "circle-3__sili-bschedule__s0"
    try:
        assert wait_for(lambda: metrics_rows(victim / "metrics.csv") >= 12), "run never got going"
        pid = json.loads((victim / "worker.json").read_text())["pid"]
        assert pid != proc.pid
        os.kill(pid, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, stderr
    assert json.loads(stdout)["failed"] == {
        "circle-3__sili-bschedule__s0": "worker killed by SIGKILL"
    }
    assert len(pd.read_csv(out / "runs" / "circle-3__sili-bschedule__s1" / "metrics.csv")) == 40
    assert "worker killed by SIGKILL" in (victim / "error.txt").read_text()  # runs.csv's cause
    assert not (victim / "worker.json").exists()
    checkpointed = torch.load(victim / "checkpoint.pt", weights_only=False)["interaction"]
    assert 10 <= checkpointed < 40 and not (victim / "summary.json").exists()
    before = pd.read_csv(victim / "metrics.csv")

    res = _sili("sweep", "--resume", out, "--no-progress")
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert (report["already_done"], report["done"], report["failed"]) == (1, 1, {})
    assert "done circle-3__sili-bschedule__s0 (resumed)" in res.stderr
    after = pd.read_csv(victim / "metrics.csv")
    # resumed, not restarted: the rows up to the checkpoint are the very rows written before
    pd.testing.assert_frame_equal(after.head(checkpointed), before.head(checkpointed))
    # and the result is exactly the uninterrupted run
    cfg = RunConfig.from_dict(json.loads((victim / "config.json").read_text())["run"])
    train(cfg, tmp_path / "ref", progress=False)
    ref = pd.read_csv(tmp_path / "ref" / "metrics.csv")
    pd.testing.assert_frame_equal(_without_wall_time(after), _without_wall_time(ref))
    assert (pd.read_csv(out / "runs.csv")["status"] == "done").all()
    if tb.available():
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

        acc = EventAccumulator(str(victim / "tb"))
        acc.Reload()
        assert [e.step for e in acc.Scalars("reward/task")] == list(range(40))


def test_a_killed_worker_is_retried_from_its_checkpoint_with_retries(tmp_path):
    spec = _spec(methods=["sili"], seeds=[0], interactions=40, checkpoint_every=5)
    run_dir = tmp_path / "runs" / "circle-3__sili-bschedule__s0"
    with killing_its_worker_once(run_dir) as killed:
        report = run_sweep(spec, tmp_path, LocalBackend(workers=1, retries=1), progress=False)
    (outcome,) = report.outcomes.values()
    assert outcome.status == "done" and outcome.resumed and outcome.pid != killed[0]
    assert metrics_rows(run_dir / "metrics.csv") == 40 and (run_dir / "summary.json").is_file()


def test_a_second_sweep_on_the_same_directory_is_refused(tmp_path):
    with sweep_lock(tmp_path), pytest.raises(Exception, match="another `sili sweep` is running"):
        run_sweep(_spec(), tmp_path, LocalBackend(workers=1), progress=False)


@pytest.mark.parametrize(
    "args,message",
    [
        (["--tasks", "circle-9", "--methods", "sili"], "unknown task 'circle-9'"),
        (["--tasks", "circle-3", "--methods", "sili,ppo"], "unknown method 'ppo'"),
        (["--tasks", "circle-3", "--methods", "sili", "--seeds", "4-2"], "seed range '4-2'"),
        (["--tasks", "circle-3", "--methods", "sili", "--seeds", "0-99999999"], "than 10,000 runs"),
        (["--tasks", "circle-3", "--methods", "sili", "--beta", "2"], "outside the allowed"),
        (["--tasks", "circle-3", "--methods", "sac", "--beta", "0.5"], "--beta applies to"),
        (["--tasks", "circle-3", "--methods", "sili", "--controller", "osc"], "--controller"),
        (["--tasks", "circle-3", "--methods", "sili", "--set", "gamma=3"], "gamma must be"),
        (["--tasks", "circle-3"], "--tasks and --methods are required"),
        (
            ["--tasks", "circle-3", "--methods", "sili", "--beta-schedule", "0:0,9:x"],
            "--beta-schedule '0:0,9:x': 'x' is not a number in [0, 1]",
        ),
        (
            ["--tasks", "circle-3", "--methods", "sac", "--target-entropy-schedule", "0:inf"],
            "'inf' is not a finite number",
        ),
        (["--tasks", "circle-3", "--methods", "sac", "--ray-address", "auto"], "needs --backend"),
        (["--tasks", "no_such_module:Env", "--methods", "sac"], "cannot load task class"),
        (["--tasks", ":Env", "--methods", "sac"], "task ':Env' names no module"),
        (["--tasks", "", "--methods", "sac"], "no tasks given; allowed: circle-3"),
        (["--tasks", "circle-3", "--methods", "all,sac"], "'all' stands alone"),
        (["--tasks", "sawyer-reach", "--methods", "sac", "--controller", ","], "no controllers"),
        (["--tasks", "circle-3", "--methods", "sili", "--beta-schedule", ""], "'' is not INTER"),
        (["--tasks", "circle-3", "--methods", "sac", "--retries", "x"], "'x' is not an integer"),
        (
            ["--tasks", "circle-3", "--methods", "sac", "--backend", "ray", "--ray-address", "x"],
            "'x' is not a Ray address; give auto, local, HOST:PORT or ray://HOST:PORT",
        ),
        (
            ["--tasks", "circle-3,driving", "--methods", "sac", "--env-kwarg", "outside_margin=1"],
            "task 'driving' takes no argument outside_margin (--env-kwarg); its arguments: ",
        ),
    ],
)
def test_bad_sweep_input_exits_2_with_the_allowed_values(tmp_path, args, message):
    done = sili_in_process("sweep", *args, "--out", tmp_path / "s")  # argparse's errors too
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert not (tmp_path / "s").exists()


def test_a_sweep_trains_a_users_task_class_from_the_working_directory(
    tmp_path, monkeypatch, capsys
):
    (tmp_path / "sweep_lab").mkdir()
    (tmp_path / "sweep_lab" / "__init__.py").write_text("")
    (tmp_path / "sweep_lab" / "doors.py").write_text(
        "from sili_robots.examples.two_doors import TwoDoorsEnv\n\n\n"
        "class Doors(TwoDoorsEnv):\n"
        "    pass\n\n\n"
        "class Unbuilt(TwoDoorsEnv):\n"
        "    def __init__(self, horizon=20):\n"
        "        raise RuntimeError('no simulator here')\n"
    )
    monkeypatch.chdir(tmp_path)  # where the workers import it from, as `sili train` does
    monkeypatch.syspath_prepend(str(tmp_path))  # here too, and undone after the test
    task, out = "sweep_lab.doors:Doors", tmp_path / "sweep"
    args = ["sweep", "--tasks", task, "--methods", "sili,oracle", "--seeds", "0"]
    args += ["--env-kwarg", "horizon=6", "--interactions", "3", *FAST_ARGS, "--out", str(out)]
    assert main([*args, "--no-progress"]) == 0
    runs = sorted((out / "runs").iterdir())
    names = ["sweep_lab-doors-Doors__oracle__s0", "sweep_lab-doors-Doors__sili-bschedule__s0"]
    assert [r.name for r in runs] == names  # file names any shell, make or LaTeX takes
    cfg, env, _, _ = load_trained(runs[1])
    assert (cfg.task, cfg.task_id, cfg.method) == (task, None, "sili")
    assert type(env.unwrapped).__name__ == "Doors" and env.unwrapped.horizon == 6
    assert main(["sweep", "--resume", str(out), "--interactions", "4", "--no-progress"]) == 0
    assert all(len(pd.read_csv(r / "metrics.csv")) == 4 for r in runs)
    table = pd.read_csv(out / "runs.csv")
    assert set(table["task"]) == {task} and set(table["status"]) == {"done"}
    capsys.readouterr()
    assert main(["plot", str(out), "--formats", "png"]) == 0
    assert (out / "figures" / "sweep_lab-doors-Doors.png").is_file()
    unbuilt = ["sweep", "--tasks", "sweep_lab.doors:Unbuilt", "--methods", "sac"]
    assert main([*unbuilt, "--out", str(tmp_path / "unbuilt"), "--dry-run"]) == 2  # before any run
    assert (
        "task 'sweep_lab.doors:Unbuilt' cannot be built with its default arguments: "
        "RuntimeError: no simulator here" in capsys.readouterr().err
    )


def test_schedules_given_to_the_sweep_drive_its_runs(tmp_path):
    out = tmp_path / "s"
    args = ["--tasks", "circle-3", "--methods", "sili,oracle", "--interactions", 4]
    args += ["--beta-schedule", "0:0,2:0.5", "--target-entropy-schedule", "0:-2,3:-5"]
    args += ["--workers", 2, "--no-progress", "--out", out]
    done = _sili("sweep", *args, *FAST_ARGS)
    assert done.returncode == 0, done.stderr
    sili = pd.read_csv(out / "runs" / "circle-3__sili-bschedule__s0" / "metrics.csv")
    assert sili["beta"].tolist() == [0.0, 0.25, 0.5, 0.5]
    for name in ("circle-3__sili-bschedule__s0", "circle-3__oracle__s0"):
        agent = json.loads((out / "runs" / name / "config.json").read_text())["run"]["agent"]
        assert agent["sac"]["target_entropy"] == {"points": [[0, -2.0], [3, -5.0]]}
    # the sweep records its schedules, so a re-run finds every run done
    again = _sili("sweep", "--resume", out, "--no-progress")
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout)["already_done"] == 2


def test_resume_of_a_non_sweep_and_changed_settings_exit_2(tiny_sweep, tmp_path, capsys):
    assert main(["sweep", "--resume", str(tmp_path), "--interactions", "9"]) == 2
    assert "is not a sweep directory" in capsys.readouterr().err  # the first thing to mend
    out, _ = tiny_sweep
    args = ["--tasks", "circle-3", "--methods", "sac", "--seeds", "0", "--interactions", "9"]
    assert main(["sweep", *args, "--out", str(out), *FAST_ARGS]) == 2  # (saved as often or not)
    assert "has 8 interactions, fewer than the 9 asked for now" in capsys.readouterr().err
    assert main(["sweep", *args, "--out", str(out), *FAST_ARGS, "--set", "sac.tau=0.5"]) == 2
    err = capsys.readouterr().err
    assert "agent.sac.tau: 0.005 on disk, 0.5 now; interactions: 8 on disk, 9 now" in err
    assert f"or move that run out of {out}" in err
    resume = ["sweep", "--resume", str(out), "--checkpoint-every", "9", "--workers", "1"]
    assert main(resume) == 2
    err = capsys.readouterr().err
    assert "it takes no --checkpoint-every (allowed with it: --interactions, --backend" in err
    assert main(["sweep", "--resume", str(out), "--seeds", "0"]) == 2  # typed at its default
    assert "it takes no --seeds (" in capsys.readouterr().err


class _JobsSeen(LocalBackend):
    """A local backend that keeps the jobs it was handed."""

    def run(self, jobs, monitor):
        self.jobs = {job.name: job.config for job in jobs}
        return super().run(jobs, monitor)


def test_a_sweep_run_again_where_kernels_time_otherwise_keeps_each_runs_own(
    tmp_path, monkeypatch, capsys
):
    """The same sweep re-run for more seeds where the kernel timing picks another library
    (another machine, a fresh cache): the runs on disk go on with the kernels they were made
    with, as ``sili train --resume`` does, and the new ones take this machine's. It was refused:
    'made with other settings (agent.matmul: 'aten' on disk, 'onednn' now)'."""
    import sili_robots.sweep.spec as spec_module

    def made_with(run):
        return json.loads((tmp_path / "runs" / run / "config.json").read_text())["run"]["agent"]

    monkeypatch.setattr(spec_module, "default_matmul", lambda: "aten")
    first = _spec(methods=["sac"], seeds=[0], interactions=5)
    assert run_sweep(first, tmp_path, LocalBackend(workers=1), progress=False).ok
    (tmp_path / "runs" / "circle-3__sac__s0" / "summary.json").unlink()  # as if stopped
    monkeypatch.setattr(spec_module, "default_matmul", lambda: "onednn")
    args = ["--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1", "--interactions", "5"]
    args += ["--checkpoint-every", "4"]
    assert main(["sweep", *args, "--out", str(tmp_path), *FAST_ARGS, "--dry-run"]) == 0
    assert "circle-3__sac__s0\tresumable" in capsys.readouterr().out
    pinned = ["--set", "matmul=onednn"]  # given, not timed: the run on disk is not that run
    assert main(["sweep", *args, "--out", str(tmp_path), *FAST_ARGS, *pinned, "--dry-run"]) == 2
    assert "agent.matmul: 'aten' on disk, 'onednn' now" in capsys.readouterr().err
    backend = _JobsSeen(workers=1)
    more = _spec(methods=["sac"], seeds=[0, 1], interactions=5)  # planned here and now
    assert run_sweep(more, tmp_path, backend, progress=False).ok
    assert {name: cfg["agent"]["matmul"] for name, cfg in backend.jobs.items()} == {
        "circle-3__sac__s0": "aten",
        "circle-3__sac__s1": "onednn",
    }
    assert [made_with(f"circle-3__sac__s{seed}")["matmul"] for seed in (0, 1)] == [
        "aten",
        "onednn",
    ]
    assert run_sweep(recorded_specs(tmp_path), tmp_path, progress=False, recorded=True).ok


def test_a_sweep_run_again_with_another_checkpoint_interval_goes_on_with_its_runs(tmp_path, capsys):
    """How often a run is saved changes no number it logs (as ``collect`` holds): the same
    sweep invoked again for more seeds without its ``--checkpoint-every`` was refused as 'made
    with other settings (checkpoint_every: 4 on disk, 50 now)'."""
    first = _spec(methods=["sac"], seeds=[0], interactions=5)  # saved every 4
    assert run_sweep(first, tmp_path, LocalBackend(workers=1), progress=False).ok
    run = tmp_path / "runs" / "circle-3__sac__s0"
    (run / "summary.json").unlink()  # as if stopped after its checkpoint at 4
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1"]
    args += ["--interactions", "5", "--out", str(tmp_path), *FAST_ARGS, "--no-progress"]
    assert main([*args, "--dry-run"]) == 0
    assert "circle-3__sac__s0\tresumable" in capsys.readouterr().out
    assert main(args) == 0
    assert len(pd.read_csv(run / "metrics.csv")) == 5  # finished
    assert (tmp_path / "runs" / "circle-3__sac__s1" / "summary.json").is_file()
    assert main([*args, "--set", "sac.lr=1e-3", "--dry-run"]) == 2  # a setting still counts
    assert "made with other settings (agent.sac.lr" in capsys.readouterr().err
    # both invocations are recorded: the first's interval wins, as for a timed kernel
    assert main(["sweep", "--resume", str(tmp_path), "--interactions", "6", "--dry-run"]) == 0
    assert capsys.readouterr().out.count("resumable (extended to 6)") == 2


def test_a_failed_sweep_run_finished_by_hand_is_no_longer_called_failed(tmp_path, capsys):
    """``sili train --resume`` on a sweep's run claims it as a worker does, and with the claim
    goes the failure an earlier attempt recorded: the dry run said 'done (failed before, see
    its error.txt)' of a run finished since."""
    assert run_sweep(_spec(methods=["sac"], seeds=[0], interactions=5), tmp_path, progress=False).ok
    run = tmp_path / "runs" / "circle-3__sac__s0"
    (run / "summary.json").unlink()  # stopped after its checkpoint at 4 ...
    (run / "error.txt").write_text("Traceback ...: the attempt's failure")  # ... by a failure
    assert main(["sweep", "--resume", str(tmp_path), "--dry-run"]) == 0
    assert (
        "circle-3__sac__s0\tresumable (failed before, see its error.txt)" in capsys.readouterr().out
    )
    assert main(["train", "--resume", str(run), "--no-progress"]) == 0
    assert not (run / "error.txt").exists()
    capsys.readouterr()
    assert main(["sweep", "--resume", str(tmp_path), "--dry-run"]) == 0
    assert capsys.readouterr().out == "circle-3__sac__s0\tdone\n1 run\n"


def test_a_dry_run_refused_by_a_live_trainer_lists_each_run_as_it_would(tmp_path, capsys):
    """The listing before the refusal said only each run's state: 'done' of a run the
    extension would go on with, and nothing of an earlier failure."""
    assert run_sweep(_spec(methods=["sac"], seeds=[0, 1], interactions=3), tmp_path).ok
    s0, s1 = (tmp_path / "runs" / f"circle-3__sac__s{seed}" for seed in (0, 1))
    (s0 / "error.txt").write_text("Traceback ...")
    trainer = {"pid": os.getpid(), "host": socket.gethostname()}  # a live process on this host
    (s1 / "worker.json").write_text(json.dumps(trainer))
    capsys.readouterr()
    for extend, s0_line in ((["--interactions", "5"], "resumable (extended to 5)"), ([], "done")):
        if not extend:
            s0_line += " (failed before, see its error.txt)"
        assert main(["sweep", "--resume", str(tmp_path), *extend, "--dry-run"]) == 2
        printed = capsys.readouterr()
        assert (
            "circle-3__sac__s1 in" in printed.err and "is being trained by process" in printed.err
        )
        s1_line = f"circle-3__sac__s1\ttraining (process {os.getpid()})"
        assert printed.out == f"circle-3__sac__s0\t{s0_line}\n{s1_line}\n2 runs\n"


def test_a_record_that_cannot_run_is_named_and_a_dry_run_refuses_it_too(tmp_path, capsys):
    out = tmp_path / "sweep"
    base = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--out", str(out), *FAST_ARGS]
    assert main([*base, "--interactions", "2", "--no-progress"]) == 0
    record = out / "sweep.json"
    kept = json.loads(record.read_text())
    kept["invocations"][0]["betas"] = [5]  # a hand edit no sweep can have
    record.write_text(json.dumps(kept))
    capsys.readouterr()
    for again in (["sweep", "--resume", str(out)], [*base, "--interactions", "2"]):
        for dry in (["--dry-run"], []):  # a new invocation joins the record: it must read too
            assert main([*again, *dry]) == 2
            err = capsys.readouterr().err
            assert f"{record} records a sweep that cannot run: --beta applies to" in err, err
    first = {**kept["invocations"][0], "betas": None}
    for edit, said in (
        ({"seeds": [-1]}, "seed -1 is not allowed"),  # found where its runs are made
        (
            {"agent_overrides": {"sac.lr": "x"}},
            "setting sac.lr must be a number or a schedule (INTERACTION:VALUE",
        ),
    ):
        record.write_text(json.dumps({"invocations": [{**first, **edit}]}))
        assert main(["sweep", "--resume", str(out), "--dry-run"]) == 2
        assert f"{record} records a sweep that cannot run: {said}" in capsys.readouterr().err
    record.write_text("{")
    for dry in (["--dry-run"], []):  # a new invocation is added to the record: it must read
        assert main([*base, "--interactions", "2", *dry]) == 2
        assert f"{record} is damaged" in capsys.readouterr().err
    record.write_text('{"invocations": []}')  # not a sweep of no runs to resume
    for dry in (["--dry-run"], []):
        assert main(["sweep", "--resume", str(out), *dry]) == 2
        assert f"{record} is damaged (no invocation recorded)" in capsys.readouterr().err


def test_a_new_run_is_not_made_in_a_sweeps_or_a_collections_runs(tmp_path, capsys):
    """The sweep plans its own settings under a run's name (and would not resume another
    task's run there); a collection holds finished runs."""
    out = tmp_path / "sweep"
    base = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--out", str(out), *FAST_ARGS]
    assert main([*base, "--interactions", "2", "--no-progress"]) == 0
    run = out / "runs" / "circle-3__sac__s0"
    kept = (run / "metrics.csv").read_bytes()
    train = ["train", "--task", "circle-8", "--method", "oracle", "--interactions", "1"]
    for into in (run, out / "runs" / "mine", out / "runs" / "x" / ".." / "mine"):
        assert main([*train, "--out", str(into), "--overwrite"]) == 2
        assert (
            f"--out {into} is in the sweep {out}: `sili sweep --resume" in capsys.readouterr().err
        )
    with pytest.raises(ConfigError, match=r"run_dir .* is in the sweep .*: `sili sweep --resume"):
        SILI("circle-8", run_dir=run, overwrite=True)
    assert (run / "metrics.csv").read_bytes() == kept and not (out / "runs" / "mine").exists()
    assert main(["collect", str(out), "--into", str(tmp_path / "c")]) == 0
    new = tmp_path / "c" / "runs" / "mine"
    assert main([*train, "--out", str(new)]) == 2
    assert "is in the results collection" in capsys.readouterr().err and not new.exists()
    assert main(["train", "--resume", str(run), "--interactions", "3", "--no-progress"]) == 0


def test_overwrite_starts_the_sweep_anew_and_keeps_a_users_files(tmp_path, capsys):
    out = tmp_path / "sweep"
    base = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--out", str(out), *FAST_ARGS]
    assert main([*base, "--seeds", "0-1", "--interactions", "2", "--no-progress"]) == 0
    s0, s1 = out / "runs" / "circle-3__sac__s0", out / "runs" / "circle-3__sac__s1"
    (out / "notes.txt").write_text("mine")
    (s0 / "plot.png").write_text("mine")
    again = [*base, "--seeds", "0", "--interactions", "3"]
    assert main(again) == 2  # other settings on disk: refused without --overwrite
    assert "has 2 interactions, fewer than the 3 asked for now; extend the sweep's runs first" in (
        capsys.readouterr().err
    )
    assert main([*again, "--overwrite", "--dry-run"]) == 0
    assert capsys.readouterr().out == "circle-3__sac__s0\tnew\ncircle-3__sac__s1\tremoved\n1 run\n"
    assert len(pd.read_csv(s0 / "metrics.csv")) == 2 and s1.is_dir()  # a dry run changes nothing
    trainer = {"pid": os.getpid(), "host": socket.gethostname()}  # a live process on this host
    (s1 / "worker.json").write_text(json.dumps(trainer))
    assert main([*again, "--overwrite"]) == 2  # e.g. an orphan still saving its interaction
    assert f"circle-3__sac__s1 in {out} is being trained by process" in capsys.readouterr().err
    for dry in ([], ["--dry-run"]):  # nor resumed beside it; a dry run says so as well
        assert main(["sweep", "--resume", str(out), "--no-progress", *dry]) == 2
        printed = capsys.readouterr()
        assert f"circle-3__sac__s1 in {out} is being trained by process" in printed.err
        listed = f"circle-3__sac__s0\tdone\ncircle-3__sac__s1\ttraining (process {os.getpid()})"
        assert printed.out == (f"{listed}\n2 runs\n" if dry else "")  # where each run stands
    (s1 / "worker.json").unlink()
    (out / "figures").mkdir()
    plotted = ["circle-3.png", "circle-3.pdf", "circle-3_beta.svg", "overview.png"]
    for name in [*plotted, "mine.png"]:
        (out / "figures" / name).write_text("the replaced sweep's" if name in plotted else "mine")
    assert main([*again, "--overwrite", "--no-progress"]) == 0
    assert len(pd.read_csv(s0 / "metrics.csv")) == 3  # trained anew, not resumed
    assert not s1.exists()  # the replaced sweep's run, which the new one does not plan
    # sili plot's figures showed the replaced sweep; a user's own figure beside them stays
    assert [p.name for p in (out / "figures").iterdir()] == ["mine.png"]
    assert (out / "notes.txt").read_text() == (s0 / "plot.png").read_text() == "mine"
    recorded = json.loads((out / "sweep.json").read_text())["invocations"]
    assert [(r["seeds"], r["interactions"]) for r in recorded] == [([0], 3)]
    assert set(pd.read_csv(out / "runs.csv")["run"]) == {"circle-3__sac__s0"}
    assert main(["sweep", "--resume", str(out), "--overwrite"]) == 2
    assert "it takes no --overwrite" in capsys.readouterr().err
    # what cannot be told safely is refused, in a dry run too: a damaged record ...
    record = (out / "sweep.json").read_text()
    (out / "sweep.json").write_text('{"invocations": [{"bogus": 1}]}')
    for dry in ([], ["--dry-run"]):
        assert main([*again, "--overwrite", *dry]) == 2
        err = capsys.readouterr().err
        assert "sweep.json is damaged (TypeError" in err and "cannot tell which runs" in err
    assert main(["sweep", "--resume", str(out)]) == 2  # a clear error, not a traceback
    assert "sweep.json is damaged (TypeError" in capsys.readouterr().err
    # ... and a results collection, whose runs may be the only copy
    (out / "sweep.json").write_text(record)
    collection = tmp_path / "collection"
    assert main(["collect", str(out), "--into", str(collection)]) == 0
    into = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0", *FAST_ARGS]
    into += ["--interactions", "3", "--out", str(collection), "--overwrite"]
    for dry in ([], ["--dry-run"]):
        assert main([*into, *dry]) == 2
        assert "is a results collection, not a sweep" in capsys.readouterr().err
    assert (collection / "runs" / "circle-3__sac__s0" / "config.json").is_file()


def test_resume_with_interactions_extends_every_run_as_if_started_with_that_budget(
    tmp_path, capsys
):
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sili", "--seeds", "0-1"]
    args += ["--interactions", "4", "--checkpoint-every", "3", *FAST_ARGS, "--out", str(out)]
    assert main([*args, "--no-progress"]) == 0
    names = ["circle-3__sili-bschedule__s0", "circle-3__sili-bschedule__s1"]
    capsys.readouterr()
    for shorter, dry in (("3", ["--dry-run"]), ("2", [])):
        assert main(["sweep", "--resume", str(out), "--interactions", shorter, *dry]) == 2
        err = capsys.readouterr().err
        assert "would shorten the sweep" in err and "(allowed: >= 4)" in err
    assert main(["sweep", "--resume", str(out), "--interactions", "7", "--dry-run"]) == 0
    assert (
        capsys.readouterr().out
        == "".join(f"{n}\tresumable (extended to 7)\n" for n in names) + "2 runs\n"
    )
    assert main(["sweep", "--resume", str(out), "--interactions", "7", "--no-progress"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["done"], report["already_done"], report["failed"]) == (2, 0, {})
    recorded = json.loads((out / "sweep.json").read_text())["invocations"]
    assert [r["interactions"] for r in recorded] == [7]  # the record is the extended sweep
    run = out / "runs" / names[0]
    cfg = RunConfig.from_dict(json.loads((run / "config.json").read_text())["run"])
    assert cfg.interactions == 7
    train(cfg, tmp_path / "ref", progress=False)  # the same run, started with 7
    pd.testing.assert_frame_equal(
        _without_wall_time(pd.read_csv(run / "metrics.csv")),
        _without_wall_time(pd.read_csv(tmp_path / "ref" / "metrics.csv")),
    )
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0  # nothing left to do
    assert json.loads(capsys.readouterr().out)["already_done"] == 2


def test_a_run_an_earlier_version_named_after_the_default_controller_is_found(tmp_path, capsys):
    """Sweeps with --controller mink,osc named the mink runs sawyer-reach-mink__...; the same run
    is sawyer-reach__... now, with or without --controller, and its folder is taken over."""
    spec = SweepSpec(
        tasks=["sawyer-reach"],
        methods=["sac"],
        seeds=[0],
        interactions=2,
        controllers=["mink", "osc"],
    )
    mink = expand(spec)[0]
    old = tmp_path / "runs" / "sawyer-reach-mink__sac__s0"
    old.mkdir(parents=True)
    (old / "config.json").write_text(json.dumps({"run": mink.config.to_dict()}))
    args = ["sweep", "--tasks", "sawyer-reach", "--methods", "sac", "--interactions", "2"]
    for controllers in (["--controller", "mink,osc"], []):
        assert main([*args, *controllers, "--out", str(tmp_path), "--dry-run"]) == 0
        assert capsys.readouterr().out.splitlines()[0] == (
            "sawyer-reach__sac__s0\tnew (its folder sawyer-reach-mink__sac__s0 is renamed to it "
            "first)"
        )


def test_a_controller_given_as_a_task_argument_is_the_sweeps_controller(tmp_path, capsys):
    """As sili train takes either: the run is named by it, as with --controller."""
    args = ["sweep", "--tasks", "sawyer-reach", "--methods", "sac", "--interactions", "2"]
    planned = []
    for given in (["--controller", "osc"], ["--env-kwarg", "controller=osc"]):
        assert main([*args, *given, "--out", str(tmp_path / "s"), "--dry-run"]) == 0
        planned.append(capsys.readouterr().out)
    assert planned[0] == planned[1] == "sawyer-reach-osc__sac__s0\tnew\n1 run\n"
    assert main([*args, "--env-kwarg", "controller=3", "--out", str(tmp_path / "s")]) == 2
    assert "--env-kwarg controller=3: give controller names, e.g. osc" in capsys.readouterr().err


def test_a_run_an_earlier_version_named_after_the_sweeps_latent_is_resumed_not_retrained(
    tmp_path, capsys
):
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac,stable", "--latent", "continuous"]
    assert main([*args, "--interactions", "2", *FAST_ARGS, "--out", str(out), "--no-progress"]) == 0
    runs = out / "runs"
    (runs / "circle-3__sac__s0").rename(runs / "circle-3__sac-continuous__s0")  # as named before
    # a resume refused for another run's sake renames nothing
    config = runs / "circle-3__stable-continuous__s0" / "config.json"
    kept = config.read_text()
    config.write_text(kept.replace('"seed": 0', '"seed": 7'))
    capsys.readouterr()
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 2
    assert "seed: 7 on disk, 0 now" in capsys.readouterr().err
    assert (runs / "circle-3__sac-continuous__s0").is_dir()
    config.write_text(kept)
    assert main(["sweep", "--resume", str(out), "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == (
        "circle-3__sac__s0\tdone (its folder circle-3__sac-continuous__s0 is renamed to it first)"
    )
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert json.loads(capsys.readouterr().out)["already_done"] == 2
    names = ["circle-3__sac__s0", "circle-3__stable-continuous__s0"]
    assert sorted(p.name for p in runs.iterdir()) == names
    assert sorted(pd.read_csv(out / "runs.csv")["run"]) == names
    # --overwrite removes the run under either name
    (runs / "circle-3__sac__s0").rename(runs / "circle-3__sac-continuous__s0")
    assert (
        main(
            [
                *args,
                "--interactions",
                "2",
                *FAST_ARGS,
                "--out",
                str(out),
                "--overwrite",
                "--dry-run",
            ]
        )
        == 0
    )
    assert "circle-3__sac-continuous__s0\tremoved" in capsys.readouterr().out


def test_an_extension_checks_every_run_first_and_one_cut_short_is_finished_by_a_resume(
    tmp_path, capsys
):
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1"]
    assert main([*args, "--interactions", "3", *FAST_ARGS, "--out", str(out), "--no-progress"]) == 0
    s0, s1 = (out / "runs" / f"circle-3__sac__s{i}" for i in (0, 1))
    record = (out / "sweep.json").read_text()
    # a run extended on its own past the sweep: refused before anything changes, with the fix
    assert main(["train", "--resume", str(s1), "--interactions", "5", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["sweep", "--resume", str(out), "--interactions", "4", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"sili sweep --resume {out} --interactions 5" in err
    assert (out / "sweep.json").read_text() == record and (s0 / "summary.json").is_file()
    # a finished run kept without its checkpoint cannot go on: refused, nothing changed
    (s0 / "checkpoint.pt").rename(tmp_path / "kept.pt")
    assert main(["sweep", "--resume", str(out), "--interactions", "5", "--dry-run"]) == 2
    assert "without its checkpoint.pt" in capsys.readouterr().err
    assert (out / "sweep.json").read_text() == record
    (tmp_path / "kept.pt").rename(s0 / "checkpoint.pt")
    # an extension cut short after its record was written: a plain resume finishes it
    write_invocations(out, [replace(spec, interactions=5) for spec in recorded_specs(out)])
    assert main(["sweep", "--resume", str(out), "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines()[:2] == [
        "circle-3__sac__s0\tresumable (extended to 5)",
        "circle-3__sac__s1\tdone",
    ]
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert len(pd.read_csv(s0 / "metrics.csv")) == len(pd.read_csv(s1 / "metrics.csv")) == 5
    # a new invocation with a larger budget is another sweep, not an extension
    capsys.readouterr()
    assert main([*args, "--interactions", "6", *FAST_ARGS, "--out", str(out)]) == 2
    said = (
        f"fewer than the 6 asked for now; extend the sweep's runs first (sili sweep --resume {out}"
    )
    assert said in capsys.readouterr().err


def test_a_run_extended_but_left_with_its_short_summary_is_resumed_not_skipped(tmp_path):
    """An extension stopped by an earlier version left the old summary beside the raised
    target: the run is resumable, and a resume trains it to its new length."""
    from sili_robots.runs import set_target

    spec = _spec(methods=["sac"], seeds=[0], interactions=3)
    assert run_sweep(spec, tmp_path, LocalBackend(workers=1), progress=False).ok
    run = tmp_path / "runs" / "circle-3__sac__s0"
    set_target(run, 5)
    assert json.loads((run / "summary.json").read_text())["interactions"] == 3
    specs = [replace(s, interactions=5) for s in recorded_specs(tmp_path)]
    report = run_sweep(specs, tmp_path, LocalBackend(workers=1), progress=False, recorded=True)
    assert report.ok and report.skipped == [] and list(report.outcomes) == [run.name]
    assert len(pd.read_csv(run / "metrics.csv")) == 5


def test_a_run_under_its_own_name_wins_over_a_folder_under_a_former_name(tmp_path, capsys):
    """A user's leftover under the name an earlier version gave the run is neither taken as
    the run nor renamed over it."""
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac,stable", "--latent", "continuous"]
    assert main([*args, "--interactions", "2", *FAST_ARGS, "--out", str(out), "--no-progress"]) == 0
    current, former = (out / "runs" / f"circle-3__sac{s}__s0" for s in ("", "-continuous"))
    former.mkdir()
    config = json.loads((current / "config.json").read_text())
    config["run"]["seed"] = 7
    (former / "config.json").write_text(json.dumps(config))
    capsys.readouterr()
    assert main(["sweep", "--resume", str(out), "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "circle-3__sac__s0\tdone"
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert json.loads(capsys.readouterr().out)["already_done"] == 2
    assert json.loads((former / "config.json").read_text())["run"]["seed"] == 7
    assert (current / "summary.json").is_file()


def test_overwrite_of_a_folder_with_an_empty_runs_folder_starts_the_sweep(tmp_path, capsys):
    """An --overwrite cut short after it removed the record leaves runs/ empty: that is no
    results collection."""
    out = tmp_path / "sweep"
    (out / "runs").mkdir(parents=True)
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0"]
    args += ["--interactions", "2", *FAST_ARGS, "--out", str(out), "--overwrite"]
    assert main([*args, "--dry-run"]) == 0
    assert capsys.readouterr().out == "circle-3__sac__s0\tnew\n1 run\n"
    assert main([*args, "--no-progress"]) == 0
    (out / "sweep.json").unlink()  # runs/ holding a run, no record: a results collection
    assert main([*args, "--dry-run"]) == 2
    assert "is a results collection, not a sweep" in capsys.readouterr().err


def test_the_closing_line_counts_the_runs_finished_earlier(tmp_path, capsys):
    small = {"methods": ["sac"], "interactions": 2}
    first = _spec(**small, seeds=[0])
    assert run_sweep(first, tmp_path, LocalBackend(workers=1), progress=False).ok
    capsys.readouterr()
    again = _spec(**small, seeds=[0, 1])
    report = run_sweep(again, tmp_path, LocalBackend(workers=1), progress=False)
    assert report.ok and report.skipped == ["circle-3__sac__s0"]
    assert "sweep: 2 done (1 of them earlier), 0 failed, 0 not run" in capsys.readouterr().err


def test_a_stop_file_left_by_an_earlier_sweep_does_not_stop_the_next(tmp_path):
    run = tmp_path / "runs" / "circle-3__sac__s0"
    run.mkdir(parents=True)
    (run / "stop").touch()  # as a sweep killed while it stopped its workers leaves it
    spec = _spec(methods=["sac"], seeds=[0], interactions=3)
    assert run_sweep(spec, tmp_path, LocalBackend(workers=1), progress=False).ok
    assert len(pd.read_csv(run / "metrics.csv")) == 3 and not (run / "stop").exists()


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is dead too
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split(")")[-1].split()[0] != "Z"


def _long_sweep(tmp_path, **popen_kwargs):
    """A one-run sweep of 5,000 interactions in its own process, and its run's directory."""
    out = tmp_path / "sweep"
    args = ["--tasks", "circle-3", "--methods", "sac", "--seeds", "0", "--interactions", 5000]
    args += [*FAST_ARGS, "--no-progress", "--out", out]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", "sweep", *map(str, args)], **popen_kwargs
    )
    return proc, out / "runs" / "circle-3__sac__s0"


def test_workers_stop_when_the_sweep_process_is_killed(tmp_path):
    proc, run_dir = _long_sweep(tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert wait_for(lambda: metrics_rows(run_dir / "metrics.csv") >= 5)
        pid = json.loads((run_dir / "worker.json").read_text())["pid"]
    finally:
        proc.kill()
        proc.wait()
    assert wait_for(lambda: not _alive(pid), timeout=20), "the worker outlived its sweep"
    assert not (run_dir / "summary.json").exists()
    assert metrics_rows(run_dir / "metrics.csv") < 5000


def test_sigterm_stops_a_sweep_as_ctrl_c_does(tmp_path):
    """`timeout`, a job scheduler or `kill`: the workers stop, the tables and the report are
    written, the exit code says which signal."""
    proc, run_dir = _long_sweep(tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out = run_dir.parents[1]
    pids = []

    def training() -> bool:
        if metrics_rows(run_dir / "metrics.csv") < 5:
            return False
        pids.append(json.loads((run_dir / "worker.json").read_text())["pid"])
        return True

    stderr = signal_when(proc, training)
    pid = pids[0]
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "sweep: 0 done, 0 failed, 1 not run (1 stopped midway, resumable)" in stderr
    assert "sili sweep: stopped by SIGTERM" in stderr and "Traceback" not in stderr
    assert pd.read_csv(out / "runs.csv")["status"].tolist() == ["incomplete"]
    assert wait_for(lambda: not _alive(pid), timeout=20)
    # the worker logged and checkpointed the interaction it was in before it stopped
    checkpointed = torch.load(run_dir / "checkpoint.pt", weights_only=False)["interaction"]
    assert checkpointed == metrics_rows(run_dir / "metrics.csv") >= 5


def test_a_sigterm_to_the_whole_process_group_loses_no_interaction(tmp_path):
    """`timeout` and job schedulers signal the sweep and its workers together: each worker
    still logs and checkpoints the interaction it is in (the sweep's own stop used to reach
    it as a second signal, which stops at once)."""
    out = tmp_path / "sweep"
    args = ["--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1", "--interactions", 5000]
    args += [*FAST_ARGS, "--workers", 2, "--checkpoint-every", 1000, "--no-progress", "--out", out]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", "sweep", *map(str, args)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as under `timeout`
    )
    runs = [out / "runs" / f"circle-3__sac__s{i}" for i in (0, 1)]
    try:
        assert wait_for(lambda: all(metrics_rows(r / "metrics.csv") >= 3 for r in runs), 240)
        os.killpg(proc.pid, signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr
    for run in runs:
        checkpointed = torch.load(run / "checkpoint.pt", weights_only=False)["interaction"]
        assert checkpointed == metrics_rows(run / "metrics.csv") >= 3
        assert not (run / "stop").exists() and not (run / "worker.json").exists()


def test_one_ctrl_c_delivered_twice_by_timeout_still_checkpoints_the_run(tmp_path):
    """``timeout -s INT`` signals the sweep, then its process group: the sweep gets SIGINT
    twice, a moment apart on a busy machine. That is one stop: the worker still logs and
    checkpoints its interaction (the second used to stop it at once, losing every interaction
    since its last checkpoint)."""
    out = tmp_path / "sweep"
    args = ["--tasks", "circle-3", "--methods", "sac", "--seeds", "0", "--interactions", 5000]
    args += ["--workers", 1, "--checkpoint-every", 1000, "--no-progress", "--out", out]
    # an interaction of 100 updates: the sweep's stop waits a second or so for it to end
    args += ["--set", "updates_per_step=2", "--set", "random_interactions=1"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", "sweep", *map(str, args)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    run = out / "runs" / "circle-3__sac__s0"
    try:
        assert wait_for(lambda: metrics_rows(run / "metrics.csv") >= 2, 240)
        proc.send_signal(signal.SIGINT)  # timeout's signal to the sweep ...
        sent = time.monotonic()
        assert wait_for(lambda: (run / "stop").exists(), 30)
        os.killpg(proc.pid, signal.SIGINT)  # ... and to its group, while the sweep stops
        gap = time.monotonic() - sent
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    if gap >= SAME_STOP_S:  # a second stop, as a person's: not what this test is about
        pytest.skip(f"the machine took {gap:.2f} s to see the sweep stopping")
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert "1 stopped midway, resumable" in stderr
    checkpointed = torch.load(run / "checkpoint.pt", weights_only=False)["interaction"]
    assert checkpointed == metrics_rows(run / "metrics.csv") >= 3


def test_progress_display_counts_runs_and_interactions(tmp_path):
    import io

    from rich.console import Console

    from sili_robots.sweep.progress import SweepProgress
    from sili_robots.sweep.worker import Job, Outcome

    jobs = [Job(f"r{i}", {}, str(tmp_path / f"r{i}")) for i in range(3)]
    for i, rows in enumerate((4, 2, 0)):
        (tmp_path / f"r{i}").mkdir()
        lines = ["interaction"] + [str(j) for j in range(rows)]
        (tmp_path / f"r{i}" / "metrics.csv").write_text("\n".join(lines) + "\n")
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=True, width=150, color_system=None)
    display = SweepProgress(
        jobs, {"r0": 10, "r1": 10, "r2": 10, "old": 10}, already_done=1, console=console
    )
    with display:
        display.started(jobs[0])
        display.started(jobs[1])
        display.finished(Outcome("r0", "done", wall_time_s=1.5, verdict="SILI held [it]"))
        display.finished(Outcome("r1", "failed", error="ConfigError: bad [thing]"))
        counts = display._counts()
        assert "2 done" in counts and "0 running" in counts and "1 failed" in counts
        assert "1 pending (of 4)" in counts
        # finished runs count in full, a failed one only for what it logged: 10 + 10 + 2 + 0
        assert display._completed() == 22 and display._total_interactions == 32
    out = buf.getvalue()
    assert "done r0 in 1.5 s: SILI held [it]" in out  # the run's verdict, not eaten as markup
    assert "failed r1: ConfigError: bad [thing]" in out  # error text not eaten as markup
    assert "sweep: 2 done (1 of them earlier), 1 failed, 1 not run" in out


def test_a_stopped_sweep_calls_resumable_only_the_runs_with_a_checkpoint(tmp_path):
    """A run stopped while its worker started has no checkpoint: a resume trains it again."""
    import io

    from rich.console import Console

    from sili_robots.sweep.progress import SweepProgress
    from sili_robots.sweep.worker import Job

    jobs = [Job(f"r{i}", {}, str(tmp_path / f"r{i}")) for i in range(3)]
    for job in jobs:
        (tmp_path / job.name).mkdir()
    (tmp_path / "r0" / "checkpoint.pt").write_bytes(b"")

    def stopped(running: list[Job]) -> str:
        buf = io.StringIO()
        display = SweepProgress(
            jobs,
            dict.fromkeys(("r0", "r1", "r2"), 10),
            already_done=0,
            console=Console(file=buf, width=200),
        )
        with display:
            for job in running:
                display.started(job)
        return buf.getvalue()

    assert "3 not run (1 stopped midway, resumable)" in stopped(jobs[:1])
    said = (
        "3 not run (3 stopped midway: 1 resumable, 2 before a first checkpoint, they start again)"
    )
    assert said in stopped(jobs)
    assert "(1 stopped midway: 0 resumable, 1 before a first checkpoint, it starts again)" in (
        stopped(jobs[1:2])
    )
    # one that ended as the sweep stopped, its outcome never reported (Ray's grace wait): done
    (tmp_path / "r0" / "summary.json").write_text("{}")
    assert "sweep: 1 done, 0 failed, 2 not run (2 stopped midway: 0 resumable" in stopped(jobs)


@pytest.mark.slow
def test_driving_and_sawyer_runs_sweep_side_by_side(tmp_path):
    """Two Driving runs at once (libsumo: one simulation per process, so one run per worker)
    and Sawyer-Reach under two controllers."""
    spec = SweepSpec(
        tasks=["driving", "sawyer-reach"],
        methods=["sac"],
        seeds=[0, 1],
        interactions=3,
        controllers=["mink", "osc"],
        agent_overrides=FAST,
    )
    report = run_sweep(spec, tmp_path, LocalBackend(workers=2), progress=False)
    assert report.ok, report.failed
    runs = pd.read_csv(tmp_path / "runs.csv").set_index("run")
    assert list(runs.index) == [
        "driving__sac__s0",
        "driving__sac__s1",
        "sawyer-reach-osc__sac__s0",
        "sawyer-reach-osc__sac__s1",
        "sawyer-reach__sac__s0",  # the default controller: the run without --controller
        "sawyer-reach__sac__s1",
    ]
    assert (runs["status"] == "done").all()
    assert runs.loc["sawyer-reach-osc__sac__s0", "controller"] == "osc"
    assert runs.loc["sawyer-reach-osc__sac__s0", "task_args"] == '{"controller": "osc"}'
    assert pd.isna(runs.loc["sawyer-reach__sac__s0", "task_args"])  # the default
    table = pd.read_csv(tmp_path / "results.csv")
    mink = table[table.run == "sawyer-reach__sac__s0"]["task_reward"].to_numpy()
    osc = table[table.run == "sawyer-reach-osc__sac__s0"]["task_reward"].to_numpy()
    assert not np.allclose(mink, osc)  # the controller reached the task


def test_results_table_names_the_task_arguments_a_run_departs_in(tmp_path):
    """A run given another margin is told apart; one given its version's own margin, or its
    task's default controller by name, is not."""
    for name, margin in (("wide", "0.3"), ("own", "0.1")):
        args = ["train", "--task", "circle-3", "--interactions", "2", *FAST_ARGS, "--no-progress"]
        out = tmp_path / "runs" / name
        assert main([*args, "--env-kwarg", f"outside_margin={margin}", "--out", str(out)]) == 0
    for name, controller in (("sawyer", []), ("mink", ["--controller", "mink"])):
        args = ["train", "--task", "sawyer-reach", "--interactions", "1", *FAST_ARGS]
        out = tmp_path / "runs" / name
        assert main([*args, *controller, "--no-progress", "--out", str(out)]) == 0
    table = results_table(tmp_path).groupby("run")[["task_args", "controller"]].first()
    assert table["task_args"].to_dict() == {
        "mink": "",  # the default controller, named
        "own": "",
        "sawyer": "",
        "wide": '{"outside_margin": 0.3}',
    }
    # named or not, the default controller is one variant of the task
    assert table["controller"].to_dict() == {
        "mink": "mink",
        "own": "",
        "sawyer": "mink",
        "wide": "",
    }


def test_without_tensorboard_no_scalars_are_written(tmp_path, monkeypatch):
    monkeypatch.setattr(tb, "available", lambda: False)
    with pytest.raises(Exception, match=r"pip install 'sili-robots\[tensorboard\]'"):
        run_sweep(_spec(), tmp_path, LocalBackend(workers=1), tensorboard_scalars=True)
    spec = _spec(methods=["sac"], seeds=[0], interactions=2)
    report = run_sweep(spec, tmp_path / "s", LocalBackend(workers=1), progress=False)
    assert report.ok
    run_dir = tmp_path / "s" / "runs" / "circle-3__sac__s0"
    assert (run_dir / "summary.json").exists() and not (run_dir / "tb").exists()


def test_a_tensorboard_writer_that_cannot_start_only_turns_the_scalars_off(tmp_path, monkeypatch):
    """When TensorBoard's writer cannot be loaded, the run's block still completes: a warning,
    no error, no tb/."""
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # as if it were absent
    ran = []
    with (
        pytest.warns(UserWarning, match=f"TensorBoard scalars off for {tmp_path.name}"),
        tb.mirrored(tmp_path, enabled=True),
    ):
        ran.append(True)
    assert ran == [True] and not (tmp_path / "tb").exists()


@pytest.mark.skipif(not tb.available(), reason="tensorboard is not installed")
def test_a_loss_that_is_not_finite_is_left_out_of_the_scalars(tmp_path):
    """A diverged (nan/inf) loss in metrics.csv is not mirrored as a TensorBoard point; the
    finite ones are."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from sili_robots.metrics import METRIC_COLUMNS

    def row(j, loss):
        values = {"interaction": j, "task_reward": -1.0, "strategy_changed": 0, "critic_loss": loss}
        return ",".join(str(values.get(c, "")) for c in METRIC_COLUMNS) + "\r\n"

    tail = tb.MetricsTail(tmp_path, interval=60)  # no metrics.csv yet: any new one is the run's
    tail.start()
    new = tmp_path / "new.csv"
    rows = row(0, 0.5) + row(1, "nan") + row(2, "inf") + row(3, 0.25)
    new.write_text(",".join(METRIC_COLUMNS) + "\r\n" + rows)
    os.replace(new, tmp_path / "metrics.csv")
    tail.stop()
    assert tail.rows_written == 4 and not tail.failed
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    assert [(e.step, e.value) for e in acc.Scalars("loss/critic")] == [(0, 0.5), (3, 0.25)]
    assert [e.step for e in acc.Scalars("reward/task")] == [0, 1, 2, 3]


@pytest.mark.skipif(not tb.available(), reason="tensorboard is not installed")
def test_tensorboard_tail_skips_rows_a_resume_drops_and_waits_for_whole_lines(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from sili_robots.metrics import METRIC_COLUMNS

    def row(j, reward):
        values = {"interaction": j, "task_reward": reward, "strategy_changed": j % 2}
        return ",".join(str(values.get(c, "")) for c in METRIC_COLUMNS) + "\r\n"

    header = ",".join(METRIC_COLUMNS) + "\r\n"
    metrics = tmp_path / "metrics.csv"
    metrics.write_text(header + "".join(row(j, -99.0) for j in range(5)))  # before the kill
    tail = tb.MetricsTail(tmp_path, interval=60)
    tail.start()
    tail.poll()
    assert tail.rows_written == 0  # the old file: training has not trimmed it yet
    new = tmp_path / "new.csv"
    new.write_text(header + row(0, -1.0) + row(1, -2.0) + row(2, -3.0)[:7])
    os.replace(new, metrics)  # what MetricsWriter does when a run (re)starts
    tail.poll()
    assert tail.rows_written == 2  # the half-written third row waits
    with metrics.open("a") as f:
        f.write(row(2, -3.0)[7:])
    tail.stop()
    assert tail.rows_written == 3
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    assert [(e.step, e.value) for e in acc.Scalars("reward/task")] == [
        (0, -1.0),
        (1, -2.0),
        (2, -3.0),
    ]
    assert [e.value for e in acc.Scalars("stability/true")] == [0.0, 1.0]  # from interaction 1


def test_in_a_log_the_closing_line_starts_a_line_of_its_own(tmp_path):
    """Redirected, rich's live display ends without a newline: the closing line was glued on."""
    import io

    from rich.console import Console

    from sili_robots.sweep.progress import SweepProgress

    buf = io.StringIO()
    with SweepProgress([], {"old": 10}, already_done=1, console=Console(file=buf, width=100)):
        pass
    assert "\nsweep: 1 done (1 of them earlier)" in buf.getvalue()


def test_overwrite_removes_the_figures_of_a_task_the_sweep_was_given_by_another_name(tmp_path):
    out = tmp_path / "sweep"
    base = ["sweep", "--tasks", "sili/Circle3-v1", "--methods", "sac", "--out", str(out)]
    assert main([*base, *FAST_ARGS, "--interactions", "1", "--no-progress"]) == 0
    (out / "figures").mkdir()
    for name in ("circle-3.png", "circle-3_beta.pdf", "overview.png", "mine.png"):
        (out / "figures" / name).write_text("")  # sili plot names them by the runs' circle-3
    assert main([*base, *FAST_ARGS, "--interactions", "2", "--no-progress", "--overwrite"]) == 0
    assert [p.name for p in (out / "figures").iterdir()] == ["mine.png"]


def test_a_sweeps_run_extended_by_hand_updates_the_sweeps_tables(tmp_path, capsys, monkeypatch):
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0"]
    assert main([*args, "--interactions", "3", *FAST_ARGS, "--out", str(out), "--no-progress"]) == 0
    run = out / "runs" / "circle-3__sac__s0"
    assert main(["train", "--resume", str(run), "--interactions", "5", "--no-progress"]) == 0
    assert pd.read_csv(out / "runs.csv")["interactions_logged"].tolist() == [5]
    assert len(pd.read_csv(out / "results.csv")) == 5
    monkeypatch.chdir(run)  # from inside the run: runs/NAME/../NAME
    assert (
        main(["train", "--resume", f"../{run.name}", "--interactions", "6", "--no-progress"]) == 0
    )
    assert len(pd.read_csv(out / "results.csv")) == 6
    monkeypatch.chdir(tmp_path)
    elsewhere = tmp_path / "disk2" / "circle-3__sac__s0"  # a run kept elsewhere, linked in
    elsewhere.parent.mkdir()
    run.rename(elsewhere)
    run.symlink_to(elsewhere, target_is_directory=True)
    assert main(["train", "--resume", str(run), "--interactions", "7", "--no-progress"]) == 0
    assert len(pd.read_csv(out / "results.csv")) == 7


def test_a_ray_address_is_probed_where_its_port_can_be_told(monkeypatch):
    import ray._private.services

    from sili_robots.errors import ConfigError
    from sili_robots.sweep.ray_backend import check_reachable

    for nothing_there in ("127.0.0.1:1", "[::1]:1", "ray://127.0.0.1:1", "localhost:1"):
        with pytest.raises(ConfigError, match=r"cannot connect to Ray at .*: Connection refused"):
            check_reachable(nothing_there)
    for not_probed in ("::1", "fe80::1%eth0"):  # ray.init reads these itself
        check_reachable(not_probed)
    for given in ("127.0.0.1:1", "ray://127.0.0.1:1"):  # what auto stands for, as ray.init reads
        monkeypatch.setenv("RAY_ADDRESS", given)
        said = rf"at '{given}' \(--ray-address auto\): Connection refused"
        with pytest.raises(ConfigError, match=said):
            check_reachable("auto")
    monkeypatch.delenv("RAY_ADDRESS")  # and no cluster started on this machine:
    monkeypatch.setattr(ray._private.services, "canonicalize_bootstrap_address", lambda a: None)
    with pytest.raises(ConfigError, match="auto finds no running Ray cluster"):
        check_reachable("auto")


@pytest.mark.parametrize("group_sigterm", [False, True])
def test_a_worker_past_its_grace_is_stopped_at_once_with_its_finally_blocks(
    group_sigterm, tmp_path, monkeypatch
):
    """Asked to stop, a worker finishes its interaction; past STOP_GRACE_S the sweep's STOP_NOW
    stops it at once (a SIGTERM is held until the interaction ends), exit 143, not SIGKILL,
    also when it already holds a SIGTERM sent to the whole process group."""
    from sili_robots.build import make_run_config
    from sili_robots.sweep import local
    from sili_robots.sweep.worker import Job

    # the first learning interaction (the third) takes seconds: 2,000 updates
    cfg = make_run_config("circle-3", "sac", 0, 5000, settings={**FAST, "updates_per_step": 40})
    run_dir = tmp_path / "run"
    backend = LocalBackend(workers=1)
    backend._ensure_forkserver()
    alive_r, alive_w = backend._ctx.Pipe(duplex=False)
    worker = backend._start(Job("run", cfg.to_dict(), str(run_dir)), alive_r)
    try:
        assert wait_for(lambda: metrics_rows(run_dir / "metrics.csv") >= 2)
        if group_sigterm:
            os.kill(worker.process.pid, signal.SIGTERM)  # held: the interaction goes on
        monkeypatch.setattr(local, "STOP_GRACE_S", 0.0)  # past its grace at once
        LocalBackend._stop([worker])
        assert worker.process.exitcode == 128 + signal.SIGTERM  # not -9: `finally` blocks ran
        assert metrics_rows(run_dir / "metrics.csv") == 2  # the long interaction was not waited for
        assert not (run_dir / "worker.json").exists()  # its claim given back on the way out
    finally:
        if worker.process.is_alive():
            worker.process.kill()
        alive_r.close()
        alive_w.close()


def test_a_worker_refuses_a_run_another_live_process_claimed_and_leaves_its_claim(tmp_path):
    """A `sili train --resume` started on a queued run of a sweep trains it; the sweep's worker,
    reaching it later, fails it with the reason instead of training beside (two writers of one
    checkpoint) and deleting the other process's claim. One process cannot claim a run twice."""
    from sili_robots.build import make_run_config
    from sili_robots.errors import ConfigError
    from sili_robots.sweep.state import process_started, training_claim
    from sili_robots.sweep.worker import Job, run_job

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    other = subprocess.Popen(["sleep", "60"])
    try:
        claim = {"pid": other.pid, "host": socket.gethostname()}
        claim["started"] = process_started(other.pid)
        (run_dir / "worker.json").write_text(json.dumps(claim))
        cfg = make_run_config("circle-3", "sac", 0, 2, settings=FAST)
        outcome = run_job(Job("run", cfg.to_dict(), str(run_dir)))
        assert outcome.status == "failed"
        assert f"being trained by process {other.pid}" in outcome.error
        assert json.loads((run_dir / "worker.json").read_text()) == claim
        assert not (run_dir / "metrics.csv").exists()
    finally:
        other.kill()
        other.wait()
    with training_claim(run_dir):  # the other process is gone: its claim is stale, taken over
        refused = pytest.raises(ConfigError, match=f"being trained by process {os.getpid()}")
        with refused, training_claim(run_dir):
            pass
        assert json.loads((run_dir / "worker.json").read_text())["pid"] == os.getpid()
    assert not (run_dir / "worker.json").exists()


def test_a_run_the_disk_refuses_fails_with_the_file_named_and_never_fails_the_sweep(tmp_path):
    """A worker's run that cannot write its checkpoint fails naming it (torch said "unexpected
    pos"); where even its error.txt cannot be written, the run still fails, not the worker."""
    from disk_helpers import file_size_limit

    from sili_robots.build import make_run_config
    from sili_robots.sweep.worker import Job, run_job

    cfg = make_run_config("circle-3", "sac", 0, 2, settings=FAST)
    with file_size_limit(20_000):  # config and history fit, a checkpoint (~44 kB) does not
        outcome = run_job(Job("run", cfg.to_dict(), str(tmp_path / "run")))
    assert outcome.status == "failed", outcome
    assert f"File too large: '{tmp_path / 'run' / 'checkpoint.pt'}'" in outcome.error
    assert "File too large" in (tmp_path / "run" / "error.txt").read_text()
    with file_size_limit(1):  # nothing can be written
        outcome = run_job(Job("run", cfg.to_dict(), str(tmp_path / "full")))
    assert outcome.status == "failed" and "File too large" in outcome.error, outcome
    assert not (tmp_path / "full" / "error.txt").exists()  # whole or not at all


def test_the_runs_table_tells_a_run_not_started_from_one_under_way(tiny_sweep, tmp_path):
    from sili_robots.sweep.results import runs_table

    out = tmp_path / "sweep"
    shutil.copytree(tiny_sweep[0], out)
    under_way, not_started = "circle-3__sac__s0", "circle-3__sac__s1"
    (out / "runs" / under_way / "summary.json").unlink()
    for name in ("summary.json", "metrics.csv", "checkpoint.pt"):
        (out / "runs" / not_started / name).unlink()
    metrics = out / "runs" / under_way / "metrics.csv"
    pd.read_csv(metrics).head(5).to_csv(metrics, index=False)  # 5 of its 8 logged so far
    table = runs_table(out).set_index("run")
    done = "circle-3__sili-bschedule__s0"
    status = table["status"]
    assert status[under_way] == "incomplete" and status[not_started] == "not started"
    assert status[done] == "done"
    assert table.loc[under_way, "interactions_logged"] == 5
    assert table.loc[done, "interactions_logged"] == 8
    finished = results_table(out).groupby("run")["finished"]
    assert not finished.any()[under_way] and finished.all()[done]


def test_a_users_folder_among_the_runs_is_not_a_run(tiny_sweep, tmp_path):
    from sili_robots.sweep.results import runs_table

    out = tmp_path / "sweep"
    shutil.copytree(tiny_sweep[0], out)
    (out / "runs" / "notes").mkdir()  # no config.json
    (out / "runs" / "notes" / "todo.txt").write_text("mine")
    assert "notes" not in set(runs_table(out)["run"]) | set(results_table(out)["run"])
    assert len(runs_table(out)) == 4


def test_a_run_recorded_before_profiles_is_tabled_as_the_package_profile(tiny_sweep, tmp_path):
    from sili_robots.sweep.results import runs_table

    out = tmp_path / "sweep"
    shutil.copytree(tiny_sweep[0], out)
    config = out / "runs" / "circle-3__sac__s0" / "config.json"
    record = json.loads(config.read_text())
    assert record["run"]["agent"].pop("profile") == "package"
    config.write_text(json.dumps(record))
    assert runs_table(out).set_index("run").loc["circle-3__sac__s0", "profile"] == "package"


def test_a_sweep_notes_runs_whose_kernels_are_slow_on_this_machine(tmp_path, monkeypatch):
    """As ``sili train`` does, once per kind, for the runs it will train: a sweep made on a
    machine with bfloat16 units and resumed on one without goes on ~10x slower."""
    from agent_helpers import timed_kernels

    even = {"onednn": 1e-3, "aten": 1e-3}
    timed_kernels(monkeypatch, tmp_path / "cache", even, {"float32": 1e-3, "bfloat16": 4.2e-3})
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1", *FAST_ARGS]
    args += ["--interactions", "1", "--no-progress", "--no-tensorboard", "--workers", "1"]
    res = sili_in_process(*args, "--set", "sac.precision=bfloat16", "--out", out)
    note = (
        "sili sweep: note: 2 runs train with sac.precision=bfloat16, 4.2x as slow as float32 on "
        "this machine (as timed for its default): a run keeps its kernels"
    )
    assert res.returncode == 0, res.stderr
    assert note in res.stderr
    res = sili_in_process("sweep", "--resume", out, "--interactions", "2", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert note in res.stderr  # extended: the runs made in bfloat16 keep it
    res = sili_in_process("sweep", "--resume", out, "--no-progress")
    assert res.returncode == 0 and "as slow as" not in res.stderr  # all done: none to train
    from sili_robots.errors import ConfigError

    def stopped(*args, **kwargs):
        raise ConfigError("stopped where the sweep would train")

    monkeypatch.setattr("sili_robots.sweep.runner.run_sweep", stopped)
    ray = sili_in_process("sweep", "--resume", out, "--interactions", "3", "--backend", "ray")
    assert "stopped where the sweep would train" in ray.stderr
    assert "as slow as" not in ray.stderr  # Ray's machines may be a cluster's: not this one's


def test_an_unwritable_kernel_cache_is_timed_once_per_process(monkeypatch):
    """Where kernels.json cannot be written, the choice is kept in the process: a sweep's note
    asks for every run it plans, and each timing takes seconds."""
    from sili_robots.agent import matmul

    monkeypatch.setenv("SILI_ROBOTS_CACHE", "/dev/null/cache")
    monkeypatch.setattr(matmul, "_MEASURED", {})
    timed = []

    def fake(precision_of):
        timed.append(precision_of)
        return {"float32": 1e-3, "bfloat16": 4e-3}

    monkeypatch.setattr(matmul, "time_precisions", fake)
    monkeypatch.setattr(matmul, "default_matmul", lambda: "aten")
    for _ in range(5):
        assert matmul.slow_kernels("aten", "bfloat16") == [
            ("sac.precision=bfloat16", 4.0, "float32")
        ]
    assert len(timed) == 1


def test_progress_counts_runs_under_way_as_running_not_pending(tmp_path):
    import io

    from rich.console import Console

    from sili_robots.sweep.progress import SweepProgress
    from sili_robots.sweep.worker import Job

    jobs = [Job(f"r{i}", {}, str(tmp_path / f"r{i}")) for i in range(3)]
    display = SweepProgress(
        jobs,
        dict.fromkeys(("r0", "r1", "r2"), 10),
        already_done=0,
        console=Console(file=io.StringIO()),
    )
    display.started(jobs[0])
    display.started(jobs[1])
    counts = display._counts()
    assert "2 running" in counts and "1 pending (of 3)" in counts


def test_a_claim_is_recognised_while_the_trainer_grows(tmp_path):
    """A process is told by its start time, not by anything that changes as it runs (its size)."""
    import mmap

    from sili_robots.sweep.state import process_started, training_claim, training_worker

    before = process_started(os.getpid())
    with training_claim(tmp_path):
        grown = mmap.mmap(-1, 256 * 1024 * 1024)
        grown.write(b"\1" * (64 << 20))  # resident too, not only mapped
        try:
            assert process_started(os.getpid()) == before
            assert training_worker(tmp_path) == os.getpid()
        finally:
            grown.close()


def test_a_sweep_given_through_python_names_what_each_field_takes(tmp_path):
    """A string where a list belongs was split into letters (controllers="osc" planned three
    runs), numpy numbers planned and then failed to record, and overwrite="no" retrained."""
    for fields, said in (
        ({"tasks": "circle-3"}, "SweepSpec tasks must be a non-empty list of task names, got 'c"),
        ({"controllers": "osc", "tasks": ["sawyer-reach"]}, "controllers must be a non-empty"),
        ({"seeds": []}, "SweepSpec seeds must be a non-empty list of seeds, got"),
        ({"seeds": None}, "SweepSpec seeds must be a non-empty list of seeds, got None"),
        ({"seeds": [0, 0]}, "SweepSpec seeds gives 0 twice"),
        ({"interactions": "1"}, "interactions must be an integer >= 1, got '1'"),
        ({"beta_schedule": "0:0.5"}, "beta_schedule must be a list of \\(interaction, value\\)"),
        ({"lr_schedule": [(0, 3e-4, 7)]}, "lr_schedule must be a list of \\(interaction, value\\)"),
        ({"agent_overrides": {1: 2}}, "agent_overrides must be a dict of names to values"),
    ):
        with pytest.raises(ConfigError, match=said):
            _spec(**fields)
    numpy = _spec(seeds=np.arange(1), interactions=np.int64(2), agent_overrides=FAST)
    assert run_sweep(numpy, tmp_path, LocalBackend(workers=1), progress=False).ok
    assert json.loads((tmp_path / "sweep.json").read_text())["invocations"][0]["seeds"] == [0]
    kept = (tmp_path / "runs" / "circle-3__sac__s0" / "config.json").stat().st_mtime_ns
    for call, said in (
        (lambda: run_sweep(numpy, tmp_path, overwrite="no"), "overwrite must be True or False"),
        (lambda: run_sweep([], tmp_path), "specs must be a SweepSpec or a non-empty list"),
        (lambda: run_sweep(numpy, tmp_path, backend="local"), "backend must be a sweep backend"),
        (lambda: LocalBackend(workers=1.5), r"workers must be an integer >= 1, got 1\.5"),
        (lambda: LocalBackend(retries="1"), "retries must be an integer >= 0, got '1'"),
        (lambda: LocalBackend(start_method="fork"), "start method 'fork' is not allowed"),
        (lambda: RayBackend(workers=0), "workers must be an integer >= 1, got 0"),
        (lambda: RayBackend(workers=1.5), r"workers must be an integer >= 1, got 1\.5"),
        (lambda: RayBackend(retries=-1), "retries must be an integer >= 0, got -1"),
        (lambda: RayBackend(address=6379), "address must be a string or None, got 6379"),
    ):
        with pytest.raises(ConfigError, match=said):
            call()
    assert (tmp_path / "runs" / "circle-3__sac__s0" / "config.json").stat().st_mtime_ns == kept


def test_a_sweep_whose_backend_lost_a_run_is_not_ok(tmp_path):
    """Every planned run must be done or skipped: a backend that returns no outcome for one (a
    lost remote worker) fails the sweep."""

    class LosesEverything:
        def run(self, jobs, monitor):
            return []

    spec = SweepSpec(
        tasks=["circle-3"], methods=["sac"], seeds=[0], interactions=2, agent_overrides=FAST
    )
    report = run_sweep(
        spec, tmp_path / "s", LosesEverything(), progress=False, tensorboard_scalars=False
    )
    assert report.failed == {} and report.skipped == []
    assert not report.ok


class _Counting:
    """A backend wrapper that is also its monitor: it counts the runs under way as it hears of
    them, and passes every event on to the sweep's own monitor."""

    def __init__(self, backend):
        self.backend, self.running, self.most = backend, 0, 0

    def run(self, jobs, monitor):
        self.monitor = monitor
        return self.backend.run(jobs, self)

    def started(self, job):
        self.running += 1
        self.most = max(self.most, self.running)
        self.monitor.started(job)

    def finished(self, outcome):
        self.running -= 1
        self.monitor.finished(outcome)

    def retrying(self, job, reason):
        self.running -= 1
        self.monitor.retrying(job, reason)

    def tick(self):
        self.monitor.tick()


def test_one_worker_trains_one_run_at_a_time(tmp_path):
    """The local backend never runs more workers at once than it is given."""
    spec = SweepSpec(
        tasks=["circle-3"],
        methods=["sac"],
        seeds=[0, 1],
        interactions=2,
        agent_overrides=FAST,
    )
    backend = _Counting(LocalBackend(workers=1))
    report = run_sweep(spec, tmp_path / "s", backend, progress=False, tensorboard_scalars=False)
    assert report.ok and len(report.outcomes) == 2
    assert backend.most == 1


def test_a_run_whose_metrics_file_is_still_empty_has_logged_nothing(tmp_path):
    """A run just created (its metrics.csv not yet written) showed -1 interactions."""
    run = tmp_path / "r0"
    run.mkdir()
    (run / "metrics.csv").write_bytes(b"")
    assert logged_interactions(run) == 0
    jobs = [Job("r0", {}, str(run))]
    display = SweepProgress(jobs, {"r0": 10}, already_done=0, console=Console(file=io.StringIO()))
    assert display._completed() == 0


def test_resume_with_the_sweeps_own_budget_is_accepted(tmp_path, capsys):
    """A script that always passes --interactions to a resume was refused as shortening it."""
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--out", str(out), *FAST_ARGS]
    assert main([*args, "--interactions", "1", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["sweep", "--resume", str(out), "--interactions", "1", "--dry-run"]) == 0
    assert "would shorten" not in capsys.readouterr().err


def test_a_run_whose_runs_folder_is_yet_to_be_made_is_in_no_sweep(tmp_path):
    """``--out results/runs/first`` in a folder where nothing is yet: a new run, not a sweep's
    (``runs`` does not exist, so nothing in it can be listed)."""
    from sili_robots.sweep.state import check_not_in_a_sweep

    check_not_in_a_sweep(tmp_path / "runs" / "first", "--out")
    assert not (tmp_path / "runs").exists()


def test_starting_the_workers_leaves_the_callers_thread_settings(monkeypatch):
    """The forkserver starts under one-thread settings (each worker trains on one core); a
    script that runs a sweep and then trains in-process must keep its own."""
    from sili_robots.sweep.worker import THREAD_ENV

    unset, own = THREAD_ENV[0], THREAD_ENV[1]
    monkeypatch.delenv(unset, raising=False)
    monkeypatch.setenv(own, "3")
    backend = LocalBackend(workers=1, start_method="forkserver")
    backend._ensure_forkserver()
    assert unset not in os.environ and os.environ[own] == "3"


def test_a_claim_left_by_a_killed_sweep_is_cleared_when_the_sweep_runs_again(tmp_path):
    """A sweep killed with -9 leaves its workers' claims; the next run of it clears those of
    dead processes, their runs done or not (a Ray sweep reads a claim as its run started)."""
    out = tmp_path / "sweep"
    spec = _spec(methods=["sac"], seeds=[0, 1], interactions=2)
    assert run_sweep(spec, out, LocalBackend(workers=1), progress=False).ok
    gone = subprocess.Popen(["true"])
    gone.wait()
    stale = json.dumps({"pid": gone.pid, "host": socket.gethostname()})
    runs = [out / "runs" / f"circle-3__sac__s{seed}" for seed in (0, 1)]
    for run in runs:
        (run / "worker.json").write_text(stale)
    (runs[1] / "summary.json").unlink()  # killed before its end was written: not done
    report = run_sweep(spec, out, LocalBackend(workers=1), progress=False)
    assert report.skipped == [runs[0].name] and report.ok
    assert not any((run / "worker.json").exists() for run in runs)
