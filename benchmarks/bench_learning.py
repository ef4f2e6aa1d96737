"""Learning benchmark: methods x seeds on a task, each run in its own process, then a table.

For each run: final task reward and true stability (fraction of interactions whose true
strategy stayed the same) over the last ``--window`` interactions, the first interaction at
which a ``--window`` rolling stability reached 0.9, wall time, and the latent diagnostics.

    python benchmarks/bench_learning.py --task circle-3 \\
        --methods sili,lili,sac,oracle,stable,smirl --seeds 0,1,2 --interactions 3000 \\
        --workers 2 --out runs/bench-circle3
    python benchmarks/bench_learning.py --from-runs sweeps/circle-3/runs   # table finished runs

Then the learning targets are checked per task: SILI holds the true strategy in >= 90% of the
last ``--window`` interactions in at least 2 of 3 seeds (two thirds of them), and its mean final
task reward is within 15% of Oracle's cost (judged only where Oracle's reward is negative) and
above LILI's and SAC's. A folder with several configurations of one method on a task (profiles,
b values, budgets) is tabulated but not judged. A run stopped midway resumes as recorded; a
finished shorter one is extended; one of other settings than those asked for is refused.
"""

from __future__ import annotations

import argparse
import copy
import itertools
import json
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pandas as pd

from sili_robots.agent.matmul import machine_key
from sili_robots.agent.methods import LATENT_METHODS
from sili_robots.atomic import nearest_existing
from sili_robots.build import make_run_config
from sili_robots.commands.common import parse_settings, positive_int, task_name
from sili_robots.diagnostics import latent_diagnostics
from sili_robots.errors import ConfigError, one_line_errors
from sili_robots.metrics import HOLDING, first_stable, kept, kept_fraction, run_metrics
from sili_robots.migrations import migrate_run, setting_path
from sili_robots.runs import (
    CONFIG,
    DAMAGED_CONFIG,
    DAMAGED_SUMMARY,
    MACHINE_SETTINGS,
    SUMMARY,
    RunConfig,
    read_config,
    read_json,
    run_differences,
)
from sili_robots.sweep import parse_seeds
from sili_robots.sweep.results import finished_summary

MARKS = {True: "MET    ", False: "NOT MET", None: "N/A    "}
#: the methods the targets compare
TARGET_METHODS = ("sili", "oracle", "lili", "sac")


def run_one(task: str, method: str, seed: int, args: argparse.Namespace) -> Path:
    """Train (or finish) one run; a run stopped midway resumes as its config.json records it,
    and a finished shorter one is extended to ``--interactions``."""
    out = Path(args.out) / f"{task}-{method}-s{seed}"
    summary = out / SUMMARY
    if (
        summary.exists()
        and read_json(summary, DAMAGED_SUMMARY, "interactions")["interactions"] == args.interactions
    ):
        return out
    cli = [sys.executable, "-m", "sili_robots.cli", "train"]
    if (out / CONFIG).exists():  # recorded: only these options may go with --resume
        cmd = [*cli, "--resume", str(out), "--interactions", str(args.interactions)]
    else:
        cmd = [*cli, "--task", task, "--method", method, "--seed", str(seed), "--out", str(out)]
        cmd += ["--interactions", str(args.interactions)]
        if args.latent and method in LATENT_METHODS:
            cmd += ["--latent", args.latent]
        for item in args.set:
            cmd += ["--set", item]
    cmd.append("--no-progress")
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{out}: sili train failed:\n{done.stderr.strip()}")
    return out


def stable_by(df: pd.DataFrame, window: int) -> float:
    """The interaction that ends the first ``window`` of true stability >= 0.9 (NaN: never)."""
    start = first_stable(kept(df).to_numpy(), window)
    return float("nan") if start is None else float(df["interaction"].iloc[start + window - 1])


def variant_of(run: dict) -> str:
    """What one configuration's seeds share: everything recorded (as the current layout reads
    it) but the seed and the per-machine settings."""
    run = copy.deepcopy(migrate_run(run))
    run.pop("seed", None)
    for setting in MACHINE_SETTINGS:
        *parents, key = setting.split(".")
        node = run
        for name in parents:
            node = node.get(name, {})
        node.pop(key, None)
    return json.dumps(run, sort_keys=True)


def table(run_dirs: list[Path], window: int) -> pd.DataFrame:
    rows = []
    for d in run_dirs:  # each file read checked: a damaged one is named
        run = read_config(d)
        summary = finished_summary(d)
        if summary is None:
            raise ConfigError(f"{d} has not finished (no {SUMMARY})")
        df = run_metrics(d)  # metrics.csv, or a collected run's .csv.gz
        if df is None:
            raise ConfigError(f"{d} has logged no interaction (no metrics.csv)")
        rows.append(
            {
                "task": run.task,
                "method": run.method,
                "latent": run.agent.latent,
                "seed": run.seed,
                "interactions": len(df),
                "final_task_reward": df["task_reward"].tail(window).mean(),
                "final_stability": kept_fraction(df.tail(window)),
                "first_stable_0.9": stable_by(df, window),
                "latent_purity": latent_diagnostics(df, window).get("latent_purity", float("nan")),
                "wall_min": summary["wall_time_s"] / 60,
                "variant": variant_of(read_json(d / CONFIG, DAMAGED_CONFIG, "run")["run"]),
            }
        )
    return pd.DataFrame(rows)


def check_targets(df: pd.DataFrame) -> list[tuple[str, bool | None, str]]:
    """The learning targets for SILI on each task, each as (what, met, the measured numbers);
    ``met`` is None where a target cannot be judged. A method's seeds are compared only when
    they share one configuration: averaging several would compare nothing."""
    out: list[tuple[str, bool | None, str]] = []
    for task, runs in df.groupby("task"):
        judged = runs[runs["method"].isin(TARGET_METHODS)]
        mixed = sorted(m for m, v in judged.groupby("method")["variant"].nunique().items() if v > 1)
        if mixed:
            out.append(
                (
                    f"{task}: targets",
                    None,
                    f"not checked: several configurations of {', '.join(mixed)} (other profiles, "
                    "b, budgets or settings); tabulate one configuration per method",
                )
            )
        elif "sili" in set(runs["method"]):
            out += task_targets(task, runs)
    return out


def task_targets(task: str, df: pd.DataFrame) -> list[tuple[str, bool | None, str]]:
    mean = df.groupby("method")["final_task_reward"].mean()
    sili = df[df["method"] == "sili"]
    held = int((sili["final_stability"] >= HOLDING).sum())
    need = -(-2 * len(sili) // 3)  # at least two thirds of the seeds: 2 of 3, 4 of 5
    out: list[tuple[str, bool | None, str]] = [
        (
            f"{task}: SILI stability >= {HOLDING} in at least 2 of 3 seeds ({need} of {len(sili)})",
            held >= need,
            f"{held} of {len(sili)} seeds ({', '.join(f'{x:.2f}' for x in sili.final_stability)})",
        )
    ]
    if "oracle" in mean:
        numbers = f"SILI {mean['sili']:.2f}, Oracle {mean['oracle']:.2f}"
        if mean["oracle"] < 0:  # 15% is of Oracle's cost: rewards here are minus costs
            ratio = mean["sili"] / mean["oracle"]
            out.append(
                (
                    f"{task}: SILI task reward within 15% of Oracle's",
                    ratio <= 1.15,
                    f"{numbers} ({ratio:.2f}x Oracle's cost)",
                )
            )
        else:
            out.append(
                (
                    f"{task}: SILI task reward within 15% of Oracle's",
                    None,
                    f"{numbers}: not judged, Oracle's reward is not a cost (< 0)",
                )
            )
    for other in ("lili", "sac"):
        if other in mean:
            out.append(
                (
                    f"{task}: SILI task reward above {other.upper()}'s",
                    mean["sili"] > mean[other],
                    f"SILI {mean['sili']:.2f}, {other.upper()} {mean[other]:.2f}",
                )
            )
    return out


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--task", type=task_name, default="circle-3")
    p.add_argument("--methods", default="sili,lili,sac,oracle,stable,smirl")
    p.add_argument("--seeds", default="0,1,2", help="e.g. 0-2 or 0,2,7")
    p.add_argument("--interactions", type=positive_int, default=3000)
    p.add_argument("--latent", default=None, help="latent kind for sili, lili and stable")
    p.add_argument("--set", action="append", default=[], help="agent override KEY=VALUE")
    p.add_argument("--window", type=positive_int, default=100)
    p.add_argument("--workers", type=positive_int, default=2)
    p.add_argument("--out", default="runs/bench-learning")
    p.add_argument("--from-runs", type=Path, help="only tabulate the finished runs in this folder")
    args = p.parse_args()
    t0 = time.perf_counter()
    if args.from_runs is not None:
        if not args.from_runs.is_dir():
            p.error(f"--from-runs {args.from_runs}: not a folder")
        dirs = sorted(d for d in args.from_runs.iterdir() if (d / "summary.json").exists())
        if not dirs:
            p.error(
                f"--from-runs {args.from_runs}: no finished runs in it (a run is a folder with a "
                "summary.json; a sweep keeps them in its runs/ folder)"
            )
    else:
        jobs = [(args.task, m, s) for m, s in itertools.product(*checked_jobs(p, args))]
        folder = nearest_existing(Path(args.out))
        if not folder.is_dir():
            p.error(f"--out {args.out}: {folder} is not a folder (the runs go in folders inside)")
        for task, method, seed in jobs:  # before any run starts: a run is never shortened
            config = Path(args.out) / f"{task}-{method}-s{seed}" / CONFIG
            if (config.parent / SUMMARY).exists():  # damaged: named now, not after the others
                read_json(config.parent / SUMMARY, DAMAGED_SUMMARY, "interactions")
            if config.exists():
                recorded = read_config(config.parent)
                if recorded.interactions > args.interactions:
                    p.error(
                        f"--interactions {args.interactions}: {config.parent} is set to "
                        f"{recorded.interactions}; give at least that, or another --out"
                    )
                other = _other_settings(recorded, task, method, seed, args)
                if other:  # reused or resumed as recorded, it would not be the run asked for
                    said = [
                        f"{key}: {there!r} there, {asked!r} asked" for key, there, asked in other
                    ]
                    more = f" and {len(said) - 3} more" if len(said) > 3 else ""
                    settable = all(key.startswith(("agent.", "addons.")) for key, _, _ in other)
                    fix = "the settings it was made with, or " if settable else ""
                    p.error(
                        f"{config.parent} holds a run of other settings ({'; '.join(said[:3])}"
                        f"{more}): give {fix}another --out"
                    )
        print(f"machine: {machine_key()} each", flush=True)  # what the runs trained now ran on
        with ThreadPoolExecutor(args.workers) as pool:
            dirs = list(pool.map(lambda j: run_one(*j, args), jobs))
    df = table(dirs, args.window)
    print(df.drop(columns="variant").to_string(index=False, float_format="%.3g"))
    finals = ["final_task_reward", "final_stability"]
    # std over seeds with ddof 0, as the figures and RESULTS.md's tables
    agg = df.groupby(["task", "method"])[finals].agg([("mean", "mean"), ("std", _population_std)])
    print()
    print(agg.to_string(float_format="%.3g"))
    for what, met, numbers in check_targets(df):
        print(f"{MARKS[met]} {what}: {numbers}")
    print(f"\nwall time {(time.perf_counter() - t0) / 60:.1f} min with {args.workers} workers")


def checked_jobs(p: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[list, list]:
    """The methods and seeds to train, each checked (with ``--set``) before any run starts;
    a bad one exits 2 naming it and what is allowed."""

    def checked(option: str, check: Callable[[], Any]) -> Any:
        try:
            return check()
        except ConfigError as err:
            p.error(f"{option}: {err}")

    seeds = checked("--seeds", lambda: parse_seeds(args.seeds))
    settings = checked("--set", lambda: parse_settings(args.set))
    if args.latent and any(setting_path(name) == "latent" for name in settings):
        p.error("give one of --latent and --set latent, not both")  # as sili train says
    methods = [m.strip() for m in args.methods.split(",")]
    twice = sorted({m for m in methods if methods.count(m) > 1})
    if twice:  # one run folder each: the second would find the first training there
        p.error(f"--methods {args.methods}: {', '.join(twice)} given twice")
    for m in methods:
        latent = args.latent if m in LATENT_METHODS else None  # as run_one passes it on
        given = [f"--set {' '.join(args.set)}"] if args.set else []
        given += [f"--latent {latent}"] if latent else []
        option = f"--methods {m}" + (f" with {' and '.join(given)}" if given else "")
        checked(
            option,
            lambda m=m, latent=latent: make_run_config(
                args.task, m, 0, 1, latent=latent, settings=settings
            ),
        )
    return methods, seeds


def _other_settings(
    recorded: RunConfig, task: str, method: str, seed: int, args: argparse.Namespace
) -> list[tuple[str, Any, Any]]:
    """How the run on disk differs from the one ``--set`` and ``--latent`` ask for, but its
    budget and the machine's settings not given (``run_one`` reuses it, or resumes it as
    recorded; as a sweep, it keeps the kernels a machine chose for it, not those asked for)."""
    latent = args.latent if method in LATENT_METHODS else None
    settings = parse_settings(args.set)
    wanted = make_run_config(
        task, method, seed, args.interactions, latent=latent, settings=settings
    )
    given = {f"agent.{setting_path(name)}" for name in settings}
    ignored = {"interactions", *MACHINE_SETTINGS} - given
    return run_differences(recorded.to_dict(), wanted.to_dict(), ignored)


def _population_std(values: pd.Series) -> float:
    return float(values.std(ddof=0))


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
