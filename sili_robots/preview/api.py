"""Preview a task from Python: record a rollout, build its meshcat scene, write HTML/PNG, serve.

    from sili_robots.preview import preview
    result = preview("circle-3", policy="scripted", interactions=3, out="p.html", png="p.png")

The policy is a scripted one (``scripted`` = the task's stabilizing reference, ``random``) or a
trained agent (``checkpoint=RUN_DIR``, through ``sili_robots.evaluation.policy_from_run``); any
``policy(env, obs) -> action`` can also be recorded directly with ``Preview.record``.
"""

from __future__ import annotations

import contextlib
import operator
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import meshcat
import numpy as np

from sili_robots.atomic import check_can_write_in, nearest_existing, write_bytes
from sili_robots.errors import (
    ConfigError,
    check_choice,
    check_count,
    check_flag,
    check_names,
    check_path,
    check_seed,
    is_number,
)
from sili_robots.preview.browser import Browser, find_chromium
from sili_robots.preview.build import overlay, populate, world_point
from sili_robots.preview.html import PREVIEW_MARK, SceneRecorder, scene_html, write_html
from sili_robots.preview.recording import Recording, record_rollout
from sili_robots.preview.render import HEIGHT, WIDTH, Rendered, render_html
from sili_robots.preview.scenes import TaskScene, scene_for
from sili_robots.preview.scenes.base import Marker

POLICIES = ("scripted", "random")
SCRIPTED_KIND = {"scripted": "stabilizing", "random": "random"}


class TeeWindow:
    """Send every meshcat command to several windows (a live server and a recorder), so the
    file and the live view are the same scene, byte for byte."""

    def __init__(self, *windows: Any) -> None:
        self.windows = windows

    def send(self, command: Any) -> None:
        for w in self.windows:
            w.send(command)


#: the most frames a preview animates (H + 1 per interaction): about 35 MB of page, past which
#: a browser plays it slowly and the recording holds gigabytes; ``sili rollout`` has no limit
MAX_FRAMES = 50_000


def _task_title(env: gym.Env) -> str:
    """The CLI name of ``env``'s task, for a scene's title: by its gymnasium id (``gym.make``),
    else its class's one name; a class of several names (Circle's variants) or none by the
    class (``build.task_name_of``, a run's record, gives a class path and refuses wrappers)."""
    from sili_robots.tasks.registry import current_names_of_class, task_spec

    spec = env.spec or env.unwrapped.spec
    if spec is not None:
        with contextlib.suppress(ConfigError):
            return task_spec(spec.id).name
    names = current_names_of_class(type(env.unwrapped))
    return names[0] if len(names) == 1 else type(env.unwrapped).__name__


@dataclass
class Preview:
    """A recorded rollout and its meshcat scene."""

    scene: TaskScene
    recording: Recording
    recorder: SceneRecorder = field(default_factory=SceneRecorder)

    @classmethod
    def record(
        cls,
        env: gym.Env,
        policy: Callable[[gym.Env, np.ndarray], np.ndarray],
        interactions: int,
        seed: int | None = None,
        task: str = "",
        policy_name: str = "",
        live: meshcat.Visualizer | None = None,
    ) -> Preview:
        """Roll ``policy`` out on ``env`` and build the scene (also into ``live`` if given);
        ``seed`` starts a game of that seed; None: 0, or the game a trained model's ``env``
        goes on with (``AgentFeedback.continues_game``)."""
        interactions = check_count("interactions", interactions)
        if seed is None and not getattr(env, "continues_game", False):
            seed = 0
        seed = None if seed is None else check_seed(seed)
        if not isinstance(env, gym.Env):  # a task's name goes to preview(), which builds it
            raise ConfigError(f"env must be a task instance (preview() takes names), got {env!r}")
        if not callable(policy):
            raise ConfigError(
                f"policy must be a function policy(env, obs) -> action, got {policy!r}"
            )
        scene = scene_for(env)
        horizon = env.unwrapped.horizon
        if interactions * (horizon + 1) > MAX_FRAMES:
            raise ConfigError(
                f"interactions {interactions}: a preview animates at most {MAX_FRAMES} frames, "
                f"{MAX_FRAMES // (horizon + 1)} interactions of H = {horizon}; give fewer "
                "(sili rollout plays any number, without a scene)"
            )
        rec = record_rollout(
            env,
            policy,
            scene.snapshot,
            interactions,
            seed=seed,
            task=task or _task_title(env),
            policy_name=policy_name,
            static=scene.static,
        )
        out = cls(scene, rec)
        window = out.recorder if live is None else TeeWindow(live.window, out.recorder)
        populate(meshcat.Visualizer(window=window), scene, rec)
        return out

    def html(self) -> str:
        return scene_html(self.recorder, overlay(self.scene, self.recording))

    def write_html(self, path: str | Path) -> Path:
        """Write the page to ``path``: a new file or an earlier preview, never another file."""
        checked = check_output(path, "path")
        return write_html(self.recorder, overlay(self.scene, self.recording), checked)

    def markers(self, frame: int | None = None) -> list[tuple[Marker, tuple[float, ...]]]:
        """What must be visible in ``frame`` (default: the scene's picture frame), with
        viewer-world points."""
        f = self.frame(frame)
        return [
            (m, world_point(self.scene, self.recording, m.position, f))
            for m in self.scene.markers(self.recording, f)
        ]

    def frame(self, frame: int | None = None) -> int:
        """``frame``, or the scene's default picture frame; ConfigError when out of range."""
        if frame is None:
            return self.scene.picture_frame(self.recording)
        last = len(self.recording) - 1
        try:  # an int, numpy's too (a 0-d integer array as well), never a bool
            index = None if isinstance(frame, (bool, np.bool_)) else operator.index(frame)
        except TypeError:
            index = None
        if index is None:
            raise ConfigError(f"frame must be an integer from 0 to {last}, got {frame!r}")
        if not 0 <= index <= last:
            raise ConfigError(f"frame {index} is outside the recording (0 to {last})")
        return index

    def render(
        self,
        html_path: str | Path,
        frame: int | None = None,
        browser: Browser | None = None,
        evaluate: str | None = None,
        size: tuple[int, int] = (WIDTH, HEIGHT),
    ) -> Rendered:
        """Screenshot ``frame`` (default: the scene's picture frame) of the written HTML at
        ``size`` (width, height in pixels) and check it."""
        f = self.frame(frame)
        width, height = check_size(size)
        return render_html(html_path, f, self.markers(f), browser, width, height, evaluate=evaluate)

    def render_live(
        self, url: str, frame: int | None = None, browser: Browser | None = None
    ) -> Rendered:
        """Screenshot ``frame`` of the scene as a live meshcat server shows it at ``url``."""
        f = self.frame(frame)
        return render_html(url, f, self.markers(f), browser=browser, live_fps=self.scene.fps)


def make_env_and_policy(
    task: str,
    policy: str | None = None,
    checkpoint: str | Path | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> tuple[str, gym.Env, Callable, str]:
    """(task name, env to step, policy, policy label) for a scripted policy (``policy``:
    scripted, the default, or random) or a trained run (``checkpoint``), one of them;
    ``env_kwargs`` build the task (for a trained run they replace its own of those names: a
    policy trained with one controller, played with another; the horizon stays the run's)."""
    from sili_robots.policies import scripted_policy
    from sili_robots.tasks import make_task, task_spec
    from sili_robots.tasks.registry import (
        check_argument_names,
        same_argument,
        task_defaults,
        title_arguments,
    )

    name = task_spec(task).name
    if env_kwargs is not None:
        env_kwargs = check_names("env_kwargs", env_kwargs)
        check_argument_names(name, env_kwargs, "env_kwargs")  # gymnasium's own: no scene cuts
    if checkpoint is not None and policy is not None:
        raise ConfigError(
            f"policy {policy!r} and checkpoint {str(checkpoint)!r}: a preview plays one of them "
            "(a scripted or random policy, or the run's agent)"
        )
    if checkpoint is None:
        policy = "scripted" if policy is None else policy
        check_choice("preview policy", policy, POLICIES)
        env = make_task(name, **(env_kwargs or {}))
        try:
            label = "random actions" if policy == "random" else f"scripted {SCRIPTED_KIND[policy]}"
            named = title_arguments(name, env_kwargs or {})
            label += "".join(f", {k}={v}" for k, v in named.items())
            return name, env, scripted_policy(env, SCRIPTED_KIND[policy]), label
        except BaseException:
            env.close()
            raise
    policy_from_run = _policy_from_run()
    run_dir = Path(checkpoint)
    if not run_dir.is_dir():
        raise ConfigError(
            f"checkpoint {str(checkpoint)!r} is not a run directory; give one written by "
            "`sili train --out` or a sweep's runs/NAME"
        )
    run_task, kwargs, make_policy = policy_from_run(run_dir)
    try:
        trained_on = task_spec(run_task).name
    except ConfigError:  # a user's task class: no scene to draw it in
        raise ConfigError(
            f"checkpoint {str(checkpoint)!r} was trained on {run_task!r}, which has no scene: "
            "previews draw the registered tasks"
        ) from None
    if trained_on != name:
        raise ConfigError(
            f"checkpoint {str(checkpoint)!r} was trained on {trained_on!r}, not {name!r} "
            f"(task version {run_task})"
        )
    from sili_robots.evaluation import check_played_horizon
    from sili_robots.labels import METHOD_NAMES
    from sili_robots.runs import read_config

    cfg = read_config(run_dir)
    check_played_horizon(run_dir, cfg, env_kwargs or {}, "env_kwargs")
    env = make_task(name, **{**kwargs, **(env_kwargs or {})})  # given ones replace the run's
    try:
        stepped, pol = make_policy(env)
    except BaseException:
        env.close()
        raise
    # the title says what was trained, where, then what it plays with when not its own
    given = "".join(f", {k}={v}" for k, v in title_arguments(run_task, cfg.env_kwargs).items())
    method = METHOD_NAMES.get(cfg.method, cfg.method)
    label = f"trained {method}, seed {cfg.seed}{given} ({run_dir.name})"
    own = {**task_defaults(run_task), **cfg.env_kwargs}  # one given at the run's own is not new
    missing = object()
    other = [
        f"{k}={v}"
        for k, v in (env_kwargs or {}).items()
        if not same_argument(own.get(k, missing), v)
    ]
    if other:
        label += ", played with " + ", ".join(other)
    return name, stepped, pol, label


def _policy_from_run() -> Callable:
    try:
        from sili_robots.evaluation import policy_from_run
    except ImportError as err:
        raise ConfigError(
            "--checkpoint needs sili_robots.evaluation.policy_from_run, which this installation "
            f"does not provide ({err}); use --policy scripted|random"
        ) from None
    return policy_from_run


@dataclass
class PreviewResult:
    """What ``preview`` produced, with wall-clock seconds per stage."""

    preview: Preview
    html: Path | None
    png: Path | None = None
    rendered: Rendered | None = None
    url: str | None = None
    seconds: dict[str, float] = field(default_factory=dict)


def preview(
    task: str,
    *,
    policy: str | None = None,
    checkpoint: str | Path | None = None,
    interactions: int = 3,
    seed: int | None = None,
    out: str | Path | None = "preview.html",
    png: str | Path | None = None,
    serve: bool = False,
    serve_seconds: float | None = None,
    on_ready: Callable[[PreviewResult], None] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    size: tuple[int, int] | None = None,
) -> PreviewResult:
    """Record ``interactions`` interactions of ``task`` and write/render/serve the preview;
    ``size``: the ``png``'s (width, height) in pixels (None: 640 x 480).

    ``seed``: the game's (default 0); none with ``checkpoint``, whose agent goes on with the
    game it trained in. ``png`` renders the scene's picture frame (the last; on Driving the last
    interaction's moment the ego draws level with the opponent) in headless Chromium (found
    before the recording, a ConfigError without it; ``out`` is written first; a temporary file
    is used when ``out`` is None, and removed). ``serve`` starts a live meshcat server on
    127.0.0.1, calls ``on_ready`` with the result so far (files written, picture checked,
    ``url`` set) and blocks for ``serve_seconds`` (None: until Ctrl-C); the server is stopped on
    every exit path.
    """
    from sili_robots.preview.server import LiveServer

    serve = check_flag("serve", serve)
    if checkpoint is not None and seed is not None:
        raise ConfigError(
            f"seed {seed!r} and checkpoint: a trained run's agent goes on with the game it "
            "trained in; give no seed"
        )
    if serve_seconds is not None and not (is_number(serve_seconds) and serve_seconds >= 0):
        raise ConfigError(f"serve_seconds must be a number >= 0 (or None), got {serve_seconds!r}")
    out = None if out is None else check_output(out, "out")  # "~" expanded, as written
    png = None if png is None else check_output(png, "png")
    if size is not None and png is None:
        raise ConfigError(f"size {size!r} is the picture's: give png too")
    size = (WIDTH, HEIGHT) if size is None else check_size(size)
    if png is not None:
        find_chromium()  # before the recording: a missing browser is told before any work
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    name, env, pol, label = make_env_and_policy(task, policy, checkpoint, env_kwargs)
    server = LiveServer() if serve else None
    temporary: Path | None = None
    try:
        if server is not None:
            server.start()
        prev = Preview.record(
            env,
            pol,
            interactions,
            seed,
            name,
            label,
            live=server.visualizer if server is not None else None,
        )
        seconds["record_and_build"] = time.perf_counter() - t0
        result = PreviewResult(prev, None, seconds=seconds)
        if out is not None or png is not None:
            t1 = time.perf_counter()
            result.html = _write(prev, out)
            temporary = None if out is not None else result.html
            seconds["html"] = time.perf_counter() - t1
        if png is not None:
            t2 = time.perf_counter()
            result.rendered = prev.render(result.html, size=size)
            result.png = Path(png)
            result.png.parent.mkdir(parents=True, exist_ok=True)
            write_bytes(result.png, marked_png(result.rendered.png))
            seconds["png"] = time.perf_counter() - t2
        if temporary is not None:
            temporary.unlink(missing_ok=True)
            result.html = temporary = None
        if server is not None:
            result.url = server.web_url
            server.serve(
                serve_seconds, on_ready=None if on_ready is None else lambda: on_ready(result)
            )
        return result
    finally:
        if temporary is not None:
            temporary.unlink(missing_ok=True)
        if server is not None:
            server.stop()
        env.close()


#: a PNG text chunk (keyword, NUL, text) naming what wrote the picture
PNG_MARK = b"Software\0sili-robots preview"
PNG_HEADER = 8 + 25  # the signature and the IHDR chunk, which must come first


def marked_png(png: bytes) -> bytes:
    """``png`` with ``PNG_MARK`` in a text chunk, so a later preview knows it may replace it."""
    chunk = b"tEXt" + PNG_MARK
    mark = len(PNG_MARK).to_bytes(4, "big") + chunk + zlib.crc32(chunk).to_bytes(4, "big")
    return png[:PNG_HEADER] + mark + png[PNG_HEADER:]


#: the smallest picture (width, height) whose title, caption and legend leave the scene in view
#: (Speaker-Listener's long caption covered a 400 x 300 one), and the largest side rendered
MIN_SIZE, MAX_SIDE = (480, 360), 4096


def check_size(size: Any) -> tuple[int, int]:
    """``size`` as (width, height) in pixels, from ``MIN_SIZE`` to ``MAX_SIDE`` a side."""
    bad = ConfigError(
        f"size {size!r}: give (width, height) in pixels, width from {MIN_SIZE[0]} and height "
        f"from {MIN_SIZE[1]}, each up to {MAX_SIDE}"
    )
    if not (isinstance(size, tuple | list) and len(size) == 2):
        raise bad
    try:
        return (
            check_count("width", size[0], MIN_SIZE[0], MAX_SIDE),
            check_count("height", size[1], MIN_SIZE[1], MAX_SIDE),
        )
    except ConfigError:
        raise bad from None


def check_output(path: str | Path, option: str) -> Path:
    """An output a preview may write (``option``: how the caller names it): an HTML or PNG
    name (Chromium opens a page by its suffix), and an existing file only if a preview wrote
    it or it is empty (as ``tempfile`` makes one): a run's or a user's file is never replaced;
    its folder must be one or be creatable."""
    path = check_path(option, path)
    suffixes = (".png",) if option.endswith("png") else (".html", ".htm")
    if path.suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {path}: give a file name ending in {' or '.join(suffixes)}")
    if path.is_file() and path.stat().st_size and not _written_by_a_preview(path):
        raise ConfigError(
            f"{option} {path} exists and is not a preview (or a picture of a version that did "
            "not mark its own); remove it or give another file name"
            if path.suffix.lower() == ".png"
            else f"{option} {path} exists and is not a preview; give another file name"
        )
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a folder; give a file name in it")
    folder = nearest_existing(path.parent)
    if not folder.is_dir():  # checked before the rollout, not at the write after it
        raise ConfigError(f"{option} {path}: {folder} is a file, so no folder can be made there")
    try:
        check_can_write_in(folder)
    except OSError as err:
        raise ConfigError(
            f"{option} {path}: cannot write in {folder} ({err.strerror or err}); give a file "
            "name where one can be written"
        ) from None
    return path


def _written_by_a_preview(path: Path) -> bool:
    with path.open("rb") as f:
        if path.suffix.lower() == ".png":
            return PNG_MARK in f.read(PNG_HEADER + 64)
        f.seek(max(path.stat().st_size - (1 << 16), 0))  # the mark is in the page's last script
        return PREVIEW_MARK in f.read().decode("utf-8", "replace")


def _write(prev: Preview, out: str | Path | None) -> Path:
    if out is not None:
        return prev.write_html(out)
    import tempfile

    fd, tmp = tempfile.mkstemp(prefix="sili-preview-", suffix=".html")
    import os

    os.close(fd)
    try:
        return prev.write_html(tmp)
    except BaseException:  # a full disk: the caller never learns the name, so it goes here
        Path(tmp).unlink(missing_ok=True)
        raise
