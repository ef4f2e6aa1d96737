"""``sili sweep``: train tasks x methods x seeds (x b x controllers) on a process pool or Ray."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

from sili_robots.agent import LATENT_CHOICES, METHODS, PROFILES
from sili_robots.agent.methods import paper_departures
from sili_robots.build import unversioned_note
from sili_robots.commands.common import (
    CONTROLLERS_HELP,
    LATENT_HELP,
    add_override_args,
    add_schedule_args,
    counted,
    given_options,
    non_negative_int,
    parse_settings,
    path_arg,
    positive_int,
    schedule_args,
    task_kwargs_arg,
    track_typed_options,
    writable_dir,
)
from sili_robots.errors import ConfigError, compared
from sili_robots.migrations import setting_path
from sili_robots.sweep.spec import (
    SWEEP_SCHEDULES,
    SweepSpec,
    check_task_arguments,
    parse_betas,
    parse_list,
    parse_seeds,
)

BACKENDS = ("local", "ray")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep",
        help="run many training runs (tasks x methods x seeds x b x controllers), resumably",
        description="Every combination becomes one run directory under OUT/runs/; finished runs "
        "are skipped and interrupted ones resume when the same sweep is run again. Writes "
        "OUT/results.csv (a row per run per interaction) and OUT/runs.csv (a row per run).",
    )
    p.add_argument(
        "--tasks",
        help="comma-separated task names or package.module:ClassName, e.g. circle-3,circle-8",
    )
    p.add_argument("--methods", help=f"comma-separated methods ({', '.join(METHODS)}), or 'all'")
    p.add_argument(
        "--seeds", default="0", help="seeds: ranges and lists, e.g. 0-4 or 0,2,7 (default 0)"
    )
    p.add_argument(
        "--beta",
        metavar="B1,B2,...",
        help="stability weights b to sweep (for sili and smirl; other methods fix b)",
    )
    add_schedule_args(p, scope=" in every run")
    p.add_argument(
        "--controller",
        metavar="C1,C2,...",
        help=f"controllers to sweep on the tasks that take one ({CONTROLLERS_HELP})",
    )
    p.add_argument("--latent", choices=LATENT_CHOICES, help=f"latent kind: {LATENT_HELP}")
    p.add_argument(
        "--profile",
        choices=PROFILES,
        help="settings every run starts from: the package's defaults or the paper's appendix "
        "(run names get -paper; default: each task's, the paper's for sili on driving)",
    )
    p.add_argument(
        "--interactions",
        type=positive_int,
        default=1000,
        help="interactions per run (default 1000); with --resume, extend every run to this many",
    )
    p.add_argument(
        "--checkpoint-every",
        type=positive_int,
        default=50,
        help="interactions between each run's checkpoints, where --resume continues (default 50)",
    )
    add_override_args(
        p,
        scope=" for every run",
        refused="; not b, the latent kind or the method (--beta or --beta-schedule, --latent, "
        "--methods)",
        refused_kwargs="; controller=C is --controller C",
    )
    p.add_argument("--out", type=path_arg, help="sweep directory (created, or continued)")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the sweep in --out: its runs start anew (its own files only)",
    )
    p.add_argument(
        "--resume",
        type=path_arg,
        metavar="SWEEP_DIR",
        help="run the sweep recorded in SWEEP_DIR again (with it give only --interactions and "
        "how it runs: --backend, --workers, --ray-address, --retries, --no-tensorboard, "
        "--no-progress, --dry-run)",
    )
    p.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help="local processes (default), or Ray (the ray extra: pip install -e '.[ray]')",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        help="parallel runs (local default: the CPU count; ray default: as the cluster allows)",
    )
    p.add_argument(
        "--ray-address",
        type=ray_address,
        metavar="ADDRESS",
        help="with --backend ray: the Ray cluster to join (e.g. auto, HOST:6379, "
        "ray://HOST:10001); default: a local one",
    )
    p.add_argument(
        "--retries",
        type=non_negative_int,
        default=0,
        help="re-run a run whose worker died this many times (it resumes from its checkpoint; "
        "default 0)",
    )
    p.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard scalars")
    p.add_argument("--no-progress", action="store_true", help="no live display (log lines only)")
    p.add_argument("--dry-run", action="store_true", help="list the runs and their state, run none")
    p.set_defaults(run=run)
    track_typed_options(p)


#: what ``--resume SWEEP_DIR`` takes besides: how to run the recorded sweep, not what it holds
#: (and ``--interactions``, which extends it)
RESUME_OPTIONS = (
    "interactions",
    "backend",
    "workers",
    "ray_address",
    "retries",
    "no_tensorboard",
    "no_progress",
    "dry_run",
)


#: what ray.init takes as an address: auto, local, HOST:PORT, ray://HOST:PORT ([IPv6]:PORT)
RAY_ADDRESS = re.compile(r"auto|local|(ray://)?([A-Za-z0-9.\-]+|\[[0-9A-Fa-f:.]+\]):\d{1,5}")


def ray_address(text: str) -> str:
    """A Ray cluster address, checked before anything is written (Ray names a bad one only
    when the sweep connects)."""
    port = text.strip().rpartition(":")[2]
    if not RAY_ADDRESS.fullmatch(text.strip()) or (port.isdigit() and int(port) > 65535):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a Ray address; give auto, local, HOST:PORT or ray://HOST:PORT "
            "(PORT up to 65535)"
        )
    return text.strip()


def spec_from_args(args: argparse.Namespace) -> SweepSpec:
    from sili_robots.agent import METHODS
    from sili_robots.agent.methods import LATENT_METHODS

    if args.tasks is None or args.methods is None:
        raise ConfigError("--tasks and --methods are required (or --resume SWEEP_DIR)")
    methods = list(METHODS) if args.methods.strip() == "all" else parse_list(args.methods)
    if "all" in methods:
        raise ConfigError(f"--methods {args.methods!r}: 'all' stands alone (every method)")
    if args.latent is not None and not set(methods) & set(LATENT_METHODS):
        # checked for new sweeps only: a recorded one that gave it resumes as it ran
        raise ConfigError(
            f"--latent applies to methods {', '.join(LATENT_METHODS)} only, none of which is in "
            f"the sweep ({', '.join(methods)}); the others fix latent = 'none'"
        )
    env_kwargs = task_kwargs_arg(args)
    controllers = _controllers(_controller_text(args.controller, env_kwargs))
    schedules = schedule_args(args)
    spec = SweepSpec(
        tasks=parse_list(args.tasks),
        methods=methods,
        seeds=parse_seeds(args.seeds),
        interactions=args.interactions,
        betas=parse_betas(args.beta) if args.beta is not None else None,
        **{
            field: [list(p) for p in schedules[path].points]
            for field, (path, _) in SWEEP_SCHEDULES.items()
            if path in schedules
        },
        controllers=controllers,
        latent=args.latent,
        profile=args.profile,
        agent_overrides=parse_settings(args.agent_set),
        env_kwargs=env_kwargs,
        checkpoint_every=args.checkpoint_every,
    )
    check_task_arguments(spec)  # new sweeps only, as --latent above
    _note_settings(spec, parse_settings(args.agent_set))
    if args.latent == "partial" and "lili" in methods:  # (on Speaker-Listener's default too)
        print(
            "sili sweep: note: --latent partial learns no latent strategy and LILI always learns "
            "one: its runs learn a discrete latent",
            file=sys.stderr,
        )
    for task in spec.tasks:
        note = unversioned_note(task)
        if note:
            print(f"sili sweep: note: {note}", file=sys.stderr)
    return spec


def _note_settings(spec: SweepSpec, given: dict[str, Any]) -> None:
    """A note per ``--set`` setting some of the sweep's methods never read (every run records
    it; a sweep gives its settings to all its methods, so it is not refused), and per one that
    departs from the paper profile of runs recorded as that profile."""
    from sili_robots.sweep import expand

    paths = {setting_path(name): name for name in given}
    unread: dict[tuple[str, str], dict[str, list[str]]] = {}  # (name, why) -> method -> tasks
    departs: dict[tuple[str, str], dict[str, list[str]]] = {}  # (name, paper's) -> ...
    for run in expand(spec):
        cfg = run.config
        for path, why in cfg.unread_settings(paths).items():
            _add(unread, (paths[path], why), cfg.method, cfg.task)
        for path, value in paper_departures(cfg.agent, paths).items():
            _add(departs, (paths[path], f"{path} {compared(value)}"), cfg.method, cfg.task)
    for (name, why), methods in unread.items():
        print(
            f"sili sweep: note: --set {name} does nothing for {_where(methods)}: {why}",
            file=sys.stderr,
        )
    for (name, paper), methods in departs.items():
        print(
            f"sili sweep: note: --set {name} departs from the paper profile ({paper} there) for "
            f"{_where(methods)}: recorded as profile paper with it",
            file=sys.stderr,
        )


def _where(methods: dict[str, list[str]]) -> str:
    """``sili on circle-3, driving; lili on driving``"""
    return "; ".join(f"{m} on {', '.join(tasks)}" for m, tasks in methods.items())


def _add(
    notes: dict[tuple[str, str], dict[str, list[str]]], key: tuple[str, str], method: str, task: str
) -> None:
    """Note ``key`` for ``method`` on ``task`` (each once, in the sweep's order)."""
    tasks = notes.setdefault(key, {}).setdefault(method, [])
    tasks += [task] if task not in tasks else []


def _controller_text(given: str | None, env_kwargs: dict[str, Any]) -> str | None:
    """``--controller``, or ``--env-kwarg controller=C`` taken as it (and out of the task
    arguments), as ``sili train`` takes either: the sweep names its runs by controller
    (``task_kwargs_arg`` refuses both given)."""
    if "controller" not in env_kwargs:
        return given
    value = env_kwargs.pop("controller")
    if not isinstance(value, str):
        raise ConfigError(f"--env-kwarg controller={value!r}: give controller names, e.g. osc")
    return value


def _controllers(text: str | None) -> list[str] | None:
    if text is None:
        return None
    controllers = parse_list(text)
    if not controllers:
        raise ConfigError(f"no controllers in --controller {text!r}; give e.g. mink,osc")
    return controllers


def _specs_and_dir(args: argparse.Namespace) -> tuple[list[SweepSpec], Path]:
    from sili_robots.sweep.runner import extended
    from sili_robots.sweep.state import recorded_specs

    if args.resume is not None:
        specs = recorded_specs(args.resume)  # a clear error when it is not a sweep
        recorded = given_options(args, {"resume", *RESUME_OPTIONS})
        if recorded:
            allowed = ", ".join(args.option_names[dest] for dest in RESUME_OPTIONS)
            raise ConfigError(
                f"--resume SWEEP_DIR runs the sweep as {args.resume} records it; it takes no "
                f"{', '.join(recorded)} (allowed with it: {allowed})"
            )
        if _extends(args):
            specs = extended(specs, args.interactions, args.resume)
        return specs, args.resume
    if args.out is None:
        raise ConfigError("--out SWEEP_DIR is required")
    return [spec_from_args(args)], args.out


def _dry_run(args: argparse.Namespace, specs: list[SweepSpec], sweep_dir: Path) -> int:
    """Print each planned run and what the sweep would do with it; refuse what it would (a run
    another process trains: after the listing, which shows it)."""
    from sili_robots.sweep.runner import as_found, as_made, check_planned, plan, replaced_runs
    from sili_robots.sweep.state import RunBeingTrained, run_path, shorter_run

    planned = plan(specs)
    if args.overwrite:  # what is on disk goes: every planned run is new
        names = [r.name for r in planned]
        for name in replaced_runs(sweep_dir, planned):
            if name in names:
                print(f"{name}\tnew")
            elif run_path(sweep_dir, name).is_dir():
                print(f"{name}\tremoved")
        print(counted(len(planned), "run"))
        return 0
    planned = as_made(sweep_dir, planned)
    recorded = args.resume is not None
    try:
        found, shorter = check_planned(sweep_dir, planned, recorded)
    except RunBeingTrained:
        found = {run_.name: as_found(sweep_dir, run_) for run_ in planned}
        shorter = []
        for run_ in planned:
            with contextlib.suppress(ConfigError):  # (the trained one raises: listed as such)
                if recorded and shorter_run(sweep_dir, found[run_.name]):
                    shorter.append(run_)
        _list_planned(sweep_dir, planned, found, shorter)
        raise
    _list_planned(sweep_dir, planned, found, shorter)
    return 0


def _list_planned(sweep_dir: Path, planned: list, found: dict, shorter: list) -> None:
    """One line per planned run: its state and what the sweep does first with it."""
    from sili_robots.runs import CHECKPOINT, ERROR_FILE
    from sili_robots.sweep.state import run_path, run_state, training_worker

    for run_ in planned:
        on_disk = found[run_.name]
        path = run_path(sweep_dir, on_disk.name)
        notes = [] if on_disk is run_ else [f"its folder {on_disk.name} is renamed to it first"]
        pid = training_worker(path)
        if pid is not None:  # (the sweep refuses to run now)
            state = f"training (process {pid})"
        elif run_ in shorter:
            state = "resumable" if (path / CHECKPOINT).is_file() else "new"
            notes.insert(0, f"extended to {run_.config.interactions}")
        else:
            state = run_state(path)
            if (path / ERROR_FILE).is_file():  # the run's last attempt failed
                notes.insert(0, f"failed before, see its {ERROR_FILE}")
        print(f"{run_.name}\t{state}" + (f" ({', '.join(notes)})" if notes else ""))
    print(counted(len(planned), "run"))


def _extends(args: argparse.Namespace) -> bool:
    """``--resume SWEEP_DIR --interactions N``: the recorded sweep, every run extended to N."""
    return args.resume is not None and "interactions" in args.typed_options


def _backend(args: argparse.Namespace):
    if args.backend == "ray":
        from sili_robots.sweep.ray_backend import RayBackend, import_ray

        import_ray()  # a clear error now when Ray is not installed
        return RayBackend(args.ray_address, args.workers, args.retries)
    if args.ray_address:
        raise ConfigError("--ray-address needs --backend ray")
    from sili_robots.sweep.local import LocalBackend

    return LocalBackend(args.workers or os.cpu_count() or 1, args.retries)


def _check_agents_build(specs: list[SweepSpec], sweep_dir: Path) -> None:
    """Where ``--overwrite`` would remove runs, each planned run's agent built once per kind
    (runs apart by their seed alone are one), as ``sili train --overwrite`` does: a network too
    large for this machine fails before any run is removed."""
    from sili_robots.build import built_task, check_agent_builds
    from sili_robots.sweep.runner import plan, replaced_runs
    from sili_robots.sweep.state import run_path

    planned = plan(specs)
    if not any(run_path(sweep_dir, n).is_dir() for n in replaced_runs(sweep_dir, planned)):
        return
    kinds: set[str] = set()
    tasks: dict[str, Any] = {}  # built once per task and arguments
    try:
        for run_ in planned:
            cfg = run_.config
            task = cfg.task_id or cfg.task
            kind = json.dumps([task, cfg.env_kwargs, cfg.method, cfg.agent.to_dict()], default=str)
            if kind not in kinds:
                kinds.add(kind)
                built = json.dumps([task, cfg.env_kwargs], default=str)
                if built not in tasks:
                    tasks[built] = built_task(task, cfg.env_kwargs)
                check_agent_builds(cfg, tasks[built])
    finally:
        for env in tasks.values():
            env.close()


def _note_slow_kernels(specs: list[SweepSpec], sweep_dir: Path) -> None:
    """Runs to train whose kernels are slow on this machine (``sili train``'s note, once per
    kind): a run made elsewhere keeps the kernels it began with."""
    from collections import Counter

    from sili_robots.agent.matmul import slow_kernels
    from sili_robots.runs import read_config
    from sili_robots.sweep.runner import as_found, as_made, plan
    from sili_robots.sweep.state import run_path, run_state

    try:
        planned = as_made(sweep_dir, plan(specs))
    except ConfigError:
        return  # the sweep itself says why
    kinds: Counter[tuple[str, str]] = Counter()
    for run_ in planned:
        folder = run_path(sweep_dir, as_found(sweep_dir, run_).name)  # (an earlier version's)
        with contextlib.suppress(ConfigError):  # (a damaged record: the sweep says so)
            if run_state(folder) == "done" and read_config(folder).interactions >= (
                run_.config.interactions
            ):
                continue  # nothing to train
            kinds[run_.config.agent.matmul, run_.config.agent.sac.precision] += 1
    found: Counter[tuple[str, float, str]] = Counter()
    for (matmul, precision), count in kinds.items():
        for slow in slow_kernels(matmul, precision):
            found[slow] += count
    for (setting, ratio, fastest), count in found.items():
        runs = "1 run trains" if count == 1 else f"{count} runs train"
        print(
            f"sili sweep: note: {runs} with {setting}, {ratio:.1f}x as slow as {fastest} on this "
            "machine (as timed for its default): a run keeps its kernels, as its numbers depend "
            "on them",
            file=sys.stderr,
        )


def run(args: argparse.Namespace) -> int:
    from sili_robots.sweep.runner import run_sweep
    from sili_robots.sweep.state import check_sweep_dir

    specs, sweep_dir = _specs_and_dir(args)
    if args.resume is None:
        check_sweep_dir(sweep_dir, "--out")
    backend = _backend(args)  # its options checked in a dry run too; nothing starts yet
    if args.ray_address:  # before the sweep writes anything
        backend.check_reachable()
    writable_dir(sweep_dir, "--resume" if args.resume else "--out")  # creates nothing
    if args.dry_run:
        return _dry_run(args, specs, sweep_dir)
    if args.backend == "local":  # (Ray's may be a cluster's machines, with memory of their own)
        if args.overwrite:  # before the sweep removes the runs it replaces
            _check_agents_build(specs, sweep_dir)
        _note_slow_kernels(specs, sweep_dir)
    report = run_sweep(
        specs,
        sweep_dir,
        backend,
        progress=not args.no_progress,
        tensorboard_scalars=False if args.no_tensorboard else None,
        overwrite=args.overwrite,
        recorded=args.resume is not None,
    )
    print(
        json.dumps(
            {
                "sweep_dir": str(sweep_dir),
                "runs": len(report.planned),
                "already_done": len(report.skipped),
                "done": sum(o.status == "done" for o in report.outcomes.values()),
                "failed": report.failed,
                "results": str(sweep_dir / "results.csv"),
            },
            indent=2,
        )
    )
    return 0 if report.ok else 1
