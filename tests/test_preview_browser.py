"""Previews in a real headless Chromium (software WebGL): the picture shows the scene.

Chromium is required here (CI installs Debian's ``chromium``); without it these tests fail
with the install hint instead of being skipped.
"""

import io
import os
import subprocess
import sys
from pathlib import Path

import meshcat
import meshcat.transformations as tf
import pytest
from PIL import Image

from sili_robots.preview import Browser, BrowserError, Preview, make_env_and_policy
from sili_robots.preview.build import populate
from sili_robots.preview.html import SceneRecorder

TASKS_2D = ["circle-3", "circle-8", "circle-continuous", "circle-unequal", "speaker-listener"]


@pytest.fixture(scope="module")
def browser():
    with Browser() as b:
        yield b


def _record(task, interactions=2, policy="scripted"):
    name, env, pol, label = make_env_and_policy(task, policy)
    try:
        return Preview.record(env, pol, interactions, 0, name, label)
    finally:
        env.close()


@pytest.mark.parametrize("task", TASKS_2D)
def test_picture_shows_the_scene(task, browser, tmp_path):
    prev = _record(task, policy="random" if task == "circle-8" else "scripted")
    html = prev.write_html(tmp_path / "p.html")
    shot = prev.render(html, browser=browser)
    assert shot.problems() == []
    seen = {r.marker.name for r in shot.markers}
    assert {"ego", "opponent", "circle"} <= seen or {"listener", "speaker", "true goal"} <= seen
    assert len(seen) >= 3
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


def _variant(prev, tmp_path, draw=True, shift=None):
    """The same preview, re-drawn empty or displaced (its markers stay where they were)."""
    scene = prev.scene
    if not draw:
        scene = type("Empty", (type(scene),), {"draw": lambda self, vis, rec, anim: None})()
    recorder = SceneRecorder()
    vis = meshcat.Visualizer(window=recorder)
    populate(vis, scene, prev.recording)
    if shift is not None:
        vis.set_transform(tf.translation_matrix(shift))
    broken = Preview(prev.scene, prev.recording, recorder)
    return broken, broken.write_html(tmp_path / "variant.html")


def test_empty_scene_fails_the_same_check(browser, tmp_path):
    prev = _record("circle-3")
    broken, html = _variant(prev, tmp_path, draw=False)
    found = broken.render(html, browser=browser).problems()
    assert any("blank" in p for p in found)
    assert any(p.startswith("ego not seen") for p in found)
    assert any(p.startswith("opponent not seen") for p in found)


def test_misplaced_scene_fails_the_same_check(browser, tmp_path):
    prev = _record("speaker-listener")
    broken, html = _variant(prev, tmp_path, shift=[0.45, 0.3, 0.0])
    found = broken.render(html, browser=browser).problems()
    assert not any("blank" in p for p in found)  # something is drawn, just not where it belongs
    assert any(p.startswith("listener not seen") for p in found)
    assert any(p.startswith("speaker not seen") for p in found)


def test_broken_page_fails_the_same_check(browser, tmp_path):
    prev = _record("circle-3")
    html = prev.write_html(tmp_path / "p.html")
    text = html.read_text()
    marker = "var commands = ["
    html.write_text(text.replace(marker, marker + '"not base64!", ', 1))
    with pytest.raises(BrowserError, match="page failed before it was ready"):
        prev.render(html, browser=browser)


def test_cli_png(tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "sili_robots.cli",
            "preview",
            "speaker-listener",
            "--interactions",
            "2",
            "--out",
            str(tmp_path / "s.html"),
            "--png",
            str(tmp_path / "s.png"),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert out.returncode == 0, out.stderr
    assert "picture check: ok" in out.stdout
    assert Image.open(tmp_path / "s.png").size == (640, 480)


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


def test_browser_processes_end_with_close():
    b = Browser().start()
    profile = b._profile
    assert len(_alive_with(profile)) >= 2  # the browser and its helpers
    b.close()
    assert _alive_with(profile) == []
    assert not os.path.exists(profile)
