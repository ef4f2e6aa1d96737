"""``sili preview``: a meshcat preview of a task played by a scripted policy or a trained agent.

Writes one self-contained HTML file (opens offline, animated with meshcat's timeline), optionally
renders its picture frame (the last; Driving's last pass) to PNG in headless Chromium (and checks
the picture shows the scene), and optionally serves the scene live on 127.0.0.1 until Ctrl-C.
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

from sili_robots.commands.common import positive_int, registered_task, seed, writable_file


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "preview",
        help="meshcat preview of a task: HTML, PNG (headless Chromium) or a live server",
        description="Record a rollout and show it in meshcat: --out writes a self-contained "
        "HTML file, --png renders its picture frame in headless Chromium, --serve starts a live "
        "meshcat server on 127.0.0.1 until Ctrl-C.",
    )
    p.add_argument(
        "task",
        type=functools.partial(
            registered_task, command="preview", why="draws the registered tasks' scenes"
        ),
        help="task name, e.g. circle-3",
    )
    who = p.add_mutually_exclusive_group()
    who.add_argument(
        "--policy",
        default="scripted",
        choices=("scripted", "random"),
        help="scripted = the task's stabilizing reference policy (default)",
    )
    who.add_argument("--checkpoint", metavar="RUN_DIR", help="play the agent trained in RUN_DIR")
    p.add_argument(
        "--interactions", type=positive_int, default=3, help="interactions to record (default 3)"
    )
    p.add_argument("--seed", type=seed, default=0, help="first interaction's seed (default 0)")
    p.add_argument("--out", default="preview.html", help="HTML file to write (preview.html)")
    p.add_argument(
        "--png",
        default=None,
        help="also render the picture frame to this PNG: the last, or on Driving the last "
        "interaction's moment the ego draws level with the opponent",
    )
    p.add_argument("--serve", action="store_true", help="serve live on 127.0.0.1 until Ctrl-C")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.preview import BrowserError, preview
    from sili_robots.preview.server import ServerError

    def announce(url: str) -> None:
        print(f"meshcat server: {url}  (Ctrl-C to stop)", flush=True)

    if args.out is not None:
        writable_file(Path(args.out), "--out")
    if args.png is not None:
        writable_file(Path(args.png), "--png")
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
            on_url=announce,
        )
    except (BrowserError, ServerError) as err:
        print(f"sili preview: error: {err}", file=sys.stderr)
        return 1
    rec = result.preview.recording
    secs = ", ".join(f"{k} {v:.2f} s" for k, v in result.seconds.items())
    print(f"task={rec.task} policy={rec.policy} interactions={rec.interactions} frames={len(rec)}")
    if result.html is not None:
        print(f"wrote {result.html} ({result.html.stat().st_size / 1e6:.1f} MB, self-contained)")
    if result.png is not None and result.rendered is not None:
        print(f"wrote {result.png} (frame {result.rendered.frame})")
        found = result.rendered.problems()
        if found:
            print("the picture failed its checks:", *found, sep="\n  ", file=sys.stderr)
            return 1
        print(f"picture check: ok ({len(result.rendered.markers)} scene elements seen)")
    print(f"time: {secs}")
    return 0
