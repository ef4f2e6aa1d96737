"""The live meshcat server: serves the same scene, and never outlives its parent.

meshcat 0.3.2's ``Visualizer.close()`` is broken; these tests check that no server process is
left behind on a normal exit, an error, Ctrl-C, SIGTERM, or when the parent is killed outright.
"""

import base64
import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from sili_robots.preview import Browser, LiveServer, Preview, make_env_and_policy, preview
from sili_robots.preview import api as preview_api


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in "ZX"


def _wait_dead(pid: int, timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if not _alive(pid):
            return True
        time.sleep(0.05)
    return False


def _children_running(parent: int, needle: str) -> list[int]:
    out = []
    for d in Path("/proc").glob("[0-9]*"):
        try:
            stat = (d / "stat").read_text().rsplit(")", 1)[1].split()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if int(stat[1]) == parent and needle in cmd and stat[0] not in "ZX":
            out.append(int(d.name))
    return out


def test_live_server_serves_the_same_scene_and_stops(tmp_path):
    with LiveServer() as server:
        pid = server.pid
        assert _alive(pid) and server.web_url.startswith("http://127.0.0.1:")
        name, env, pol, label = make_env_and_policy("speaker-listener")
        prev = Preview.record(env, pol, 3, 0, name, label, live=server.visualizer)
        env.close()
        # meshcat's own static_html() from the server holds exactly the file's commands
        served = set(re.findall(r'base64,([A-Za-z0-9+/=]+)"', server.visualizer.static_html()))
        assert served == {base64.b64encode(c).decode() for c in prev.recorder.commands()}
        # and a browser pointed at the server sees the scene where it belongs, in every frame
        # (meshcat's replay sent the animation before the objects: only the last frame was right)
        with Browser() as b:
            for frame in (0, 25, None):
                shot = prev.render_live(server.web_url, frame, browser=b)
                assert shot.problems() == [], frame
        assert any(u.startswith(server.web_url) for u in shot.page.requests)
    assert _wait_dead(pid)


def test_server_stops_when_building_the_preview_fails(monkeypatch, tmp_path):
    started = []
    real_start = LiveServer.start

    def spy(self):
        started.append(self)
        return real_start(self)

    def boom(*args, **kwargs):
        raise RuntimeError("simulated failure while building the scene")

    monkeypatch.setattr(LiveServer, "start", spy)
    monkeypatch.setattr(preview_api.Preview, "record", boom)
    with pytest.raises(RuntimeError, match="simulated failure"):
        preview("circle-3", out=tmp_path / "p.html", serve=True)
    (server,) = started
    assert server.proc is None  # stopped
    assert not _children_running(os.getpid(), "meshcat_child")


@pytest.mark.parametrize("seconds", [0.3, 0])  # 0: allowed ("a number >= 0"), served, stopped
def test_server_stops_after_serving_for_a_while(seconds, tmp_path):
    """In a thread given a minute: 0 read as "until Ctrl-C" would fail the test, not hang it."""
    urls, results = [], []
    serving = threading.Thread(
        target=lambda: results.append(
            preview(
                "speaker-listener",
                interactions=1,
                out=None,
                serve=True,
                serve_seconds=seconds,
                on_ready=lambda r: urls.append(r.url),
            )
        ),
        daemon=True,
    )
    serving.start()
    serving.join(timeout=60)
    assert not serving.is_alive(), f"still serving after a minute (serve_seconds={seconds})"
    (result,) = results
    assert urls == [result.url] and result.url.startswith("http://127.0.0.1:")
    assert not _children_running(os.getpid(), "meshcat_child")


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@contextlib.contextmanager
def _serving_cli(tmp_path, *extra):
    """``sili preview --serve`` read up to its URL: (the process, its meshcat server). Both
    are killed however the test ends: a failed assertion must not leave a server running."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sili_robots.cli",
            "preview",
            "circle-3",
            "--interactions",
            "1",
            "--out",
            str(tmp_path / "p.html"),
            "--serve",
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a background job (e.g. a CI runner's) inherits SIGINT ignored; a terminal's Ctrl-C
        # reaches a process whose SIGINT is at its default, so start it that way
        preexec_fn=_default_sigint,
    )
    servers: list[int] = []
    try:
        proc.before = []  # what was printed before the URL
        while not (line := proc.stdout.readline()).startswith("meshcat server: "):
            assert line, "".join(proc.before) + proc.stderr.read()
            proc.before.append(line)
        assert line.startswith("meshcat server: http://127.0.0.1:"), line
        servers = _children_running(proc.pid, "meshcat_child")
        (server,) = servers
        yield proc, server
    finally:
        proc.kill()  # nothing once it has been waited for
        proc.wait(timeout=30)
        for pid in servers:  # still the server only while alive (a pid is not reused before)
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


def _listening_addresses(pid: int) -> set[str]:
    """Local addresses (hex, as in /proc/net/tcp) of the sockets ``pid`` listens on."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    out = set()
    for table in ("tcp", "tcp6"):
        for row in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            cols = row.split()
            if cols[3] == "0A" and cols[9] in inodes:  # LISTEN
                out.add(cols[1].rsplit(":", 1)[0])
    return out


def test_cli_reports_the_files_and_the_check_before_serving_on_the_loopback(tmp_path):
    with _serving_cli(tmp_path, "--png", str(tmp_path / "p.png")) as (proc, server):
        printed = "".join(proc.before)
        assert "wrote " + str(tmp_path / "p.html") in printed
        assert "picture check: ok" in printed and (tmp_path / "p.png").is_file()
        # meshcat's live page has no title or legend: the HTML page's are printed beside it
        assert "\nscene: circle-3 · scripted stabilizing · 1 interaction" in printed
        assert "\nlegend: ego (#1f6fd1), ego's path (#" in printed and "circle (#" in printed
        # the web page and the zmq socket: 127.0.0.1 only, never every interface
        assert _listening_addresses(server) == {"0100007F"}
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        assert _wait_dead(server)


def test_a_server_started_in_a_thread_lives_until_it_is_stopped():
    started = []
    thread = threading.Thread(target=lambda: started.append(LiveServer().start()))
    thread.start()
    thread.join()
    (server,) = started
    try:
        time.sleep(1.0)  # the thread that started it has ended; the process has not
        assert _alive(server.pid)
    finally:
        server.stop()


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 128 + 15)])
def test_ctrl_c_and_sigterm_stop_the_server(sig, code, tmp_path):
    with _serving_cli(tmp_path) as (proc, server):
        proc.send_signal(sig)
        assert proc.wait(timeout=30) == code
        assert "Traceback" not in proc.stderr.read()
        assert _wait_dead(server)


def test_server_dies_with_a_killed_parent(tmp_path):
    with _serving_cli(tmp_path) as (proc, server):
        log = os.readlink(f"/proc/{server}/fd/1")
        assert log.endswith(" (deleted)")  # the server's log is gone once its URLs were read
        proc.kill()  # no cleanup code runs in the parent
        proc.wait(timeout=30)
        assert _wait_dead(server)


def test_serving_ends_with_an_error_when_the_meshcat_server_dies():
    """`--serve` does not keep waiting on a dead server: serve() raises ServerError soon after
    it stops (the OOM killer, a crash)."""
    from sili_robots.preview.server import ServerError

    with LiveServer() as server:
        threading.Timer(0.5, os.killpg, (server.pid, signal.SIGKILL)).start()  # while serving
        t0 = time.monotonic()
        with pytest.raises(ServerError, match="the meshcat server stopped unexpectedly"):
            server.serve(seconds=60.0)
        assert time.monotonic() - t0 < 30.0


def test_serve_puts_the_callers_sigterm_handler_back():
    def mine(signum, frame):  # never called
        pass

    previous = signal.signal(signal.SIGTERM, mine)
    server = LiveServer()
    server.proc = subprocess.Popen(["sleep", "30"])  # stands for the meshcat server
    try:
        server.serve(0.3)
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        server.proc.kill()
        server.proc.wait()
        signal.signal(signal.SIGTERM, previous)
