"""Previews in a real headless Chromium (software WebGL): the picture shows the scene.

Chromium is required here (CI installs Debian's ``chromium``); without it these tests fail
with the install hint instead of being skipped.
"""

import base64
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import meshcat
import meshcat.transformations as tf
import numpy as np
import pytest
import umsgpack
from PIL import Image

from sili_robots.errors import ConfigError
from sili_robots.preview import Browser, BrowserError, Preview, make_env_and_policy, preview
from sili_robots.preview.build import populate
from sili_robots.preview.html import SceneRecorder
from sili_robots.preview.render import render_html
from sili_robots.tasks.registry import TASKS

# every registered task: a new task without a preview scene fails here
ALL_TASKS = sorted(TASKS)
WHAT_IS_SEEN = {
    "circle": {"ego", "opponent", "circle"},
    "speaker-listener": {"listener", "speaker", "true goal", "message label"},
    "sawyer-reach": {"robot robot0_right_hand", "opponent's goal", "height plane edge"},
    "driving": {"ego", "opponent", "road", "hazard"},
}


@pytest.fixture(scope="module")
def browser():
    with Browser() as b:
        yield b


_CACHE: dict = {}


def _commands(html: str) -> list[dict]:
    blob = re.search(r"var commands = (\[.*?\]);", html, re.S).group(1)
    return [umsgpack.unpackb(base64.b64decode(c)) for c in json.loads(blob)]


def _record(task, interactions=2, policy="scripted", seed=0):
    """A recorded preview, made once per test module run (Sawyer takes seconds)."""
    key = (task, interactions, policy, seed)
    if key not in _CACHE:
        name, env, pol, label = make_env_and_policy(task, policy)
        try:
            _CACHE[key] = Preview.record(env, pol, interactions, seed, name, label)
        finally:
            env.close()
    return _CACHE[key]


def _interactions(task):
    return 1 if task == "sawyer-reach" else 2


@pytest.mark.parametrize("task", ALL_TASKS)
def test_picture_shows_the_scene(task, browser, tmp_path):
    prev = _record(task, _interactions(task), "random" if task == "circle-8" else "scripted")
    html = prev.write_html(tmp_path / "p.html")
    shot = prev.render(html, browser=browser)
    assert shot.problems() == []
    seen = {r.marker.name for r in shot.markers}
    assert WHAT_IS_SEEN[task.split("-")[0] if task.startswith("circle") else task] <= seen
    # the page worked offline: only the file itself and inline data were requested
    assert shot.page.requests and all(u.startswith(("file:", "data:")) for u in shot.page.requests)
    assert Image.open(io.BytesIO(shot.png)).size == (640, 480)


def test_timeline_moves_the_ego_and_the_caption(browser, tmp_path):
    prev = _record("circle-3")
    html = prev.write_html(tmp_path / "p.html")
    caption = "document.getElementById('preview-caption').textContent"
    early = prev.render(html, frame=3, browser=browser, evaluate=caption)
    late = prev.render(html, browser=browser, evaluate=caption)
    for shot in (early, late):
        assert shot.problems() == []
    assert early.page.value == prev.scene.caption(prev.recording, 3)
    assert late.page.value.startswith("interaction 2/2, step 50/50")
    (e0,) = [r.pixel for r in early.markers if r.marker.name == "ego"]
    (e1,) = [r.pixel for r in late.markers if r.marker.name == "ego"]
    assert abs(e0[0] - e1[0]) + abs(e0[1] - e1[1]) > 40  # the ball really moved on screen


def test_driving_timeline_follows_the_cars(browser, tmp_path):
    prev = _record("driving", interactions=1)
    html = prev.write_html(tmp_path / "d.html")
    start = prev.render(html, frame=1, browser=browser)  # the red line is just ahead
    assert start.problems() == []
    assert "red line" in {r.marker.name for r in start.markers}
    shot = prev.render(html, browser=browser)
    assert shot.problems() == []
    ego = prev.recording.frames
    assert ego[prev.frame()]["ego"][0] - ego[1]["ego"][0] > 50  # 100 m further down the road


@pytest.mark.parametrize(
    ("task", "seed", "hidden_by"),
    [("driving", 11, "COLLISION"), ("sawyer-reach", 3, "opponent's goal 2")],
)
def test_a_body_hidden_behind_another_passes_the_check(task, seed, hidden_by, browser, tmp_path):
    """Cars that collided stand one in front of the other; the arm covers a goal. Both are
    drawn where they belong, so the picture is right (these games used to fail the check)."""
    prev = _record(task, 1, "random", seed)
    html = prev.write_html(tmp_path / "p.html")
    caption = "document.getElementById('preview-caption').textContent"
    shot = prev.render(html, browser=browser, evaluate=caption)
    assert hidden_by in shot.page.value  # still the game that shows it
    assert shot.problems() == []
    plain = [(replace(m, behind=()), p) for m, p in prev.markers(shot.frame)]
    again = render_html(html, shot.frame, plain, browser=browser)
    assert any(" not seen at pixel" in p for p in again.problems())  # without looking behind


@pytest.mark.parametrize("corner", [(-1.0, -1.0), (1.0, 1.0)])
def test_the_circle_camera_sees_the_whole_arena(corner, browser, tmp_path):
    """An agent may run to the arena's walls; the ego is looked for wherever it goes."""
    name, env, _, label = make_env_and_policy("circle-3")
    try:
        prev = Preview.record(env, lambda _env, _obs: np.array(corner), 1, 0, name, label)
    finally:
        env.close()
    ego = prev.recording.frames[-1]["ego"]
    assert np.all(np.abs(ego) > 1.9)  # in the corner
    html = prev.write_html(tmp_path / "p.html")
    shot = prev.render(html, browser=browser)
    assert shot.problems() == []
    (seen,) = [r for r in shot.markers if r.marker.name == "ego"]
    assert seen.in_view and seen.ok


def test_a_point_behind_the_camera_is_out_of_the_picture(browser, tmp_path):
    """Projected as is, a point straight behind the camera lands mid-picture (mirrored)."""
    from sili_robots.preview.build import world_point
    from sili_robots.preview.scenes.base import Marker

    prev = _record("circle-3")
    html = prev.write_html(tmp_path / "p.html")
    frame = prev.frame()
    cam = prev.scene.camera(prev.recording)
    behind = 2 * np.asarray(cam.position) - np.asarray(cam.target)
    marker = Marker("behind", tuple(behind), 0xD62728, 0.1)
    point = world_point(prev.scene, prev.recording, marker.position, frame)
    (result,) = render_html(html, frame, [(marker, point)], browser=browser).markers
    assert result.pixel == (-1, -1) and not result.in_view and not result.ok


def _variant(prev, tmp_path, draw=True, shift=None, path=""):
    """The same preview, re-drawn empty or with the node at ``path`` displaced (its markers
    stay where they were)."""
    scene = prev.scene
    if not draw:
        scene = type("Empty", (type(scene),), {"draw": lambda self, vis, rec, anim: None})()
    recorder = SceneRecorder()
    vis = meshcat.Visualizer(window=recorder)
    populate(vis, scene, prev.recording)
    if shift is not None:
        (vis[path] if path else vis).set_transform(tf.translation_matrix(shift))
    broken = Preview(prev.scene, prev.recording, recorder)
    return broken, broken.write_html(tmp_path / "variant.html")


def test_empty_scene_fails_the_same_check(browser, tmp_path):
    prev = _record("circle-3")
    broken, html = _variant(prev, tmp_path, draw=False)
    found = broken.render(html, browser=browser).problems()
    assert any("blank" in p for p in found)
    assert any(p.startswith("ego not seen") for p in found)
    assert any(p.startswith("opponent not seen") for p in found)


@pytest.mark.parametrize(
    ("task", "path", "shift", "missing"),
    [
        ("speaker-listener", "", [0.45, 0.3, 0.0], ["listener", "speaker"]),
        ("driving", "vehicles", [0.0, 9.0, 0.0], ["ego", "opponent"]),
    ],
)
def test_misplaced_scene_fails_the_same_check(task, path, shift, missing, browser, tmp_path):
    prev = _record(task)
    broken, html = _variant(prev, tmp_path, shift=shift, path=path)
    found = broken.render(html, browser=browser).problems()
    assert not any("blank" in p for p in found)  # something is drawn, just not where it belongs
    for name in missing:
        assert any(p.startswith(f"{name} not seen") for p in found), found


def test_broken_page_fails_the_same_check(browser, tmp_path):
    prev = _record("circle-3")
    html = prev.write_html(tmp_path / "p.html")
    text = html.read_text()
    marker = "var commands = ["
    html.write_text(text.replace(marker, marker + '"not base64!", ', 1))
    with pytest.raises(BrowserError, match="page failed before it was ready"):
        prev.render(html, browser=browser)


def test_cli_png_replaces_a_previews_picture_and_no_other(tmp_path):
    def cli_png(png: Path) -> subprocess.CompletedProcess:
        args = [
            "preview",
            "speaker-listener",
            "--interactions",
            "2",
            "--out",
            str(tmp_path / "s.html"),
        ]
        return subprocess.run(
            [sys.executable, "-m", "sili_robots.cli", *args, "--png", str(png)],
            capture_output=True,
            text=True,
            timeout=180,
        )

    for _ in range(2):  # the second replaces the first's picture
        out = cli_png(tmp_path / "s.png")
        assert out.returncode == 0, out.stderr
        assert "picture check: ok" in out.stdout
        assert Image.open(tmp_path / "s.png").size == (640, 480)
    mine = tmp_path / "mine.png"
    Image.open(tmp_path / "s.png").save(mine)  # a picture of the user's: no preview's mark
    out = cli_png(mine)
    assert out.returncode == 2 and f"--png {mine} exists and is not a preview" in out.stderr
    (tmp_path / "notes.html").write_text("<html>mine</html>")
    with pytest.raises(ConfigError, match=r"out .*notes\.html exists and is not a preview"):
        preview("circle-3", out=tmp_path / "notes.html")  # the Python API keeps it too
    assert (tmp_path / "notes.html").read_text() == "<html>mine</html>"


def _alive_with(text):
    """Live (not zombie) processes whose command line mentions ``text``."""
    out = []
    for d in Path("/proc").glob("[0-9]*"):
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if text in cmd and state not in "ZX":
            out.append(int(d.name))
    return out


def test_a_browser_that_fails_to_start_is_reported_with_what_it_wrote(tmp_path):
    fake = tmp_path / "chromium"  # a browser that cannot start, as one missing a library
    fake.write_text("#!/bin/sh\necho 'error while loading shared libraries: libnss3.so' >&2\n"
                    "exit 127\n")  # fmt: skip
    fake.chmod(0o755)
    said = rf"(exited|closed).* \({re.escape(str(fake))}\); it said: error while loading .*nss3"
    with pytest.raises(BrowserError, match=said):  # named: SILI_CHROMIUM may name another
        Browser(executable=str(fake), timeout=20).start()


def test_a_browser_that_never_answers_is_named_and_killed_with_its_children(tmp_path):
    """SILI_CHROMIUM naming some other program that hangs: named, and every process it
    started (here its `sleep`, as Chromium's helpers) is killed with it."""
    fake = tmp_path / "not-chromium"
    fake.write_text("#!/bin/sh\nsleep 31.4159\ntrue\n")  # a child, not exec'd in its place
    fake.chmod(0o755)
    with pytest.raises(
        BrowserError, match=rf"timed out waiting for Chromium \({re.escape(str(fake))}"
    ):
        Browser(executable=str(fake), timeout=1).start()
    time.sleep(0.5)
    left = _alive_with("sleep 31.4159")
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert left == []


def test_a_browser_stopped_by_an_address_space_limit_is_reported_with_the_limit():
    """Chromium reserves far more virtual memory than it uses: under ``ulimit -v`` it stops
    at start saying only something cryptic, so the error names the limit."""
    script = (
        "import resource; from sili_robots.preview import Browser\n"
        "resource.setrlimit(resource.RLIMIT_AS, (2**31, resource.RLIM_INFINITY))\n"
        "try:\n    Browser(timeout=20).start()\nexcept Exception as err:\n    print(err)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
    ).stdout
    assert "address space is limited to 2.0 GiB, `ulimit -v`" in out, out


def test_browser_processes_end_with_close():
    b = Browser().start()
    profile = b._profile
    assert len(_alive_with(profile)) >= 2  # the browser and its helpers
    b.close()
    assert _alive_with(profile) == []
    assert not os.path.exists(profile)


def test_chromium_writes_nothing_in_the_home_folder(monkeypatch, tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    for name in ("XDG_CONFIG_HOME", "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    prev = _record("circle-3")
    html = prev.write_html(tmp_path / "p.html")
    with Browser() as b:
        assert prev.render(html, browser=b).problems() == []
    assert sorted(home.rglob("*")) == []


def test_chromium_leaves_nothing_in_the_temporary_folder(monkeypatch):
    """A headless Chromium leaves its process-singleton folder (org.chromium.Chromium.*) in
    the temporary directory; one per preview piled up in /tmp."""
    import tempfile

    tmp = tempfile.mkdtemp(prefix="s", dir="/tmp")  # short: see the next test
    try:
        monkeypatch.setenv("TMPDIR", tmp)
        monkeypatch.setattr(tempfile, "tempdir", tmp)  # the profile's folder, too
        with Browser() as b:
            assert os.readlink(os.path.join(b._profile, "SingletonSocket")).startswith(tmp)
        assert os.listdir(tmp) == []
    finally:
        shutil.rmtree(tmp)


def test_chromium_starts_under_a_temporary_folder_too_long_for_its_socket(monkeypatch, tmp_path):
    """Chromium's singleton socket lives in TMPDIR and it refuses to start when the socket's
    path is over 107 bytes: a preview under a long TMPDIR (a cluster's job folder) failed."""
    long = tmp_path / ("x" * 60)
    long.mkdir()
    monkeypatch.setenv("TMPDIR", str(long))
    with Browser() as b:
        assert b.call("Browser.getVersion")["product"]
    assert list(long.iterdir()) == []


def test_sawyer_is_drawn_from_the_models_own_geoms_and_joint_positions():
    from sili_robots.preview import mujoco_geoms

    prev = _record("sili/SawyerReach-v0", 1)  # starts 0.17 m above the goals
    model = prev.recording.static["model"]
    cmds = _commands(prev.html())
    meshes = [c for c in cmds if c["type"] == "set_object" and "/robot/" in c["path"]]
    n_mesh_geoms = sum(
        model.geom_type[i] == 7
        and model.body(model.geom_bodyid[i]).name.startswith(
            ("robot0_", "gripper0_", "fixed_mount0_")
        )
        for i in mujoco_geoms.visual_geom_ids(model)
    )
    assert n_mesh_geoms > 40 and len(meshes) >= n_mesh_geoms
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    clip = {a["path"]: a["clip"] for a in anim["animations"]}["/meshcat/robot/robot0_right_l6"]
    (track,) = [t for t in clip["tracks"] if t["name"] == ".position"]
    keys = {k["time"]: k["value"] for k in track["keys"]}
    poses = mujoco_geoms.body_poses(model, prev.recording.series("qpos"))
    hand = model.body("robot0_right_l6").id
    for frame in (0, 20, 50):
        assert keys[frame] == pytest.approx(poses[frame, hand, :3, 3].tolist(), abs=1e-9)
    # the hand really moved: it went down to a goal on the table
    assert poses[:, hand, 2, 3].min() < poses[0, hand, 2, 3] - 0.1


def test_driving_cars_follow_sumo_positions_step_by_step():
    prev = _record("driving")
    cmds = _commands(prev.html())
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    clip = {a["path"]: a["clip"] for a in anim["animations"]}["/meshcat/vehicles/opponent"]
    (track,) = [t for t in clip["tracks"] if t["name"] == ".position"]
    keys = {round(k["time"], 6): k["value"][:2] for k in track["keys"]}
    frames = prev.recording.frames
    sub = frames[5]["sub_opponent"]  # the ten SUMO steps of decision step 5
    assert len(sub) == 10
    for k, p in enumerate(sub):
        assert keys[round(4 + (k + 1) / 10, 6)] == pytest.approx(p.tolist(), abs=1e-9)
    assert keys[0.0] == pytest.approx(frames[0]["opponent"].tolist(), abs=1e-9)


@pytest.mark.slow
def test_trained_agent_preview_from_a_checkpoint(tmp_path):
    """A real (tiny) training run, then its agent previewed through policy_from_run."""

    def sili(*args):
        return subprocess.run(
            [sys.executable, "-m", "sili_robots.cli", *args],
            capture_output=True,
            text=True,
            timeout=600,
        )

    run = tmp_path / "run"
    out = sili(
        "train", "--task", "circle-3", "--interactions", "3", "--out", str(run), "--no-progress"
    )
    assert out.returncode == 0, out.stderr
    png = tmp_path / "agent.png"
    out = sili(
        "preview",
        "circle-3",
        "--checkpoint",
        str(run),
        "--interactions",
        "2",
        "--out",
        str(tmp_path / "agent.html"),
        "--png",
        str(png),
    )
    assert out.returncode == 0, out.stderr
    assert "policy=trained SILI, seed 0 (run)" in out.stdout and "picture check: ok" in out.stdout
    assert "frames=102" in out.stdout  # interactions counted from the preview's start
    out = sili("preview", "speaker-listener", "--checkpoint", str(run))
    assert out.returncode == 2 and "was trained on 'circle-3', not 'speaker-listener'" in out.stderr


def test_a_console_error_of_the_page_is_reported(browser, tmp_path):
    """A page that logs console.error (meshcat reports some failures so) shows up in errors;
    a warning does not."""
    page = tmp_path / "p.html"
    page.write_text(
        "<html><body><script>console.error('scene', 'broken'); console.warn('just a warning');"
        "</script></body></html>"
    )
    assert browser.render(page).errors == ["scene broken"]


def test_a_png_without_a_page_names_no_page_and_leaves_no_temporary_file(monkeypatch, tmp_path):
    """preview(out=None, png=...) renders through a temporary page it removes, and does not
    hand back that removed page's name as result.html."""
    import tempfile

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    result = preview("circle-3", interactions=1, out=None, png=tmp_path / "p.png")
    assert result.png == tmp_path / "p.png" and result.rendered.problems() == []
    assert result.html is None
    assert [p.name for p in scratch.iterdir() if p.suffix == ".html"] == []


def test_a_picture_that_fails_its_checks_exits_1(monkeypatch, tmp_path):
    """`sili preview --png` whose picture shows nothing says so and exits 1, not 0."""
    from cli_helpers import sili

    from sili_robots.preview.scenes.circle import CircleScene

    monkeypatch.setattr(CircleScene, "draw", lambda self, vis, rec, anim: None)  # empty scene
    res = sili("preview", "circle-3", "--interactions", "1", "--out", tmp_path / "p.html",
               "--png", tmp_path / "p.png")  # fmt: skip
    assert "the picture failed its checks:" in res.stderr and "ego not seen" in res.stderr
    assert res.returncode == 1


def test_a_picture_is_rendered_and_checked_at_the_size_asked_for(tmp_path, capsys):
    """A figure for a paper needs more than 640 x 480; the smallest size allowed still leaves
    Speaker-Listener's scene (the longest caption) in view."""
    from sili_robots.cli import main

    big = preview("circle-3", interactions=1, out=None, png=tmp_path / "big.png", size=(1280, 720))
    assert Image.open(big.png).size == (1280, 720) and not big.rendered.problems()
    small = tmp_path / "small.png"
    args = ["preview", "speaker-listener", "--interactions", "1", "--out", str(tmp_path / "s.html")]
    assert main([*args, "--png", str(small), "--size", "480x360"]) == 0
    assert "picture check: ok" in capsys.readouterr().out
    assert Image.open(small).size == (480, 360)
