"""``sili preview``: a meshcat preview of a task played by a scripted policy or a trained agent.

Writes one self-contained HTML file (opens offline, animated with meshcat's timeline), optionally
renders its picture frame (the last; Driving's last pass) to PNG in headless Chromium (and checks
the picture shows the scene), and optionally serves the scene live on 127.0.0.1 until Ctrl-C
(what was written and checked is printed before serving, with the scene's title and legend,
which meshcat's live page does not show).
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sili_robots.commands.common import (
    add_task_args,
    path_arg,
    positive_int,
    registered_task,
    seed,
    task_arguments_given,
    writable_file,
)
from sili_robots.errors import ConfigError
from sili_robots.tasks.registry import TASKS

if TYPE_CHECKING:
    from sili_robots.preview import Preview, PreviewResult


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "preview",
        help="meshcat preview of a task: HTML, PNG (headless Chromium) or a live server",
        description="Record a rollout and show it in meshcat: it is written to --out, a "
        "self-contained HTML file (preview.html unless given); --png also renders its picture "
        "frame in headless Chromium, --serve also starts a live meshcat server on 127.0.0.1 "
        "until Ctrl-C.",
    )
    p.add_argument(
        "task",
        type=functools.partial(
            registered_task, command="preview", why="draws the registered tasks' scenes"
        ),
        help=f"task name: {', '.join(TASKS)}; an earlier version by its versioned name, "
        "e.g. circle-3-v0",
    )
    who = p.add_mutually_exclusive_group()
    who.add_argument(
        "--policy",
        choices=("scripted", "random"),
        help="scripted = the task's stabilizing reference policy (default)",
    )
    who.add_argument(
        "--checkpoint", type=path_arg, metavar="RUN_DIR", help="play the agent trained in RUN_DIR"
    )
    p.add_argument(
        "--interactions",
        type=positive_int,
        default=3,
        help="interactions to record (default 3; at most 50,000 frames, H + 1 each)",
    )
    p.add_argument(
        "--seed",
        type=seed,
        help="the game's seed (default 0); not with --checkpoint, whose agent goes on with the "
        "game it trained in",
    )
    p.add_argument(
        "--out",
        type=path_arg,
        default="preview.html",
        help="HTML file to write (preview.html): an earlier preview there is replaced, any other "
        "file never",
    )
    p.add_argument(
        "--png",
        type=path_arg,
        default=None,
        help="also render the picture frame to this PNG: the last, or on Driving the last "
        "interaction's moment the ego draws level with the opponent",
    )
    p.add_argument(
        "--size",
        type=size_arg,
        metavar="WIDTHxHEIGHT",
        help="the PNG's size in pixels (default 640x480; from 480x360 to 4096x4096)",
    )
    p.add_argument("--serve", action="store_true", help="serve live on 127.0.0.1 until Ctrl-C")
    add_task_args(p, only="; with --checkpoint: in place of the run's own")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.preview import BrowserError, preview
    from sili_robots.preview.api import check_output
    from sili_robots.preview.server import ServerError

    reported: list[int] = []

    def serving(result: PreviewResult) -> None:  # what was written and checked, then the URL
        reported.append(_report(result))
        colour = sys.stdout.isatty() and not os.environ.get("NO_COLOR")  # no-color.org
        print(_key(result.preview, colour))
        print(f"meshcat server: {result.url}  (Ctrl-C to stop)", flush=True)

    if args.checkpoint is not None and args.seed is not None:
        raise ConfigError(
            f"--seed {args.seed} and --checkpoint: a trained run's agent goes on with the game it "
            "trained in; drop --seed"
        )
    env_kwargs = task_arguments_given(args)
    if env_kwargs:
        from sili_robots.build import check_task_builds

        check_task_builds(args.task, env_kwargs, "--controller, --env-kwarg")
        if args.checkpoint is not None and Path(args.checkpoint).is_dir():
            from sili_robots.evaluation import check_played_horizon
            from sili_robots.runs import read_config

            run_dir = Path(args.checkpoint)
            check_played_horizon(run_dir, read_config(run_dir), env_kwargs, "--env-kwarg")
    if args.size is not None and args.png is None:
        raise ConfigError(f"--size {args.size[0]}x{args.size[1]} is the PNG's: give --png too")
    for path, option in ((args.out, "--out"), (args.png, "--png")):
        if path is not None:
            check_output(writable_file(Path(path), option), option)
    try:
        result = preview(
            args.task,
            policy=args.policy,
            checkpoint=args.checkpoint,
            interactions=args.interactions,
            seed=args.seed,
            out=args.out,
            png=args.png,
            serve=args.serve,
            on_ready=serving,
            env_kwargs=env_kwargs,
            size=args.size,
        )
    except (BrowserError, ServerError) as err:
        print(f"sili preview: error: {err}", file=sys.stderr)
        return 1
    return reported[0] if reported else _report(result)


def size_arg(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT``, e.g. 1280x960, in the range ``check_size`` allows."""
    from sili_robots.preview.api import MAX_SIDE, MIN_SIZE, check_size

    try:
        return check_size(tuple(int(side) for side in text.lower().split("x")))
    except (ValueError, ConfigError):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a size: give WIDTHxHEIGHT, e.g. 1280x960, from "
            f"{MIN_SIZE[0]}x{MIN_SIZE[1]} to {MAX_SIDE}x{MAX_SIDE}"
        ) from None


def _report(result: PreviewResult) -> int:
    """Print what was recorded, written and checked; 1 when the picture failed its checks."""
    rec = result.preview.recording
    print(f"task={rec.task} policy={rec.policy} interactions={rec.interactions} frames={len(rec)}")
    if result.html is not None:
        print(f"wrote {result.html} ({result.html.stat().st_size / 1e6:.1f} MB, self-contained)")
    if result.png is not None and result.rendered is not None:
        print(f"wrote {result.png} (frame {result.rendered.frame})")
        found = result.rendered.problems()
        if found:
            print("the picture failed its checks:", *found, sep="\n  ", file=sys.stderr, flush=True)
            return 1
        print(f"picture check: ok ({result.rendered.seen_summary()})")
    print("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in result.seconds.items()), flush=True)
    return 0


def _key(prev: Preview, colour: bool) -> str:
    """The title and legend the HTML page shows over the scene, for the live page, which is
    meshcat's own and shows neither; ``colour``: a swatch in each item's colour (a terminal)."""
    from sili_robots.preview.shapes import css, hex_rgb

    scene, rec = prev.scene, prev.recording
    items = []
    for rgb, label in scene.legend(rec):
        r, g, b = hex_rgb(rgb)
        items.append(
            f"\033[38;2;{r};{g};{b}m\u25a0\033[0m {label}" if colour else f"{label} ({css(rgb)})"
        )
    return f"scene: {scene.title(rec)}\nlegend: " + ", ".join(items)
