"""``sili train``: train one method on one task into a run directory (or resume one)."""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import os
import shlex
import sys
from collections.abc import Iterator
from pathlib import Path

from sili_robots.agent import BETA_METHODS, LATENT_CHOICES, METHODS, PROFILES, Schedule
from sili_robots.agent.methods import paper_departures
from sili_robots.build import make_run_config, unversioned_note
from sili_robots.commands.common import (
    CONTROLLERS_HELP,
    LATENT_HELP,
    add_override_args,
    add_schedule_args,
    check_schedule_overrides,
    counted,
    given_options,
    non_negative_int,
    parse_settings,
    path_arg,
    positive_int,
    schedule_args,
    seed,
    task_arguments_given,
    task_name,
    threads_arg,
    track_typed_options,
    unit_float,
    writable_dir,
)
from sili_robots.errors import STORAGE_ERRORS, ConfigError, compared
from sili_robots.labels import shell_path
from sili_robots.metrics import METRICS
from sili_robots.migrations import setting_path
from sili_robots.runs import (
    CHECKPOINT,
    CONFIG,
    TB_DIR,
    RunConfig,
    check_new_run_dir,
    make_run_dir,
    other_software,
    read_config,
    ready_new_run_dir,
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a method on a task (or --resume a run)")
    p.add_argument(
        "--task",
        type=task_name,
        help="task name, e.g. circle-3, or a task class as package.module:ClassName",
    )
    p.add_argument("--method", default="sili", choices=METHODS, help="(default sili)")
    p.add_argument(
        "--profile",
        choices=PROFILES,
        help="starting settings: the package's defaults, or the settings of the paper's appendix "
        "(default: the task's; for sili on driving the paper's, else the package's)",
    )
    p.add_argument(
        "--latent",
        choices=LATENT_CHOICES,
        help=f"latent kind of sili, stable and lili (partial: sili and stable): {LATENT_HELP}",
    )
    p.add_argument(
        "--interactions",
        type=positive_int,
        help="interactions to train (default 1000); with --resume, extend the run to this many",
    )
    p.add_argument(
        "--seed", type=seed, default=0, help="the run's seed, 0 .. 2**32 - 1 (default 0)"
    )
    p.add_argument("--out", type=path_arg, help="run directory to create")
    p.add_argument(
        "--resume",
        type=path_arg,
        metavar="RUN_DIR",
        help="continue a killed run (or, with --interactions, extend a finished one); with it "
        "give only --interactions and --no-progress",
    )
    p.add_argument(
        "--beta",
        type=unit_float,
        help="(sili, smirl) stability weight b in [0, 1], fixed (default: sili 0 until "
        "interaction 250, 0.5 from 300; 0.5 for smirl and sili's paper profile, as on driving)",
    )
    anneal = p.add_argument(
        "--beta-anneal",
        nargs="+",
        action="append",  # given twice: refused (beta_anneal), not the last kept
        help="(sili, smirl) b = START for DELAY interactions (default 0), then linear to END "
        "over LENGTH (one segment; several: --beta-schedule)",
    )
    anneal.usage_args = "START END LENGTH [DELAY]"  # type: ignore[attr-defined]
    add_schedule_args(p, scope="")
    p.add_argument("--controller", help=f"controller of a robot task ({CONTROLLERS_HELP})")
    add_override_args(p, scope="")
    p.add_argument(
        "--checkpoint-every",
        type=positive_int,
        default=50,
        help="interactions between checkpoints, where --resume continues (default 50)",
    )
    p.add_argument(
        "--threads",
        type=threads_arg,
        default=1,
        help="torch threads for this run (default 1; recorded, as it changes the summation order)",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace the run in --out (its own files only)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(run=run)
    track_typed_options(p)


def config_from_args(args: argparse.Namespace) -> RunConfig:
    if args.task is None:
        raise ConfigError(
            "--task is required (or --resume RUN_DIR); allowed tasks: " + ", ".join(_task_names())
        )
    settings = parse_settings(args.agent_set)
    for option, given in (
        ("--beta", args.beta is not None),
        ("--beta-anneal", bool(args.beta_anneal)),
        ("--beta-schedule", bool(args.beta_schedule)),
    ):
        if given and args.method not in BETA_METHODS:
            raise ConfigError(
                f"{option} does not apply to method {args.method!r} (its b is fixed); "
                f"use --method {' or '.join(BETA_METHODS)}"
            )
    if args.beta_anneal and args.beta_schedule:
        raise ConfigError("give one of --beta-anneal and --beta-schedule, not both")
    schedules = schedule_args(args)
    options = {}
    if args.beta_anneal:
        schedules["sili.beta"] = beta_anneal(args.beta_anneal)
        options["sili.beta"] = "--beta-anneal"
    if args.beta is not None and "sili.beta" in schedules:
        given = options.get("sili.beta", "--beta-schedule")
        raise ConfigError(f"give one of --beta and {given}, not both")
    check_schedule_overrides(schedules, settings, options)
    given = {setting_path(name): name for name in settings}
    if args.beta is not None and "sili.beta" in given:
        raise ConfigError(f"give one of --beta and --set {given['sili.beta']}, not both")
    if args.beta is not None:
        settings["sili.beta"] = args.beta
    settings.update(schedules)
    if args.latent is not None and "latent" in given:
        raise ConfigError(f"give one of --latent and --set {given['latent']}, not both")
    env_kwargs = task_arguments_given(args)
    _check_one_controller(args.task, args.method, env_kwargs)
    cfg = make_run_config(
        args.task,
        args.method,
        args.seed,
        args.interactions or 1000,
        latent=args.latent,
        profile=args.profile,
        settings=settings,
        env_kwargs=env_kwargs,
        checkpoint_every=args.checkpoint_every,
        threads=args.threads,
    )
    for path, why in cfg.unread_settings(given).items():
        print(f"sili train: note: --set {given[path]} does nothing here: {why}", file=sys.stderr)
    for path, value in paper_departures(cfg.agent, given).items():
        print(
            f"sili train: note: --set {given[path]} departs from the paper profile "
            f"({path} {compared(value)} there); the run is recorded as profile paper with it",
            file=sys.stderr,
        )
    note = unversioned_note(args.task)
    if note:
        print(f"sili train: note: {note}", file=sys.stderr)
    return cfg


def _check_one_controller(task: str, method: str, env_kwargs: dict) -> None:
    """A run trains with one controller: a sweep's list (``mink,osc``) is pointed to the sweep,
    on a task that takes a controller (another says it takes none)."""
    from sili_robots.tasks.registry import check_argument_names

    given = env_kwargs.get("controller")
    if not isinstance(given, str) or "," not in given:
        return
    check_argument_names(task, ["controller"], "--controller, --env-kwarg")
    sweep = shlex.join(
        ["sili", "sweep", "--tasks", task, "--methods", method, "--controller", given]
    )
    raise ConfigError(
        f"--controller {shlex.quote(given)}: a run trains with one controller; a run with each: "
        f"{sweep} --out SWEEP_DIR"
    )


def beta_anneal(given: list[list[str]]) -> Schedule:
    """``--beta-anneal START END LENGTH [DELAY]`` (given once) as a schedule of b."""
    if len(given) > 1:
        raise ConfigError(
            f"--beta-anneal given {len(given)} times; give it once (START END LENGTH [DELAY]), "
            "or several segments as --beta-schedule I:B,I:B,..."
        )
    (words,) = given
    if len(words) not in (3, 4):
        raise ConfigError(f"--beta-anneal takes START END LENGTH [DELAY], got {' '.join(words)}")
    start, end, length, *delay = words
    try:
        return Schedule.ramp(
            unit_float(start),
            unit_float(end),
            positive_int(length),
            non_negative_int(delay[0]) if delay else 0,
        )
    except argparse.ArgumentTypeError as err:
        raise ConfigError(f"--beta-anneal: {err}") from None


def _task_names() -> list[str]:
    from sili_robots.tasks import TASKS

    return list(TASKS)


def _rebuild_sweep_tables(run_dir: Path) -> None:
    """A sweep's run trained on by hand: the sweep's tables (results.csv, runs.csv) follow."""
    from sili_robots.sweep.results import write_tables
    from sili_robots.sweep.state import RUNS_DIR, SWEEP_FILE

    run_dir = Path(os.path.abspath(run_dir))  # not resolved: a run linked into a sweep is its
    sweep_dir = run_dir.parent.parent
    if run_dir.parent.name != RUNS_DIR or not (sweep_dir / SWEEP_FILE).is_file():
        return
    try:
        write_tables(sweep_dir)
    except (OSError, ConfigError) as err:  # the run is trained; only its sweep's tables lag
        print(
            f"{sweep_dir}'s tables were not rebuilt ({err}); "
            f"`sili plot {shell_path(sweep_dir)}` rebuilds them",
            file=sys.stderr,
        )


def run(args: argparse.Namespace) -> int:
    from sili_robots.runs import check_resumable
    from sili_robots.sweep import tensorboard
    from sili_robots.sweep.state import (
        check_not_in_a_sweep,
        check_not_trained,
        run_state,
        training_claim,
    )
    from sili_robots.training import resume, train, write_summary
    from sili_robots.verdict import verdict

    if args.resume is not None:
        recorded = read_config(args.resume)  # a clear error when it is not a run
        check_resumable(args.resume)
        writable_dir(args.resume, "--resume")
        by = " (a sweep's worker, which sili sweep --resume goes on with, or another sili train)"
        check_not_trained(args.resume, by=by)
        ignored = given_options(args, {"resume", "interactions", "no_progress"})
        if ignored:
            raise ConfigError(
                f"--resume continues {args.resume} as its config.json records it; with it give "
                f"only --interactions (to extend it) and --no-progress, not {', '.join(ignored)}"
            )
        target = recorded.interactions
        done = run_state(args.resume) == "done" and (args.interactions or target) <= target
        if args.interactions is None and done:
            print(
                f"{args.resume} has already trained all {target} of its interactions; "
                "--interactions N extends it",
                file=sys.stderr,
            )
        if not done:  # (nothing to train, nothing to say of its speed)
            _note_threads_beyond_cores(recorded.threads)
            _note_slow_kernels(recorded)
            _note_other_software(args.resume, recorded)
            _note_starting_over(args.resume)
        scalars = _keeps_scalars(args.resume)
        with (
            _resume_hint(args.resume),
            training_claim(args.resume),
            tensorboard.mirrored(args.resume, scalars),
        ):
            run_dir = resume(args.resume, not args.no_progress, args.interactions)
        _rebuild_sweep_tables(run_dir)
    else:
        cfg = config_from_args(args)
        if args.out is None:
            raise ConfigError("--out RUN_DIR is required for a new run")
        quoted = shell_path(args.out)
        check_not_trained(args.out)  # --overwrite too: never under a live trainer
        check_not_in_a_sweep(args.out, "--out")
        check_new_run_dir(args.out, args.overwrite, resume=f"--resume {quoted}")
        if args.out.is_dir():  # an existing folder (one to be made: make_run_dir says why not)
            writable_dir(args.out, "--out")
        _check_builds(cfg, agent=args.overwrite and (args.out / CONFIG).is_file())
        made = make_run_dir(args.out)
        _note_threads_beyond_cores(cfg.threads)
        _note_slow_kernels(cfg)
        # again with the claim: a run may have started and ended there since
        ready = functools.partial(
            ready_new_run_dir, args.out, args.overwrite, resume=f"--resume {quoted}"
        )
        with (
            _removed_if_left_empty(made),
            _resume_hint(args.out),
            training_claim(args.out, before=ready),
        ):
            run_dir = train(cfg, args.out, progress=not args.no_progress)
    summary = write_summary(run_dir)
    print(json.dumps({"run_dir": str(run_dir), **summary}, indent=2))
    print(verdict(run_dir), file=sys.stderr)  # for people; stdout stays one JSON document
    return 0


def _keeps_scalars(run_dir: Path) -> bool:
    """Whether the run's TensorBoard scalars (a sweep's run) are written on as it trains; a
    note when they cannot be, as they would no longer match its metrics."""
    from sili_robots.sweep import tensorboard

    if not (Path(run_dir) / TB_DIR).is_dir():
        return False
    if tensorboard.available():
        return True
    print(
        f"sili train: note: {Path(run_dir) / TB_DIR} is not updated (TensorBoard is not "
        "installed: pip install 'sili-robots[tensorboard]'); it ends where the run was",
        file=sys.stderr,
    )
    return False


def _note_threads_beyond_cores(threads: int) -> None:
    """More threads than cores is allowed (a run keeps its thread count, which decides how it
    rounds, when resumed on a smaller machine) but slows the run down; say so."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if cores and threads > cores:
        print(
            f"sili train: note: --threads {threads} is more than the {cores} CPU(s) this "
            f"process may use: the run is slower than with --threads {cores}",
            file=sys.stderr,
        )


def _note_slow_kernels(cfg: RunConfig) -> None:
    """A run keeps the kernels it began with (they decide how it rounds), also resumed on a
    machine where they are slow (bfloat16 products without bfloat16 units: ~10x); say so."""
    from sili_robots.agent.matmul import slow_kernels

    for setting, ratio, fastest in slow_kernels(cfg.agent.matmul, cfg.agent.sac.precision):
        print(
            f"sili train: note: {setting} is {ratio:.1f}x as slow as {fastest} on this machine "
            "(as timed for its default); the run keeps it, as its numbers depend on it",
            file=sys.stderr,
        )


def _note_other_software(run_dir: Path, cfg: RunConfig) -> None:
    """A run resumed on other code (its own add-ons' and task's too), libraries or processor
    than it last ran on goes on as a mix, which ``continued`` records; say so up front (what
    an earlier version did not record is no news)."""
    _, changed = other_software(run_dir, cfg)
    known = [f"{k} {then} -> {now}" for k, (then, now) in changed.items() if then and now]
    if known:
        print(
            f"sili train: note: {run_dir} goes on with other software than it last ran with "
            f"({'; '.join(known)}): its results mix both (config.json's continued records where)",
            file=sys.stderr,
        )


def _note_starting_over(run_dir: Path) -> None:
    """A run killed before its first checkpoint has nothing to go on from: it trains again from
    its first interaction, and the interactions it logged are trained and written anew."""
    if (run_dir / CHECKPOINT).is_file():
        return
    with contextlib.suppress(OSError, ValueError):  # unreadable: nothing to count
        logged = (run_dir / METRICS).read_text().count("\n") - 1  # whole lines past the header
        if logged > 0:
            print(
                f"sili train: note: {run_dir} was stopped before its first checkpoint: its "
                f"{counted(logged, 'logged interaction')} {'is' if logged == 1 else 'are'} "
                "discarded and it trains again from its first (no checkpoint holds them)",
                file=sys.stderr,
            )


@contextlib.contextmanager
def _resume_hint(run_dir: Path) -> Iterator[None]:
    """A run stopped (Ctrl-C, SIGTERM, a full disk) after its first checkpoint says how to go
    on."""
    try:
        yield
    except (KeyboardInterrupt, OSError) as stop:
        if isinstance(stop, OSError) and stop.errno not in STORAGE_ERRORS:
            raise
        from sili_robots.sweep.state import run_state

        with contextlib.suppress(OSError):  # the disk may refuse a read too
            if run_state(Path(run_dir)) == "done":  # stopped in its last interaction
                print(f"the run finished all its interactions: {run_dir}", file=sys.stderr)
            elif (Path(run_dir) / CHECKPOINT).is_file():
                when = "once the disk takes writes again, " if isinstance(stop, OSError) else ""
                print(
                    f"{when}continue the run with: sili train --resume {shell_path(run_dir)}",
                    file=sys.stderr,
                )
        raise


@contextlib.contextmanager
def _removed_if_left_empty(made: list[Path]) -> Iterator[None]:
    """The folders this command made for a new run (innermost first) go again when the run
    fails before it wrote anything there (too little memory for its agent, a stop while it was
    set up)."""
    try:
        yield
    except BaseException:
        with contextlib.suppress(OSError):  # one not empty, or gone: it and those above stay
            for folder in made:
                folder.rmdir()
        raise


def _check_builds(cfg: RunConfig, agent: bool) -> None:
    """Fail fast, with the task's own message, on bad task arguments (e.g. a controller); with
    ``agent`` build the agent too, before ``--overwrite`` removes a run (a network too large
    for this machine would fail only after)."""
    from sili_robots.build import built_task, check_agent_builds

    # a new run's task_id is its name's version, so the name builds the version it trains
    env = built_task(cfg.task, cfg.env_kwargs, "--controller, --env-kwarg")
    try:
        if agent:
            check_agent_builds(cfg, env)
    finally:
        env.close()
