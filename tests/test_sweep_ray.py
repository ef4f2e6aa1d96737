"""``sili sweep --backend ray`` against a local Ray instance started by the test: the same runs
as the local backend, a failing run isolated, a killed worker retried from its checkpoint."""

import json
import os
import signal
import socket
import subprocess
import sys

import pandas as pd
import pytest
import torch
from fast_settings import FAST_AGENT as FAST
from process_helpers import killing_its_worker_once, metrics_rows, signal_when

from sili_robots.runs import RunConfig
from sili_robots.sweep import RayBackend, SweepSpec, expand, run_sweep
from sili_robots.training import train

ray = pytest.importorskip("ray")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def ray_cluster():
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ctx = ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ctx.address_info["gcs_address"]
    ray.shutdown()


def _spec(**kw):
    base = {
        "tasks": ["circle-3"],
        "methods": ["sili", "sac"],
        "seeds": [0, 1],
        "interactions": 6,
        "agent_overrides": FAST,
        "checkpoint_every": 3,
    }
    return SweepSpec(**{**base, **kw})


def _strip(df):
    return df.drop(columns="wall_time").reset_index(drop=True)


def test_ray_sweep_runs_each_run_in_a_fresh_worker_and_isolates_a_failure(ray_cluster, tmp_path):
    bad = _spec(tasks=["sawyer-reach"], methods=["sac"], seeds=[0], controllers=["bogus"])
    good = _spec(seeds=[1])  # SILI and SAC
    report = run_sweep([good, bad], tmp_path, RayBackend(), progress=False)
    assert ray.is_initialized()  # the test's instance is used, not shut down
    assert report.failed == {
        "sawyer-reach-bogus__sac__s0": "ConfigError: unknown controller 'bogus'; "
        "allowed: mink, osc, joint_velocity"
    }
    done = [o for o in report.outcomes.values() if o.status == "done"]
    assert len(done) == 2
    assert len({o.pid for o in report.outcomes.values()}) == 3  # max_calls=1: a process each
    assert os.getpid() not in {o.pid for o in done}
    table = pd.read_csv(tmp_path / "results.csv")
    assert len(table) == 2 * 6 and set(table["run"]) == {o.name for o in done}
    # the same run as the local training loop makes
    cfg = {r.name: r.config for r in expand(good)}["circle-3__sili-bschedule__s1"]
    train(cfg, tmp_path / "ref", progress=False)
    ref = pd.read_csv(tmp_path / "ref" / "metrics.csv")
    got = pd.read_csv(tmp_path / "runs" / "circle-3__sili-bschedule__s1" / "metrics.csv")
    pd.testing.assert_frame_equal(_strip(ref), _strip(got))
    runs = pd.read_csv(tmp_path / "runs.csv").set_index("run")
    assert runs.loc["sawyer-reach-bogus__sac__s0", "status"] == "failed"


def test_cli_joins_a_running_ray_cluster_by_address(ray_cluster, tmp_path):
    out = tmp_path / "sweep"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "sili_robots.cli",
            "sweep",
            "--backend",
            "ray",
            "--ray-address",
            ray_cluster,
            "--tasks",
            "circle-3",
            "--methods",
            "sac",
            "--seeds",
            "0-1",
            "--interactions",
            "5",
            "--out",
            str(out),
            "--no-progress",
            *[x for k, v in FAST.items() for x in ("--set", f"{k}={v}")],
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert (report["runs"], report["done"], report["failed"]) == (2, 2, {})
    assert "done circle-3__sac__s1" in res.stderr
    assert ray.is_initialized() and ray.cluster_resources().get("CPU") == 2  # still up


def test_ray_retries_a_killed_worker_from_its_checkpoint(ray_cluster, tmp_path):
    spec = _spec(methods=["sili"], seeds=[0], interactions=40, checkpoint_every=5)
    run_dir = tmp_path / "runs" / "circle-3__sili-bschedule__s0"
    with killing_its_worker_once(run_dir) as killed:
        report = run_sweep(spec, tmp_path, RayBackend(retries=1), progress=False)
    (outcome,) = report.outcomes.values()
    assert outcome.status == "done" and outcome.resumed and outcome.pid != killed[0]
    cfg = RunConfig.from_dict(json.loads((run_dir / "config.json").read_text())["run"])
    train(cfg, tmp_path / "ref", progress=False)
    pd.testing.assert_frame_equal(
        _strip(pd.read_csv(tmp_path / "ref" / "metrics.csv")),
        _strip(pd.read_csv(run_dir / "metrics.csv")),
    )


def test_a_stopped_ray_sweep_checkpoints_the_interaction_each_run_is_in(ray_cluster, tmp_path):
    """SIGTERM (or Ctrl-C) stops a Ray sweep as it stops a local one: each running task finishes
    and checkpoints its interaction, so resuming loses nothing."""
    out = tmp_path / "sweep"
    args = ["sweep", "--backend", "ray", "--ray-address", ray_cluster, "--tasks", "circle-3"]
    args += ["--methods", "sac", "--seeds", "0", "--interactions", "5000", "--out", str(out)]
    args += ["--no-progress", *[x for k, v in FAST.items() for x in ("--set", f"{k}={v}")]]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", *args], stderr=subprocess.PIPE, text=True
    )
    run_dir = out / "runs" / "circle-3__sac__s0"
    stderr = signal_when(proc, lambda: metrics_rows(run_dir / "metrics.csv") >= 5)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "1 stopped midway, resumable" in stderr
    checkpoint = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    assert (
        checkpoint["interaction"] == metrics_rows(run_dir / "metrics.csv") >= 5
    )  # logged and saved, nothing lost
    assert not (run_dir / "worker.json").exists()


def _children_named(parent: int, name: str) -> list[int]:
    """Processes whose parent is ``parent`` and whose command is ``name``."""
    out = []
    for d in os.scandir("/proc"):
        if d.name.isdigit():
            try:
                with open(f"/proc/{d.name}/stat") as f:
                    comm, rest = f.read().rsplit(")", 1)
            except OSError:
                continue
            if comm.endswith(f"({name}") and int(rest.split()[1]) == parent:
                out.append(int(d.name))
    return out


def test_sigterm_while_ray_starts_stops_the_sweep_as_a_sigterm_does(tmp_path):
    """``ray.init`` puts in its own SIGTERM handler (exit 15, no report) while it starts the
    local instance; a SIGTERM then still stops the sweep as the command says (128 + 15)."""
    args = ["sweep", "--backend", "ray", "--tasks", "circle-3", "--methods", "sac"]
    args += ["--interactions", "3", "--out", str(tmp_path / "s"), "--no-progress"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", *args], stderr=subprocess.PIPE, text=True
    )
    # Ray's GCS server is the first process ray.init starts; it goes on starting the rest
    stderr = signal_when(proc, lambda: bool(_children_named(proc.pid, "gcs_server")))
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "sili sweep: stopped by SIGTERM" in stderr and "Traceback" not in stderr


def test_an_address_where_no_cluster_listens_is_refused_before_anything_is_written(tmp_path):
    args = ["sweep", "--backend", "ray", "--ray-address", "127.0.0.1:1", "--tasks", "circle-3"]
    args += ["--methods", "sac", "--interactions", "3", "--out", str(tmp_path / "s")]
    out = subprocess.run(
        [sys.executable, "-m", "sili_robots.cli", *args], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 2, out.stderr
    assert "cannot connect to Ray at '127.0.0.1:1': Connection refused" in out.stderr
    assert not (tmp_path / "s").exists()


def test_a_cluster_is_reached_whatever_proxy_the_environment_names(ray_cluster, monkeypatch):
    """Ray's clients connect straight to the cluster; the handshake went through http_proxy
    (here a port where nothing listens) and refused a running head."""
    from sili_robots.sweep.ray_backend import check_reachable

    for variable in ("http_proxy", "https_proxy", "grpc_proxy"):
        monkeypatch.setenv(variable, "http://127.0.0.1:1")
    check_reachable(ray_cluster)


def test_an_address_where_another_service_listens_is_refused_not_retried(tmp_path):
    """Before, the TCP port answering was enough: ``ray.init`` then retried a web server (or any
    other service) for minutes, printing Ray's log lines, instead of exiting 2."""
    with socket.create_server(("127.0.0.1", 0)) as other:  # listens, never speaks gRPC
        address = f"127.0.0.1:{other.getsockname()[1]}"
        args = ["sweep", "--backend", "ray", "--ray-address", address, "--tasks", "circle-3"]
        args += ["--methods", "sac", "--interactions", "3", "--out", str(tmp_path / "s")]
        cmd = [sys.executable, "-m", "sili_robots.cli", *args]
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stderr
    assert (
        f"cannot connect to Ray at '{address}': something listens there but does not answer "
        "as Ray does (gRPC) in 5 s" in out.stderr
    )
    assert "Traceback" not in out.stderr and not (tmp_path / "s").exists()


def test_a_sweep_without_an_address_starts_its_own_ray_whatever_ray_address_says(tmp_path):
    """ray.init reads RAY_ADDRESS when given no address: the sweep failed with "num_cpus ...
    must not be provided" (a cluster there) or could not connect (none there)."""
    args = ["sweep", "--backend", "ray", "--tasks", "circle-3", "--methods", "sac"]
    args += ["--interactions", "1", "--out", str(tmp_path / "s"), "--no-progress"]
    args += [x for k, v in FAST.items() for x in ("--set", f"{k}={v}")]
    out = subprocess.run(
        [sys.executable, "-m", "sili_robots.cli", *args],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "RAY_ADDRESS": "127.0.0.1:1"},
    )
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["failed"] == {}
    assert "sweep: 1 done, 0 failed" in out.stderr


def test_ray_runs_at_most_workers_runs_at_once(ray_cluster, tmp_path):
    """RayBackend(workers=1) (what `--workers 1` builds) on a cluster with room for two: one
    run trains at a time."""
    import threading
    import time

    spec = _spec(methods=["sac"], interactions=30, checkpoint_every=10)
    most, over = [0], threading.Event()

    def watch() -> None:  # how many runs hold a worker's claim (worker.json) at one moment
        while not over.is_set():
            most[0] = max(most[0], len(list((tmp_path / "runs").glob("*/worker.json"))))
            time.sleep(0.01)

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        report = run_sweep(spec, tmp_path, RayBackend(workers=1), progress=False)
    finally:
        over.set()
        watcher.join()
    assert report.failed == {} and len(report.outcomes) == 2
    assert most[0] == 1
