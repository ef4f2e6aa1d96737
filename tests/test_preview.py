"""Previews without a browser: what is recorded, what the HTML holds, bad input."""

import base64
import json
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import meshcat
import meshcat.geometry as g
import numpy as np
import pytest
import umsgpack

from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.policies import scripted_policy
from sili_robots.preview import Preview, find_chromium, make_env_and_policy, preview
from sili_robots.preview.check import blank_problem, marker_results
from sili_robots.preview.html import PREVIEW_MARK, SceneRecorder
from sili_robots.preview.scenes import scene_for
from sili_robots.preview.scenes.base import Marker
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task
from sili_robots.tasks.registry import TASKS


def _record(task, interactions=2, policy="scripted"):
    name, env, pol, label = make_env_and_policy(task, policy)
    try:
        return Preview.record(env, pol, interactions, 0, name, label)
    finally:
        env.close()


def test_a_page_the_disk_refuses_leaves_the_page_written_before(tmp_path):
    """The page is replaced whole: a full disk keeps the last good one (it was cut)."""
    from disk_helpers import file_size_limit

    prev = _record("circle-3", interactions=1)
    page = prev.write_html(tmp_path / "p.html")
    written = page.read_bytes()
    with pytest.raises(OSError) as refused, file_size_limit(len(written) // 2):
        prev.write_html(page)
    assert refused.value.filename == str(page) and page.read_bytes() == written
    assert sorted(tmp_path.iterdir()) == [page]


def _commands(html: str) -> list[dict]:
    blob = re.search(r"var commands = (\[.*?\]);", html, re.S).group(1)
    return [umsgpack.unpackb(base64.b64decode(c)) for c in json.loads(blob)]


def _ego_clip(cmds: list[dict]) -> tuple[dict, dict]:
    """The ego's animation clip in a page's commands, and its position track."""
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    clip = {a["path"]: a["clip"] for a in anim["animations"]}["/meshcat/ego"]
    (track,) = [t for t in clip["tracks"] if t["name"] == ".position"]
    return clip, track


def test_recording_has_every_step_of_every_interaction():
    prev = _record("circle-3", interactions=2)
    rec = prev.recording
    assert len(rec) == 2 * (rec.horizon + 1)
    assert [f["t"] for f in rec.frames[:3]] == [0, 1, 2]
    assert [f["interaction"] for f in rec.frames[:: rec.horizon + 1]] == [0, 1]
    # the same policy rolled out directly visits the same positions
    env = make_task("circle-3")
    seen = []
    run_interactions(
        env,
        scripted_policy(env, "stabilizing"),
        2,
        seed=0,
        on_step=lambda _s, _a, _r, obs, _i: seen.append(obs[:2].copy()),
    )
    env.close()
    recorded = np.array([f["ego"] for f in rec.frames if f["t"] > 0])
    np.testing.assert_allclose(recorded, np.array(seen), atol=1e-6)
    # the stabilizing policy steps out past v1's 1.1: outside by the version's rule
    assert "ended outside the circle → opponent stays" in prev.scene.caption(rec, rec.horizon)
    assert prev.scene.title(rec) == "circle-3 · scripted stabilizing · 2 interactions, H = 50"
    one = _record("circle-3", interactions=1)
    assert one.scene.title(one.recording).endswith("· 1 interaction, H = 50")


def test_html_is_self_contained_and_animates_the_recorded_rollout():
    prev = _record("circle-8", interactions=2)
    html = prev.html()
    # meshcat's viewer (three.js included) is inlined; nothing is loaded from elsewhere
    assert "MeshCat" in html and len(html) > 500_000
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", html)
    assert "fetch(" not in html.split("var viewer = new MeshCat.Viewer")[1]
    urls = set(re.findall(r"https?://[^\s\"'`)]+", html))
    assert urls <= {"http://www.w3.org/1999/xhtml"}, urls
    cmds = _commands(html)
    objects = {c["path"] for c in cmds if c["type"] == "set_object"}
    for part in ("ego", "opponent", "circle", "locations/7", "trail/dot050"):
        assert f"/meshcat/{part}" in objects
    clip, track = _ego_clip(cmds)
    keys = {k["time"]: k["value"] for k in track["keys"]}
    ego = prev.recording.series("ego")
    assert len(keys) == len(ego)
    for frame in (0, 10, 60, len(ego) - 1):
        np.testing.assert_allclose(keys[frame][:2], ego[frame], atol=1e-9)
    assert clip["fps"] == prev.scene.fps


def test_speaker_listener_caption_says_whether_the_code_is_locked():
    """The caption follows the lock: a visit locks the code, before it the code may change."""
    prev = _record("speaker-listener", interactions=1)
    rec = prev.recording
    locked = rec.series("locked")
    assert not locked[0] and locked.any()
    first_locked = int(locked.argmax())
    assert prev.scene.caption(rec, 0).endswith(", unlocked); return so far 0.00")
    assert ", locked by a visit); return so far" in prev.scene.caption(rec, first_locked)
    assert "unlocked" not in prev.scene.caption(rec, first_locked)
    assert re.search(r"\); return -?\d", prev.scene.caption(rec, rec.last))  # not "so far"


def test_any_policy_callable_is_recorded():
    env = make_task("speaker-listener")
    prev = Preview.record(env, lambda e, obs: np.array([1.0, 0.0]), 1, 0, "speaker-listener")
    env.close()
    xs = prev.recording.series("ego")[:, 0]
    np.testing.assert_allclose(xs[:5], [0.0, 0.1, 0.2, 0.3, 0.4])
    assert prev.recording.policy == ""


def test_the_live_page_s_key_colours_each_item_in_a_terminal():
    """``--serve`` prints the title and legend meshcat's live page lacks; in a terminal each
    item's swatch is drawn in its colour, elsewhere its colour is named."""
    from sili_robots.commands.preview import _key

    env = make_task("speaker-listener")
    prev = Preview.record(env, lambda e, obs: np.array([1.0, 0.0]), 1, 0, "speaker-listener")
    env.close()
    title = prev.scene.title(prev.recording)
    (colour, label), *_ = prev.scene.legend(prev.recording)
    r, g, b = colour >> 16, (colour >> 8) & 0xFF, colour & 0xFF
    assert _key(prev, colour=True).startswith(
        f"scene: {title}\nlegend: \033[38;2;{r};{g};{b}m\u25a0\033[0m {label}, "
    )
    assert _key(prev, colour=False).startswith(f"scene: {title}\nlegend: {label} (#{colour:06x}), ")


def test_serve_colours_the_key_in_a_terminal_unless_no_color_is_set(monkeypatch, capsys, tmp_path):
    import sili_robots.preview as preview_package

    monkeypatch.chdir(tmp_path)  # the page's default path: not written here, but checked

    recorded = preview("speaker-listener", interactions=1, out=None)

    def served(*_args, on_ready, **_kwargs):  # as preview(serve=True) does, without a server
        on_ready(recorded)
        return recorded

    monkeypatch.setattr(preview_package, "preview", served)
    args = ["preview", "speaker-listener", "--interactions", "1", "--serve"]
    monkeypatch.delenv("NO_COLOR", raising=False)
    for terminal, no_color, swatch in ((True, "", True), (True, "1", False), (False, "", False)):
        capsys.readouterr()
        monkeypatch.setattr(sys.stdout, "isatty", lambda t=terminal: t)
        monkeypatch.setenv("NO_COLOR", no_color)
        assert main(args) == 0
        out = capsys.readouterr().out
        assert "\nlegend: " in out and ("\033[38;2;" in out) == swatch, (terminal, no_color)


def test_every_registered_task_has_a_preview_scene():
    for name in TASKS:
        env = make_task(name)  # cheap: Driving starts SUMO only on reset
        try:
            assert scene_for(env).env_classes, name
        finally:
            env.close()


def test_scene_for_unknown_env_names_the_known_ones():
    class Other:
        unwrapped = object()

    with pytest.raises(ConfigError, match=r"no preview scene for task class 'object'.*CircleEnv"):
        scene_for(Other())


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"policy": "greedy"}, "unknown preview policy 'greedy'; allowed: scripted, random"),
        ({"interactions": 0}, "interactions must be an integer >= 1"),
        ({"interactions": 2.5}, "interactions must be an integer >= 1, got 2.5"),  # not cut to 2
        ({"interactions": "x"}, "interactions must be an integer >= 1, got 'x'"),
        ({"checkpoint": "/nonexistent/run"}, "is not a run directory"),
        ({"seed": -1}, "seed -1 is not allowed: give an integer in [0,"),
        ({"seed": 1.5}, "seed 1.5 is not an integer"),
        ({"policy": "random", "checkpoint": "/x"}, "'/x': a preview plays one of them"),
        ({"serve": "no"}, "serve must be True or False, got 'no'"),  # started a server
        ({"serve": True, "serve_seconds": "1"}, "serve_seconds must be a number >= 0"),
        ({"env_kwargs": [1]}, "env_kwargs must be a dict of names to values, got [1]"),
    ],
)
def test_bad_preview_arguments_raise_config_error(kwargs, message, tmp_path):
    with pytest.raises(ConfigError, match=re.escape(message)):
        preview("circle-3", out=tmp_path / "p.html", **kwargs)
    assert not (tmp_path / "p.html").exists()


def test_bad_frame_is_a_config_error(tmp_path):
    prev = _record("circle-3", interactions=1)
    with pytest.raises(ConfigError, match="frame 999 is outside the recording"):
        prev.render(tmp_path / "x.html", frame=999)
    last = len(prev.recording) - 1
    for frame in (1.5, 2.0, "a", float("nan"), True, np.True_):  # not cut to 1, nor int()'s error
        expected = f"frame must be an integer from 0 to {last}, got {frame!r}"
        with pytest.raises(ConfigError, match=re.escape(expected)):
            prev.frame(frame)
    assert prev.frame(np.int64(1)) == 1 and prev.frame(np.array(2)) == 2


def test_an_output_under_a_file_or_that_is_a_folder_is_refused_before_the_rollout(
    tmp_path, monkeypatch
):
    def no_rollout(*_args, **_kwargs):
        raise AssertionError("the rollout began before the output was checked")

    monkeypatch.setattr(Preview, "record", no_rollout)
    (tmp_path / "afile").write_text("mine")
    (tmp_path / "page.html").mkdir()
    for out, why in [
        (tmp_path / "afile" / "p.html", "afile is a file, so no folder can be made there"),
        (tmp_path / "afile" / "deeper" / "p.html", "afile is a file, so no folder can be made"),
        (tmp_path / "page.html", "page.html is a folder; give a file name in it"),
    ]:
        with pytest.raises(ConfigError, match=re.escape(why)):
            preview("circle-3", interactions=1, out=out)
    with pytest.raises(
        ConfigError, match=re.escape("png must be a path (a string or pathlib.Path), got 5")
    ):
        preview("circle-3", interactions=1, out=tmp_path / "p.html", png=5)
    assert (tmp_path / "afile").read_text() == "mine" and not (tmp_path / "p.html").exists()
    locked = tmp_path / "locked"  # read-only (root writes anywhere: its refusal is made here)
    locked.mkdir()
    made = tempfile.TemporaryFile

    def read_only(*a, dir=None, **kw):
        if dir is not None and Path(dir) == locked:
            raise PermissionError(13, "Permission denied")
        return made(*a, dir=dir, **kw)

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
    for out in (locked / "p.html", locked / "new" / "p.html"):  # found before the rollout
        with pytest.raises(ConfigError, match=re.escape(f"{out}: cannot write in {locked} (Perm")):
            preview("circle-3", interactions=1, out=out)


def test_write_html_never_replaces_a_users_file(tmp_path):
    prev = _record("circle-3", interactions=1)
    notes = tmp_path / "notes.html"
    notes.write_text("my notes")
    with pytest.raises(ConfigError, match=r"notes\.html exists and is not a preview"):
        prev.write_html(notes)
    with pytest.raises(ConfigError, match=re.escape("give a file name ending in .html or .htm")):
        prev.write_html(tmp_path / "notes.txt")
    assert notes.read_text() == "my notes" and not (tmp_path / "notes.txt").exists()
    page = prev.write_html(tmp_path / "p.html")
    assert prev.write_html(page) == page  # an earlier preview is replaced
    empty = tmp_path / "empty.html"
    empty.touch()  # as tempfile.mkstemp(suffix=".html") leaves it: nothing to lose
    assert PREVIEW_MARK in prev.write_html(empty).read_text()


def test_record_refuses_a_task_name_or_a_policy_that_is_not_a_function():
    env = make_task("circle-3")
    try:
        with pytest.raises(ConfigError, match=r"env must be a task instance.*got 'circle-3'"):
            Preview.record("circle-3", scripted_policy(env, "stabilizing"), 1)
        with pytest.raises(ConfigError, match=r"policy must be a function.*got 'scripted'"):
            Preview.record(env, "scripted", 1)
    finally:
        env.close()


def test_missing_chromium_is_reported_with_the_install_hint(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("SILI_CHROMIUM", raising=False)
    with pytest.raises(ConfigError, match="apt-get install chromium"):
        find_chromium()


def test_a_png_without_chromium_is_refused_before_anything_is_recorded_or_written(
    monkeypatch, tmp_path, capsys
):
    """Asked for a PNG on a machine without a browser, the preview says so at once: no
    recording is made and no page is left half of what was asked for."""
    from sili_robots.preview import api

    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("SILI_CHROMIUM", raising=False)
    monkeypatch.setattr(api, "make_env_and_policy", lambda *_a: pytest.fail("recorded"))
    argv = ["preview", "circle-3", "--out", str(tmp_path / "p.html"), "--png"]
    assert main([*argv, str(tmp_path / "p.png")]) == 2
    assert "apt-get install chromium" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_failed_render_leaves_no_temporary_page(monkeypatch, tmp_path):
    import tempfile

    from sili_robots.preview import BrowserError

    monkeypatch.setenv("SILI_CHROMIUM", "false")  # an executable that exits at once
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with pytest.raises(BrowserError):
        preview("circle-3", interactions=1, out=None, png=tmp_path / "p.png")
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_leaves_no_temporary_page(monkeypatch, tmp_path):
    import tempfile

    import sili_robots.preview.api as preview_api

    def full_disk(*_args):
        raise OSError(28, "No space left on device")

    monkeypatch.setenv("SILI_CHROMIUM", "false")  # found; the write fails before it runs
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(preview_api, "write_html", full_disk)
    with pytest.raises(OSError, match="No space left"):
        preview("circle-3", interactions=1, out=None, png=tmp_path / "p.png")
    assert list(tmp_path.iterdir()) == []


RED = 0xD62728


def _picture(*discs):
    """A grey 40 x 40 picture with a red disc of radius 5 at each (x, y)."""
    rgb = np.full((40, 40, 3), 200, np.int16)
    yy, xx = np.mgrid[0:40, 0:40]
    for x, y in discs:
        rgb[(xx - x) ** 2 + (yy - y) ** 2 <= 25] = [0xD6, 0x27, 0x28]
    return rgb


def test_a_marker_behind_another_body_is_looked_for_with_that_body_hidden():
    from sili_robots.preview.check import marker_results
    from sili_robots.preview.scenes.base import Marker, hidden_set

    covered, uncovered = _picture(), _picture((20, 20))  # the arm hides the goal
    goal = Marker("goal", (0, 0, 0), RED, 0.1, 0.5)
    behind = Marker("goal", (0, 0, 0), RED, 0.1, 0.5, behind=("robot",))
    assert behind.views() == [("robot",)]
    hidden = {hidden_set("robot"): uncovered}
    (plain,) = marker_results(covered, [goal], [(20, 20)], [(24, 20)], hidden)
    (seen,) = marker_results(covered, [behind], [(20, 20)], [(24, 20)], hidden)
    assert not plain.ok and seen.ok and seen.fraction == 1.0
    # hidden or not, a goal drawn elsewhere is still missing
    (gone,) = marker_results(covered, [behind], [(20, 20)], [(24, 20)], {("robot",): covered})
    assert not gone.ok


def test_a_body_in_front_of_another_counts_both_as_drawn():
    """Two cars collided: hiding the one behind changes nothing; with the front car hidden,
    hiding the one behind does."""
    from sili_robots.preview.check import marker_results
    from sili_robots.preview.scenes.base import Marker, hidden_set

    front, back_only, empty = _picture((20, 20)), _picture((21, 20)), _picture()
    shots = {
        ("back",): front,  # the back car hidden: the front car still covers its place
        ("front",): back_only,
        hidden_set("front", "back"): empty,
    }
    back = Marker("back", (0, 0, 0), 0, 0.1, 0.5, toggle="back", behind=("front",))
    assert back.views() == [("back",), ("front",), ("back", "front")]
    alone = Marker("back", (0, 0, 0), 0, 0.1, 0.5, toggle="back")
    (seen,) = marker_results(front, [back], [(21, 20)], [(25, 20)], shots)
    (unseen,) = marker_results(front, [alone], [(21, 20)], [(25, 20)], shots)
    assert seen.ok and not unseen.ok


def test_a_marker_out_of_the_cameras_view_is_asked_for_only_if_it_must_be_seen():
    from sili_robots.preview.check import marker_results, problems
    from sili_robots.preview.scenes.base import Marker

    rgb = _picture((20, 20))
    png = _png(rgb)
    here = Marker("here", (0, 0, 0), RED, 0.1, 0.5)
    passed = Marker("passed", (9, 9, 9), RED, 0.1, may_leave_view=True)
    results = marker_results(rgb, [here, passed], [(20, 20), (-1, -1)], [(24, 20), (-1, -1)])
    assert [r.in_view for r in results] == [True, False] and all(r.ok for r in results)
    assert problems(png, results) == []
    framed_badly = marker_results(rgb, [here], [(55, 3)], [(60, 3)])  # the camera looks away
    assert problems(png, framed_badly) == [
        "here is not in the camera's view (at pixel (55, 3) of 40 x 40)"
    ]
    # a centre in view whose edge point lies behind the camera: looked for, with a small radius
    (edge_behind,) = marker_results(rgb, [here], [(20, 20)], [(-1, -1)])
    assert edge_behind.ok and edge_behind.radius_px == 2.0


def _png(rgb):
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb.astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def test_cli_rejects_bad_input_with_exit_2(tmp_path, capsys):
    for argv, message in [
        (["--policy", "greedy"], "invalid choice: 'greedy'"),
        (["--policy", "random", "--checkpoint", str(tmp_path)], "not allowed with argument"),
        (["--interactions", "0"], "need an integer >= 1"),
        (["--size", "479x360"], "'479x360' is not a size: give WIDTHxHEIGHT, e.g. 1280x960, from"),
        (["--size", "640x480x3"], "is not a size"),
    ]:
        with pytest.raises(SystemExit) as exc:
            main(["preview", "circle-3", *argv])
        assert exc.value.code == 2 and message in capsys.readouterr().err
    for size in [(480, 359), (4097, 480), (640.0, 480), "640x480"]:  # before the rollout
        with pytest.raises(ConfigError, match=re.escape(f"size {size!r}: give (width, height)")):
            preview("circle-3", interactions=10**6, out=None, png=tmp_path / "p.png", size=size)
    with pytest.raises(ConfigError, match=r"size \(800, 600\) is the picture's: give png too"):
        preview("circle-3", interactions=10**6, out=None, size=(800, 600))  # nothing to size
    assert main(["preview", "circle-3", "--size", "800x600"]) == 2
    assert "--size 800x600 is the PNG's: give --png too" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["preview", "circle-4"])
    assert "unknown task 'circle-4'" in capsys.readouterr().err
    assert main(["preview", "circle-3", "--checkpoint", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "is not a run directory" in err and "Traceback" not in err
    doors = "sili_robots.examples.two_doors:TwoDoorsEnv"
    train = ["train", "--task", doors, "--method", "sac", "--interactions", "1"]
    train += ["--set", "hidden=8"]
    assert main([*train, "--out", str(tmp_path / "doors"), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["preview", "circle-3", "--checkpoint", str(tmp_path / "doors")]) == 2
    assert f"was trained on {doors!r}, which has no scene" in capsys.readouterr().err
    circle = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1"]
    assert main([*circle, "--set", "hidden=8", "--out", str(tmp_path / "c"), "--no-progress"]) == 0
    capsys.readouterr()
    longer = ["preview", "circle-3", "--checkpoint", str(tmp_path / "c"), "--env-kwarg=horizon=9"]
    assert main(longer) == 2
    assert f"--env-kwarg horizon=9: the run in {tmp_path / 'c'} was trained with horizon 50" in (
        capsys.readouterr().err
    )
    with pytest.raises(ConfigError, match=r"env_kwargs horizon=9: the run in .* horizon 50"):
        make_env_and_policy("circle-3", checkpoint=tmp_path / "c", env_kwargs={"horizon": 9})
    assert (
        main(["preview", "circle-3", "--checkpoint", str(tmp_path / "doors"), "--seed", "7"]) == 2
    )
    assert "--seed 7 and --checkpoint: a trained run's agent goes on with the game" in (
        capsys.readouterr().err
    )
    with pytest.raises(ConfigError, match="seed 7 and checkpoint: a trained run's agent goes on"):
        preview("circle-3", checkpoint=tmp_path / "c", seed=7, out=None)
    played = preview("circle-3", checkpoint=tmp_path / "c", interactions=1, out=tmp_path / "p.html")
    assert played.preview.recording.frames[0]["game_interaction"] == 1  # the trained game goes on


def test_a_scripted_preview_plays_the_controller_asked_for():
    name, env, _, label = make_env_and_policy("sawyer-reach", env_kwargs={"controller": "osc"})
    try:
        assert name == "sawyer-reach" and env.unwrapped.controller_name == "osc"
        assert label == "scripted stabilizing, controller=osc"  # on the picture's title
    finally:
        env.close()
    _, env, _, label = make_env_and_policy("sawyer-reach")  # the default is named too
    env.close()
    assert label == "scripted stabilizing, controller=mink"


def test_a_trained_runs_title_names_its_controller_given_or_not(tmp_path):
    """A controller ablation's pictures say which controller each run was trained with."""
    for controller in ("mink", "joint_velocity"):
        given = [] if controller == "mink" else ["--controller", controller]
        run = tmp_path / controller
        train = ["train", "--task", "sawyer-reach", "--method", "sac", "--interactions", "1"]
        assert main([*train, "--set", "hidden=8", "--no-progress", "--out", str(run), *given]) == 0
        _, env, _, label = make_env_and_policy("sawyer-reach", checkpoint=run)
        env.close()
        assert label == f"trained SAC, seed 0, controller={controller} ({controller})"


def test_a_trained_run_is_previewed_with_another_controller(tmp_path):
    """A transfer ablation's picture: the run's agent, trained with mink, plays with OSC, and
    the title says both; the run's own controller, given, is not named twice."""
    run = tmp_path / "r"
    train = ["train", "--task", "sawyer-reach", "--method", "sac", "--interactions", "1"]
    assert main([*train, "--set", "hidden=8", "--no-progress", "--out", str(run)]) == 0
    played = {}
    for given in (None, "osc", "mink"):
        kwargs = None if given is None else {"controller": given}
        if given == "mink":  # the run's own, a numpy horizon of its own too: nothing new
            kwargs["horizon"] = np.int64(50)
        _, env, pol, label = make_env_and_policy("sawyer-reach", checkpoint=run, env_kwargs=kwargs)
        try:
            obs, info = env.reset()
            assert info["interaction"] == 1  # the game it trained in, restored on this controller
            played[given] = env.unwrapped.controller_name, label, pol(env, obs)
        finally:
            env.close()
    own = "trained SAC, seed 0, controller=mink (r)"
    assert [c for c, _, _ in played.values()] == ["mink", "osc", "mink"]
    assert [t for _, t, _ in played.values()] == [own, f"{own}, played with controller=osc", own]
    first = [a for _, _, a in played.values()]  # the run's agent, in the game it trained in
    np.testing.assert_array_equal(first[0], first[1])
    np.testing.assert_array_equal(first[0], first[2])


def test_preview_seed_picks_the_game_recorded(tmp_path, capsys):
    """`sili preview --seed N` records the game of seed N (Circle (8 Goals)' opponent differs
    by seed), seed 0 by default."""

    def ego(*extra: str) -> list:
        out = tmp_path / "page.html"
        assert main(["preview", "circle-8", "--interactions", "2", "--out", str(out), *extra]) == 0
        capsys.readouterr()
        _, track = _ego_clip(_commands(out.read_text()))
        return [(k["time"], list(k["value"])) for k in track["keys"]]

    default = ego()
    assert ego("--seed", "0") == default
    assert ego("--seed", "5") != default


def test_the_picture_checks_summary_counts_an_element_out_of_view_apart():
    """'picture check: ok (N scene elements seen, M out of view)': an element allowed out of
    view is not counted as seen."""
    from sili_robots.preview.browser import PageResult
    from sili_robots.preview.check import MarkerResult
    from sili_robots.preview.render import Rendered

    def marker(name, may_leave):
        return Marker(name, (0.0, 0.0, 0.0), 0x1F6FD1, 0.1, may_leave_view=may_leave)

    results = [
        MarkerResult(marker("ego", False), (10.0, 10.0), 5.0, 0.9),
        MarkerResult(marker("opponent", False), (20.0, 20.0), 5.0, 0.8),
        MarkerResult(marker("trail", True), (-1.0, -1.0), 5.0, 0.0, in_view=False),
    ]
    page = PageResult(png=b"", width=640, height=480)
    assert Rendered(page, 0, results).seen_summary() == "2 scene elements seen, 1 out of view"
    assert Rendered(page, 0, results[:2]).seen_summary() == "2 scene elements seen"


def test_cli_records_three_interactions_into_preview_html_by_default(monkeypatch, tmp_path, capsys):
    """Without --out and --interactions, `sili preview` records 3 interactions into
    ./preview.html, as its help says."""
    monkeypatch.chdir(tmp_path)
    assert main(["preview", "circle-3"]) == 0
    out = capsys.readouterr().out
    assert "task=circle-3 policy=scripted stabilizing interactions=3 frames=153" in out
    assert "wrote preview.html (" in out and [p.name for p in tmp_path.iterdir()] == [
        "preview.html"
    ]


def test_a_browser_that_will_not_start_is_one_error_line_and_exit_1(monkeypatch, tmp_path, capsys):
    """`sili preview --png` with a browser that dies at start: one line naming why, exit 1."""
    monkeypatch.setenv("SILI_CHROMIUM", "false")  # an executable that exits at once
    argv = ["preview", "circle-3", "--interactions", "1", "--out", str(tmp_path / "p.html")]
    assert main([*argv, "--png", str(tmp_path / "p.png")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("sili preview: error: Chromium closed its DevTools pipe")
    assert err.count("\n") == 1 and "Traceback" not in err


def test_a_browser_gone_before_it_reads_its_first_command_is_a_browser_error(monkeypatch):
    """A browser that has exited by the time its first command is written (a broken pipe, on a
    loaded machine) is told as the one it closed is, not as a traceback."""
    from sili_robots.preview import Browser, BrowserError

    popen = subprocess.Popen

    def exited_at_once(*args, **kwargs):
        proc = popen(*args, **kwargs)
        proc.wait(timeout=30)
        return proc

    monkeypatch.setattr(subprocess, "Popen", exited_at_once)
    with pytest.raises(BrowserError, match=r"^Chromium closed its DevTools pipe \(/"):
        Browser(executable=shutil.which("false"), timeout=20).start()


def test_the_circle_legend_names_the_opponents_locations_only_where_there_are_some():
    """The grey discs of Circle (3 Goals) are in the legend; Circle (Continuous) has none."""
    three = _record("circle-3", interactions=1)
    assert [label for _, label in three.scene.legend(three.recording)] == [
        "ego",
        "ego's path",
        "opponent (hidden from ego)",
        "opponent's locations",
        "circle",
    ]
    cont = _record("circle-continuous", interactions=1)
    assert "opponent's locations" not in [label for _, label in cont.scene.legend(cont.recording)]


def test_driving_caption_names_the_egos_lane_and_whether_it_was_left_at_the_red_line():
    """Merged into the left lane (the scripted stabilizing policy): "ego in the left lane",
    "was left at the red line"; straight on (the still policy): the centre lane, "was not"."""
    left = _record("driving", interactions=1)
    env = make_task("driving")
    try:
        straight = Preview.record(env, scripted_policy(env, "still"), 1, 0, "driving", "still")
    finally:
        env.close()
    caption = left.scene.caption(left.recording, left.recording.last)
    assert "; ego in the left lane" in caption and "was left at the red line" in caption
    assert "; ego in the centre lane" in left.scene.caption(left.recording, 0)
    caption = straight.scene.caption(straight.recording, straight.recording.last)
    assert "was not left at the red line" in caption


def test_sawyer_caption_says_whether_the_gripper_is_above_the_height_plane():
    """The scripted reach starts 0.90 m high (under the 0.95 m plane) and ends above it."""
    prev = _record("sawyer-reach", interactions=1)
    rec = prev.recording
    assert rec.series("ee")[0][2] < rec.static["plane_z"] < rec.series("ee")[-1][2]
    assert "gripper 0.90 m (below the plane)" in prev.scene.caption(rec, 0)
    end = prev.scene.caption(rec, rec.last)  # the game's end: no next goal, the return whole
    assert "(above the plane)" in end and re.search(r"plane\); return -?\d", end), end


def test_cli_writes_html(tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "sili_robots.cli",
            "preview",
            "circle-continuous",
            "--interactions",
            "2",
            "--out",
            str(tmp_path / "c.html"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "frames=102" in out.stdout and "self-contained" in out.stdout
    assert (tmp_path / "c.html").stat().st_size > 500_000
    html = (tmp_path / "c.html").read_text()
    assert html.rstrip().endswith("</html>") and PREVIEW_MARK in html[-65536:]
    again = ["preview", "circle-3", "--interactions", "1", "--out", str(tmp_path / "c.html")]
    assert main(again) == 0  # a preview replaces its own page (only)
    assert (tmp_path / "c.html").read_text() != html


def test_a_preview_past_its_frame_limit_is_refused_before_the_rollout(
    monkeypatch, capsys, tmp_path
):
    """``--interactions 100000000`` recorded silently into gigabytes for a page no browser plays."""
    import sili_robots.preview.api as api

    def began(*_args, **_kwargs):
        raise AssertionError("the rollout began")

    monkeypatch.setattr(api, "record_rollout", began)
    assert api.MAX_FRAMES // 51 == 980  # Circle's H = 50: 51 frames an interaction
    with pytest.raises(SystemExit):
        main(["preview", "--help"])
    assert f"at most {api.MAX_FRAMES:,} frames" in " ".join(capsys.readouterr().out.split())
    out = str(tmp_path / "p.html")
    assert main(["preview", "circle-3", "--interactions", "981", "--out", out]) == 2
    err = capsys.readouterr().err
    limit = "a preview animates at most 50000 frames, 980 interactions of H = 50; give fewer"
    assert f"interactions 981: {limit}" in err and "Traceback" not in err
    with make_task("circle-3") as env, pytest.raises(AssertionError, match="the rollout began"):
        Preview.record(env, scripted_policy(env, "stabilizing"), 980)  # the most: allowed


def test_an_unknown_task_argument_is_named_as_the_preview_was_given_it():
    """It named ``make_task``, a function the caller never called; gymnasium's own arguments
    (``max_episode_steps``) would cut the interactions the scene draws H + 1 frames of."""
    for given in ("foo", "max_episode_steps"):
        with pytest.raises(ConfigError, match=rf"no argument {given} \(env_kwargs\); its arg"):
            preview("circle-3", env_kwargs={given: 3}, out=None)


def test_a_preview_is_titled_by_its_tasks_name_when_none_is_given():
    """It said ``CircleEnv`` (the class of every Circle variant), ``DrivingEnv``."""
    for env, name in [(gym.make("sili/Circle8-v1"), "circle-8"), (make_task("driving"), "driving")]:
        with env:
            prev = Preview.record(env, lambda e, obs: e.action_space.sample() * 0, 1)
        assert prev.recording.task == name and prev.scene.title(prev.recording).startswith(name)


@pytest.fixture(scope="module")
def two_interactions() -> Iterator[Preview]:
    env = make_task("circle-3")
    try:
        yield Preview.record(env, scripted_policy(env, "stabilizing"), 2, task="circle-3")
    finally:
        env.close()


def test_the_frame_one_past_the_last_is_refused(two_interactions):
    frames = len(two_interactions.recording)
    assert two_interactions.frame(frames - 1) == frames - 1
    with pytest.raises(ConfigError, match="outside the recording"):
        two_interactions.frame(frames)


def test_the_return_so_far_starts_at_zero_in_every_interaction(two_interactions):
    firsts = [f for f in two_interactions.recording.frames if f["t"] == 0]
    assert len(firsts) == 2 and all(f["interaction_return"] == 0.0 for f in firsts)


def test_an_animation_keys_the_frame_before_each_change():
    """A jump is drawn as a jump, not faded in over the frames before it."""
    from sili_robots.preview.scenes.base import change_frames

    assert change_frames([0, 0, 0, 1, 1, 1]) == [0, 2, 3, 5]
    assert change_frames(np.empty((0, 3))) == [] and change_frames([7.0]) == [0]


def test_the_keyed_frames_are_those_of_a_frame_by_frame_comparison():
    """The frames are found in array operations (a Python loop per frame made a long
    interaction's scene take minutes); what they are is the loop's: np.allclose of neighbours,
    NaN never equal to itself."""
    from sili_robots.preview.scenes.base import change_frames

    def by_loop(values):
        keep = {0, len(values) - 1}
        for f in range(1, len(values)):
            if not np.allclose(values[f], values[f - 1]):
                keep.update((f - 1, f))
        return sorted(keep)

    rng = np.random.default_rng(0)
    held = np.repeat(rng.normal(size=(12, 3)), rng.integers(1, 5, 12), axis=0)  # steps
    held[5] += 1e-9  # within allclose's tolerance: no key
    held[9, 1] = np.nan
    for values in (held, held[:, 0], held > 0, rng.normal(size=(6, 4, 4)), np.zeros((4, 2))):
        assert change_frames(values) == by_loop(values)


def test_page_data_cannot_close_its_script_and_legend_labels_are_escaped():
    from sili_robots.preview.html import Overlay, SceneRecorder, _js, scene_html

    assert "</" not in _js(["a</script><b>"])
    page = scene_html(SceneRecorder(), Overlay("t", captions=["x</script>y"]))
    assert page.count("</script>") == page.count("<script")
    page = scene_html(SceneRecorder(), Overlay("t", legend=[("#fff", "a<b>&c")]))
    assert "a&lt;b&gt;&amp;c" in page


def test_colours_are_red_green_blue():
    from sili_robots.preview.shapes import hex_rgb, rgb_hex

    assert rgb_hex((1.0, 0.5, 0.0)) == 0xFF8000
    assert hex_rgb(rgb_hex((0.0, 0.0, 1.0))) == (0, 0, 255)


def test_a_picture_of_background_alone_is_blank():
    """The blank check without a browser (tests/test_preview_browser.py checks it on pictures
    Chromium renders)."""
    from sili_robots.preview.check import blank_problem

    gradient = np.repeat(np.linspace(150, 250, 40, dtype=np.int16)[:, None, None], 40, axis=1)
    rgb = np.repeat(gradient, 3, axis=2)
    assert "picture is blank: only 0.0% of pixels" in (blank_problem(rgb) or "")
    rgb[10:30, 10:30] = [0xD6, 0x27, 0x28]  # a body drawn: not blank
    assert blank_problem(rgb) is None


def _sent(recorder: SceneRecorder) -> list[tuple[str, str]]:
    return [(c["type"], c["path"]) for c in map(umsgpack.unpackb, recorder.commands())]


def test_an_object_set_again_drops_the_properties_of_the_one_it_replaces():
    """meshcat's server forgets a node's properties when its object is set again; the file
    replays the same scene, not the old object's properties onto the new one."""
    recorder = SceneRecorder()
    vis = meshcat.Visualizer(window=recorder)
    vis["ball"].set_object(g.Sphere(0.1))
    vis["ball"].set_property("visible", False)
    vis["ball"].set_object(g.Sphere(0.2))
    assert [s for s in _sent(recorder) if s[1] == "/meshcat/ball"] == [
        ("set_object", "/meshcat/ball")
    ]
    vis["ball"].set_property("visible", True)
    assert [s for s in _sent(recorder) if s[1] == "/meshcat/ball"] == [
        ("set_object", "/meshcat/ball"),
        ("set_property", "/meshcat/ball"),
    ]


def test_deleting_the_root_clears_the_whole_scene_as_the_server_does():
    recorder = SceneRecorder()
    vis = meshcat.Visualizer(window=recorder)
    vis["ball"].set_object(g.Sphere(0.1))
    vis["box"].set_object(g.Box([0.1, 0.1, 0.1]))
    vis["/"].delete()  # the path "/": the scene tree's root
    assert recorder.commands() == []
    vis["ball"].set_object(g.Sphere(0.2))
    assert _sent(recorder) == [("set_object", "/meshcat/ball")]


def test_a_marker_one_pixel_past_the_edge_is_out_of_view():
    """A marker at x == width (past the last column) was looked for in the picture."""
    rgb = np.full((40, 40, 3), 200, np.int16)
    passed = Marker("passed", (9, 9, 9), RED, 0.1, may_leave_view=True)
    right, below = marker_results(rgb, [passed, passed], [(40, 20), (20, 40)], [(44, 20), (24, 40)])
    assert not right.in_view and not below.in_view
    assert right.ok and below.ok  # it may leave the view: not reported missing


def test_a_view_covered_by_text_boxes_is_blank():
    """A picture whose 3D view the caption and legend cover whole passed as not blank."""
    rgb = np.zeros((40, 40, 3), np.int16)
    rgb[:, ::2] = 255  # column stripes: drawn, not background, under the boxes
    problem = blank_problem(rgb, [(0, 0, 40, 20), (0, 20, 40, 40)])
    assert problem == "picture is blank: the 3D view is covered by text boxes"


def test_a_preview_writes_where_its_tilde_path_names_and_checks_that_file(tmp_path, monkeypatch):
    """``~`` is the home folder for the check and the write alike (it was checked there and
    written to ./~ before)."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "notes.html").write_text("a user's page")
    with pytest.raises(ConfigError, match=r"notes\.html exists and is not a preview"):
        preview("circle-3", policy="scripted", interactions=1, out="~/notes.html")
    result = preview("circle-3", policy="scripted", interactions=1, out="~/p.html", png="~/p.png")
    assert result.html == tmp_path / "home" / "p.html" and result.html.is_file()
    assert result.png == tmp_path / "home" / "p.png" and result.png.is_file()
    assert not (tmp_path / "~").exists()


def test_a_previews_picture_mark_keeps_the_png_valid(tmp_path):
    """The mark that lets a later preview replace its own picture goes after the IHDR chunk,
    which a PNG must begin with: decoders that check (matplotlib's) refused it before."""
    import io

    import matplotlib.image as mpimg
    from PIL import Image

    from sili_robots.preview.api import PNG_MARK, check_output, marked_png

    plain = io.BytesIO()
    Image.new("RGB", (7, 5), (10, 200, 30)).save(plain, format="PNG")
    marked = marked_png(plain.getvalue())
    assert marked[12:16] == b"IHDR" and b"tEXt" + PNG_MARK in marked
    pixels = mpimg.imread(io.BytesIO(marked), format="png")
    assert pixels.shape == (5, 7, 3) and np.allclose(pixels[0, 0], np.array([10, 200, 30]) / 255)
    (tmp_path / "mine.png").write_bytes(plain.getvalue())
    (tmp_path / "ours.png").write_bytes(marked)
    assert check_output(tmp_path / "ours.png", "png") == tmp_path / "ours.png"  # replaceable
    with pytest.raises(ConfigError, match="exists and is not a preview"):
        check_output(tmp_path / "mine.png", "png")


def test_a_preview_closes_the_task_it_built_whether_or_not_it_succeeds(tmp_path, monkeypatch):
    """Left open, a Driving preview would hold the process's one libsumo simulation."""
    import sili_robots.preview.api as api

    closed = []
    real = api.make_env_and_policy

    def counted(*args, **kwargs):
        name, env, policy, label = real(*args, **kwargs)
        close = env.close
        monkeypatch.setattr(env, "close", lambda: closed.append(name) or close(), raising=False)
        return name, env, policy, label

    monkeypatch.setattr(api, "make_env_and_policy", counted)
    preview("circle-3", interactions=1, out=tmp_path / "p.html")
    assert closed == ["circle-3"]

    def fails(*_args, **_kwargs):
        raise RuntimeError("recording failed")

    monkeypatch.setattr(Preview, "record", fails)
    with pytest.raises(RuntimeError, match="recording failed"):
        preview("circle-8", interactions=1, out=tmp_path / "q.html")
    assert closed == ["circle-3", "circle-8"]
