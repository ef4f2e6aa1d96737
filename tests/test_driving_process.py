"""Driving across processes: libsumo's one-simulation-per-process rule, subprocess vector envs,
SUMO failures as Python errors, SUMO found from the wheel. Each scenario that could leave a
simulation behind runs in its own Python process so this test process stays clean."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import sili_robots  # noqa: F401  (registers the tasks)


def _python(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


def test_second_live_simulation_in_a_process_is_refused_until_close():
    out = _python(
        """
        import gc
        import numpy as np
        from sili_robots.errors import ConfigError
        from sili_robots.tasks.driving import DrivingEnv

        a = DrivingEnv()
        a.reset(seed=0)
        b = DrivingEnv()  # constructing is fine: SUMO starts at the first reset
        try:
            b.reset(seed=0)
        except ConfigError as exc:
            assert isinstance(exc, RuntimeError)
            print("REFUSED:", exc)
        try:
            b.step(np.array([0.5], np.float32))
        except RuntimeError as exc:
            print("NOT STARTED:", exc)  # the refused reset began nothing
        a.step(np.array([0.5], np.float32))  # the first simulation is untouched
        a.close()
        print("FIRST:", b.reset()[1]["interaction"])  # no interaction was played before
        b.reset(seed=0)  # the slot is free again
        b.step(np.array([0.5], np.float32))
        del b
        gc.collect()  # a dropped environment releases its simulation too
        c = DrivingEnv()
        c.reset(seed=0)
        c.close()
        try:
            c.reset()
        except RuntimeError as exc:
            print("CLOSED:", exc)
        print("OK")
        """
    )
    assert out.returncode == 0, out.stderr
    assert "REFUSED: libsumo runs one SUMO simulation per process" in out.stdout
    assert "call close() on that environment first" in out.stdout
    assert "CLOSED: this Driving environment was closed" in out.stdout
    assert "NOT STARTED: call reset() before step()" in out.stdout
    assert "FIRST: 0" in out.stdout
    assert out.stdout.strip().endswith("OK")


def test_async_vector_env_of_two_steps_across_interactions():
    import libsumo

    envs = gym.make_vec("sili/Driving-v0", num_envs=2, vectorization_mode="async")
    try:
        obs, info = envs.reset(seed=[0, 1])
        assert obs.shape == (2, 5) and obs.dtype == np.float32
        rewards = []
        for _ in range(23):  # crosses two interaction boundaries (autoreset)
            obs, reward, _term, _trunc, info = envs.step(np.full((2, 1), 1.0, np.float32))
            rewards.append(reward)
        assert obs.shape == (2, 5)
        assert set(info["interaction"].tolist()) == {2}
        # Always merging left at once: the workers form the convention and stop colliding.
        assert np.all(np.array(rewards[11:]) == 0.0)
    finally:
        envs.close()
    assert not libsumo.isLoaded()  # the spaces came from a copy that never started SUMO


def test_a_forked_child_leaves_its_parents_simulation_alone():
    """A child of ``os.fork`` that exits normally, or closes its inherited copy, runs the
    session's clean-up: the parent's SUMO and its saved start state must outlive it."""
    out = _python(
        """
        import os, sys
        import numpy as np
        import gymnasium as gym
        import sili_robots

        for backend in ("traci", "libsumo"):
            for child_closes in (False, True):
                env = gym.make("sili/Driving-v0", backend=backend)
                env.reset(seed=0)
                env.step(np.zeros(1, np.float32))
                pid = os.fork()
                if pid == 0:
                    if child_closes:
                        env.close()
                    sys.exit(0)  # the interpreter's exit runs the session's finalizer
                os.waitpid(pid, 0)
                env.step(np.zeros(1, np.float32))  # the SUMO server still answers
                env.reset()  # from the saved start state, still on disk
                env.close()
                print("OK", backend, child_closes)
        """
    )
    assert out.returncode == 0, out.stderr
    for backend in ("traci", "libsumo"):
        for closes in (False, True):
            assert f"OK {backend} {closes}" in out.stdout


def test_sumo_failures_become_python_errors(tmp_path: Path):
    out = _python(
        """
        import os
        from pathlib import Path
        from sili_robots.tasks.driving import DrivingEnv
        from sili_robots.tasks.sumo_scenario import ScenarioFiles
        from sili_robots.tasks.sumo_session import SumoError, SumoSession

        env = DrivingEnv()
        env.reset(seed=0)
        os.remove(env._state_file)
        try:
            env.reset()
        except SumoError as exc:
            print("RESET:", exc)
        env.close()

        bad = Path(os.environ["BAD_DIR"])
        (bad / "bad.sumocfg").write_text(
            '<configuration><input><net-file value="missing.net.xml"/></input></configuration>'
        )
        files = ScenarioFiles(bad, bad / "missing.net.xml", bad / "x", bad / "bad.sumocfg")
        try:
            SumoSession(files)
        except SumoError as exc:
            print("START:", exc)
        env = DrivingEnv()  # a failed start leaves the process usable
        env.reset(seed=0)
        env.close()
        print("OK")
        """,
        env={**os.environ, "BAD_DIR": str(tmp_path)},
    )
    assert out.returncode == 0, out.stderr
    assert "RESET: SUMO failed while restoring the start state" in out.stdout
    assert "start-state.xml" in out.stdout
    assert "START: SUMO could not start (libsumo)" in out.stdout
    assert "missing.net.xml" in out.stdout
    assert out.stdout.strip().endswith("OK")


def test_sumo_comes_from_the_wheel_and_netconvert_builds_the_network(tmp_path: Path):
    env = {k: v for k, v in os.environ.items() if k not in ("SUMO_HOME", "PROJ_LIB", "PROJ_DATA")}
    env["SILI_ROBOTS_CACHE"] = str(tmp_path)
    env["PATH"] = "/usr/bin:/bin"
    out = _python(
        """
        import numpy as np
        from sili_robots.tasks.driving import DrivingEnv

        env = DrivingEnv()
        env.reset(seed=0)
        for _ in range(env.horizon):
            env.step(np.array([1.0], np.float32))
        workdir = env.session.workdir
        env.close()
        print("WORKDIR LEFT:", workdir.exists())
        """,
        env=env,
    )
    assert out.returncode == 0, out.stderr
    nets = list(tmp_path.glob("sumo/*/road.net.xml"))
    assert len(nets) == 1
    assert "by Eclipse SUMO netconvert 1.28" in nets[0].read_text()[:300]
    assert "WORKDIR LEFT: False" in out.stdout  # the per-env state file is cleaned up
    assert {p.name for p in nets[0].parent.iterdir()} == {
        "road.nod.xml",
        "road.edg.xml",
        "road.net.xml",
        "road.rou.xml",
        "road.sumocfg",
    }


def test_a_killed_process_session_folder_is_removed_by_the_next_one(tmp_path: Path):
    """SIGKILL (a sweep stopping its worker, AsyncVectorEnv.close(terminate=True)) runs no
    clean-up: the next Driving session on the machine removes that folder, not a live one's."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    start = """
        import os, signal, sys, time
        from sili_robots.tasks.driving import DrivingEnv

        env = DrivingEnv()
        env.reset(seed=0)
        print(env.session.workdir, flush=True)
        {then}
        """
    live = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(start.format(then="time.sleep(120)"))],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        live_dir = Path(live.stdout.readline().strip())
        killed = _python(start.format(then="os.kill(os.getpid(), signal.SIGKILL)"), env=env)
        assert killed.returncode == -9, killed.stderr
        killed_dir = Path(killed.stdout.strip())
        assert killed_dir.is_dir() and live_dir.is_dir()  # no clean-up ran on the kill
        assert _python(start.format(then="env.close()"), env=env).returncode == 0
        assert not killed_dir.exists()
        assert live_dir.is_dir() and (live_dir / "start-state.xml").is_file()  # still in use
    finally:
        live.kill()
        live.wait()
    assert sorted(p.name for p in tmp_path.iterdir() if "driving" in p.name) == [live_dir.name]


def test_a_second_session_keeps_the_first_ones_folder_where_locks_are_posix_locks(tmp_path):
    """On NFS flock is a POSIX lock, which the process holding it takes again: the scan must
    not take this process's own live folder for a leftover (emulated with lockf)."""
    out = _python(
        """
        import fcntl
        fcntl.flock = fcntl.lockf  # what the NFS client does
        from sili_robots.tasks.driving import DrivingEnv

        first = DrivingEnv(backend="traci")
        first.reset(seed=0)
        second = DrivingEnv(backend="traci")
        second.reset(seed=0)
        print("FIRST KEPT:", first.session.workdir.is_dir())
        first.reset(seed=1)
        first.close()
        second.close()
        print("OK")
        """,
        env={**os.environ, "TMPDIR": str(tmp_path)},
    )
    assert out.returncode == 0, out.stderr
    assert "FIRST KEPT: True" in out.stdout and out.stdout.strip().endswith("OK")


def test_a_hidden_folder_of_a_process_killed_before_its_lock_is_removed(tmp_path, monkeypatch):
    """A folder stays hidden only until it is locked: one hidden for an hour was left by a kill
    in between, one hidden for a moment may be another process's about to be locked."""
    import tempfile

    from sili_robots.tasks import sumo_session

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    old, fresh = tmp_path / ".sili-driving-old", tmp_path / ".sili-driving-fresh"
    for folder in (old, fresh):
        folder.mkdir()
        (folder / sumo_session.WORKDIR_LOCK).touch()
    hour_ago = time.time() - sumo_session.HIDDEN_LEFTOVER_AGE - 60
    os.utime(old, (hour_ago, hour_ago))
    workdir, lock = sumo_session._make_workdir()
    try:
        assert not old.exists() and fresh.is_dir()
        assert workdir.parent == tmp_path and not workdir.name.startswith(".")
    finally:
        sumo_session._shutdown("traci", None, 0, workdir, lock, os.getpid())
    assert sorted(p.name for p in tmp_path.iterdir()) == [fresh.name]


def test_a_sumo_failure_quotes_the_latest_error_sumo_logged(tmp_path):
    """SUMO's error log grows over a session: the failure at hand is its last Error: line."""
    from sili_robots.tasks.sumo_session import SumoSession

    session = SumoSession.__new__(SumoSession)  # the message reads only the session's logs
    session.workdir, session.error_log = tmp_path, tmp_path / "sumo-errors.log"
    session.error_log.write_text(
        "Error: an earlier problem, recovered\nWarning: noise\nError: the vehicle vanished\n"
    )
    message = session._sumo_message(RuntimeError("connection lost"))
    assert message == "connection lost; SUMO said: Error: the vehicle vanished"
