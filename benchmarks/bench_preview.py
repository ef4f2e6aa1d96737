"""Preview generation time per task, against a plain rollout of the same policy.

For every task: a plain rollout (``run_interactions`` with the scripted stabilizing policy, no
recording; the reference: best of 3 after an untimed one) and then the preview the CLI makes (``sili
preview TASK --interactions N --png``): build the env and policy, record the rollout and build the
meshcat scene, write the self-contained HTML, render the picture frame in headless Chromium and
check it. All in one process, one task after the other, one Chromium for all (its start-up is timed
separately).
One-off costs of the preview itself (compiling Sawyer's visual model) land on it.

    python benchmarks/bench_preview.py [--interactions 3] [--tasks circle-3 driving ...]
                                       [--docs docs]   # also write docs/preview-TASK.png
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

from sili_robots.agent.matmul import machine_key
from sili_robots.commands.common import positive_int
from sili_robots.commands.common import seed as seed_number
from sili_robots.errors import one_line_errors
from sili_robots.policies import scripted_policy
from sili_robots.preview import Browser, BrowserError, Preview, make_env_and_policy
from sili_robots.preview.api import marked_png
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task
from sili_robots.tasks.registry import TASKS


def plain_rollout(task: str, interactions: int, seed: int, rounds: int = 3) -> float:
    """The best of ``rounds`` timed rollouts after an untimed one, which pays the process's
    first-use costs (a simulator's start, imports) so that they do not shrink the ratio."""
    env = make_task(task)
    try:
        policy = scripted_policy(env, "stabilizing")
        run_interactions(env, policy, interactions, seed=seed)
        best = float("inf")
        for _ in range(rounds):
            t0 = time.perf_counter()
            run_interactions(env, policy, interactions, seed=seed)
            best = min(best, time.perf_counter() - t0)
        return best
    finally:
        env.close()


def preview_times(
    task: str, interactions: int, seed: int, browser: Browser, out: Path, docs: Path | None
) -> dict[str, float]:
    t0 = time.perf_counter()
    name, env, policy, label = make_env_and_policy(task, "scripted")
    t1 = time.perf_counter()
    try:
        prev = Preview.record(env, policy, interactions, seed, name, label)
    finally:
        env.close()
    t2 = time.perf_counter()
    html = prev.write_html(out / f"{task}.html")
    t3 = time.perf_counter()
    shot = prev.render(html, browser=browser)
    t4 = time.perf_counter()
    problems = shot.problems()
    if problems:
        raise SystemExit(f"{task}: the picture failed its checks: {problems}")
    if docs is not None:
        docs.mkdir(parents=True, exist_ok=True)
        (docs / f"preview-{task}.png").write_bytes(marked_png(shot.png))  # sili preview's own
    return {
        "frames": len(prev.recording),
        "env": t1 - t0,
        "record_build": t2 - t1,
        "html": t3 - t2,
        "html_mb": html.stat().st_size / 1e6,
        "png": t4 - t3,
        "total": t4 - t0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--interactions", type=positive_int, default=3)
    parser.add_argument("--seed", type=seed_number, default=0)
    parser.add_argument("--tasks", nargs="*", choices=sorted(TASKS), default=sorted(TASKS))
    parser.add_argument("--docs", type=Path, default=None)
    args = parser.parse_args()
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU
    t0 = time.perf_counter()
    browser = Browser().start()
    startup = time.perf_counter() - t0
    rows = []
    try:
        with TemporaryDirectory() as tmp:
            for task in args.tasks:
                ref = plain_rollout(task, args.interactions, args.seed)
                rows.append(
                    (
                        task,
                        ref,
                        preview_times(
                            task, args.interactions, args.seed, browser, Path(tmp), args.docs
                        ),
                    )
                )
    finally:
        browser.close()
    print(f"Chromium start-up: {startup:.2f} s; interactions per preview: {args.interactions}")
    print(
        "| task | frames | plain rollout (reference) | env | record + scene | HTML (size) "
        "| PNG + checks | preview total | total / rollout |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for task, ref, r in rows:
        print(
            f"| {task} | {r['frames']} | {ref * 1e3:.1f} ms | {r['env']:.2f} s | "
            f"{r['record_build']:.2f} s | {r['html']:.2f} s ({r['html_mb']:.1f} MB) | "
            f"{r['png']:.2f} s | {r['total']:.2f} s | {r['total'] / ref:.1f}x |"
        )


if __name__ == "__main__":
    try:
        one_line_errors(main, Path(__file__).name)
    except BrowserError as err:  # e.g. no Chromium, or too little memory for it: as sili preview
        print(f"{Path(__file__).name}: error: {err}", file=sys.stderr)
        raise SystemExit(1) from None
