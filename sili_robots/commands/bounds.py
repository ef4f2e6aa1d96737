"""``sili bounds TASK``: what the scripted reference policies score on a task (reward, stability).

Unlike ``sili rollout`` it plays every scripted kind the task has and prints them side by side:
the reference lines a learned curve is read against. ``--all --write`` stores every registered
task version's bounds in the packaged file ``sili plot`` draws from.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

from sili_robots.commands.common import (
    add_task_args,
    path_arg,
    registered_task,
    seed,
    task_arguments_given,
    writable_file,
)
from sili_robots.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> None:
    from sili_robots.bounds import (
        BOUNDS_FILE,
        DEFAULT_GAMES,
        DEFAULT_INTERACTIONS,
        DEFAULT_SEED,
        TASK_INTERACTIONS,
    )

    p = sub.add_parser(
        "bounds",
        help="reference bounds of a task: reward and true stability of its scripted policies",
        description="Plays the task's scripted policies (random, still = zero action, oracle = "
        "greedy with z, stabilizing = holds z, and where they exist blind = holds z without "
        "seeing it, tracking = predicts z without stabilizing) and prints each one's mean task "
        "reward per interaction and true stability (fraction of interactions 2..N whose true "
        "strategy stayed), over every interaction but each game's first.",
    )
    p.add_argument(
        "task",
        nargs="?",
        type=functools.partial(
            registered_task,
            command="bounds",
            why="plays the registered tasks' scripted policies; on a task class, sili rollout "
            "TASK --policy random (or still) plays the two that need no knowledge of it",
        ),
        help="task name or gymnasium id, e.g. circle-3",
    )
    p.add_argument(
        "--all", action="store_true", help="every registered task version (current and earlier)"
    )
    add_task_args(p, only="; one TASK, not --all; with --write only the task's defaults")
    slow = ", ".join(f"{t}: {n}" for t, n in TASK_INTERACTIONS.items())
    p.add_argument(
        "--interactions",
        help=f"interactions per policy, shared by the games (default {DEFAULT_INTERACTIONS}; "
        f"{slow})",
    )
    p.add_argument(
        "--games",
        help="repeated games per policy, seeds SEED, SEED+1, ..., starting from each strategy "
        f"in turn (default: the smallest multiple of the number of strategies >= {DEFAULT_GAMES},"
        " fewer if the interactions are few)",
    )
    p.add_argument(
        "--seed",
        type=seed,
        default=DEFAULT_SEED,
        help=f"first game's seed (default {DEFAULT_SEED})",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument(
        "--write",
        nargs="?",
        type=path_arg,
        const=str(BOUNDS_FILE),
        metavar="FILE",
        help="also store the bounds (keyed by gymnasium id) in FILE, default the packaged "
        "bounds file `sili plot` reads (only at the task's default arguments; the packaged "
        "file only at the default counts and seed)",
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sili_robots.bounds import (
        BOUNDS_FILE,
        check_counts,
        check_game_seeds,
        check_games,
        compute_bounds,
        default_games,
        default_interactions,
        format_table,
        read_bounds_file,
        write_bounds_file,
    )
    from sili_robots.errors import MAX_SEED
    from sili_robots.tasks import task_spec
    from sili_robots.tasks.registry import all_versions

    if args.all == (args.task is not None):
        took = ""  # `--write circle-3`: the optional FILE took the task's name
        if args.task is None and args.write and Path(args.write) != BOUNDS_FILE:
            took = f" (--write took '{args.write}' as its FILE: give TASK before --write)"
        raise ConfigError(f"give either a TASK (e.g. circle-3) or --all, not both or neither{took}")
    if args.write:  # before minutes of games, not after
        read_bounds_file(writable_file(Path(args.write), "--write"))
    specs = all_versions() if args.all else [task_spec(args.task)]
    env_kwargs = _task_arguments(args, specs)
    if args.games is not None:
        check_games(args.games)  # the user's own count, whatever the interactions
    for spec in specs:  # the counts and the games' seeds checked before anything runs
        n = args.interactions or default_interactions(spec.name)
        try:
            games = check_counts(n, args.games)[1]
        except ConfigError as err:
            if args.interactions is not None:
                raise
            raise ConfigError(f"{err} ({spec.name}'s default); give --interactions") from None
        if args.games is None and args.seed + int(n) // 2 - 1 > MAX_SEED:  # (games <= n / 2)
            games = default_games(spec.name, n)  # its own: a multiple of its strategies
        check_game_seeds(args.seed, games, args.games is not None)
    if args.write:
        _check_packaged_counts(args, specs)
    for spec in specs:
        result = compute_bounds(spec.gym_id, args.interactions, args.seed, args.games, env_kwargs)
        if args.json:
            keys = ("task", "task_id", "task_args", "interactions", "games", "seed", "bounds")
            print(json.dumps({k: result[k] for k in keys if k in result}), flush=True)
        else:
            print(format_table(result), flush=True)
        if args.write:  # as each task ends: a stop or a failure keeps the tasks done
            written = write_bounds_file([result], Path(args.write), _command(args))
    if args.write:  # a note: stdout is the results alone (one JSON line per task with --json)
        print(f"wrote {written}", file=sys.stderr)
    return 0


def _command(args: argparse.Namespace) -> str:
    """The command that wrote a bounds file, as its record (each task's counts are also in its
    entry); the packaged file's, at the default counts, is ``WRITE_COMMAND``."""
    import shlex

    from sili_robots.bounds import BOUNDS_FILE, DEFAULT_SEED, WRITE_COMMAND

    if Path(args.write).resolve() == BOUNDS_FILE:
        return WRITE_COMMAND
    words = ["sili", "bounds", "--all" if args.all else args.task]
    for option, value in (("interactions", args.interactions), ("games", args.games)):
        if value is not None:
            words += [f"--{option}", str(value)]
    if args.seed != DEFAULT_SEED:
        words += ["--seed", str(args.seed)]
    return shlex.join([*words, "--write", str(args.write)])


def _task_arguments(args: argparse.Namespace, specs: list) -> dict:
    """``--controller`` and ``--env-kwarg`` for one task, checked by building it once; refused
    with ``--all`` (tasks take different arguments) and with ``--write`` when they build other
    dynamics than the version's default (a bounds file keeps each version at its defaults)."""
    from sili_robots.build import check_task_builds
    from sili_robots.tasks.registry import other_task_arguments

    env_kwargs = task_arguments_given(args)
    if not env_kwargs:
        return env_kwargs
    if args.all:
        raise ConfigError("--controller and --env-kwarg apply to one TASK, not to --all")
    (spec,) = specs
    check_task_builds(spec.name, env_kwargs, "--controller, --env-kwarg")
    other = other_task_arguments(spec.gym_id, env_kwargs)
    if args.write and other:
        given = ", ".join(f"{k}={v!r}" for k, v in other.items())
        raise ConfigError(
            f"--write stores each task version at its default arguments, not {given}; print "
            "the bounds with other ones without it"
        )
    return env_kwargs


def _check_packaged_counts(args: argparse.Namespace, specs: list) -> None:
    """The packaged file holds every task at the default counts, the lines `sili plot` draws;
    an estimate at other counts (a count given equal to a task's default is the default) goes
    to a file of its own."""
    from sili_robots.bounds import (
        BOUNDS_FILE,
        DEFAULT_SEED,
        check_counts,
        default_games,
        default_interactions,
    )

    if Path(args.write).resolve() != BOUNDS_FILE:
        return
    given = []
    counts = [(s.name, args.interactions or default_interactions(s.name)) for s in specs]
    if args.interactions is not None and any(
        check_counts(n)[0] != default_interactions(t) for t, n in counts
    ):
        given.append(f"--interactions {args.interactions}")
    if args.games is not None and any(
        check_counts(n, args.games)[1] != default_games(t, n) for t, n in counts
    ):
        given.append(f"--games {args.games}")
    if args.seed != DEFAULT_SEED:
        given.append(f"--seed {args.seed}")
    if given:
        raise ConfigError(
            f"the packaged bounds ({BOUNDS_FILE}) are measured at the default counts, which "
            f"`sili plot` draws; with {', '.join(given)} give --write FILE of your own"
        )
