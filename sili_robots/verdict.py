"""One line a newcomer understands: did the run hold the opponent, and what did it earn, next
to what standing still and the scripted references earn on the same task version."""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

import pandas as pd

from sili_robots.bounds import stored_bounds
from sili_robots.errors import ConfigError, check_count
from sili_robots.labels import METHOD_NAMES
from sili_robots.metrics import HOLDING, METRICS, kept, kept_fraction, run_metrics
from sili_robots.runs import MACHINE_SETTINGS, RunConfig, read_config, run_differences
from sili_robots.tasks.registry import other_task_arguments, task_spec


def _rows(run_dir: Path) -> pd.DataFrame:
    """The run's rows, from ``metrics.csv`` or a collection's gzipped copy."""
    rows = run_metrics(run_dir)
    if rows is None:
        raise ConfigError(f"{run_dir} has no {METRICS} (nor its gzipped copy): it logged nothing")
    if rows.empty:
        raise ConfigError(f"{run_dir} has logged no interaction yet")
    return rows


def _last(run_dir: Path, window: int) -> pd.DataFrame:
    return _rows(run_dir).tail(check_count("window", window))


def _share(stability: float) -> str:
    """``stability`` as a percentage that a miss never rounds up to ``HOLDING`` (89.8%, not
    90% next to "did not hold")."""
    if stability >= HOLDING:
        return f"{stability:.0%}"
    for decimals in range(6):  # as few as tell it from HOLDING (449 of 499: 89.98%)
        text = f"{stability:.{decimals}%}"
        if float(text[:-1]) < 100 * HOLDING:
            return text
    return f"below {HOLDING:.0%}"


def random_only(cfg: RunConfig, interactions: int) -> str:
    """'' unless every one of a run's ``interactions`` was one of the uniform random actions
    SAC starts with (its first updates come after the last of them): then, that."""
    random = cfg.agent.sac.random_interactions
    if interactions > random:
        return ""
    played = f"all its {interactions} interactions were"
    if interactions == 1:
        played = "its one interaction was"
    return f"{played} random actions (sac.random_interactions={random})"


#: said where a task version has no stored references (a user's task, other task arguments)
NO_REFERENCE = "no references are stored for this task and its arguments: reward not judged"


def _no_reference(cfg: RunConfig) -> str:
    """``NO_REFERENCE``, and on a registered task the command that measures them."""
    try:
        name = task_spec(str(cfg.task_id)).name
    except ConfigError:  # a user's task: sili bounds plays the registered ones
        return NO_REFERENCE
    command = ["sili", "bounds", name]
    for k, v in other_task_arguments(cfg.task_id, cfg.env_kwargs).items():
        command += (
            ["--controller", v] if k == "controller" else ["--env-kwarg", f"{k}={json.dumps(v)}"]
        )
    return f"{NO_REFERENCE}; `{shlex.join(command)}` measures them"


def _references(cfg: RunConfig) -> dict[str, dict[str, float]]:
    """The scripted references of the run's task version, stored for its default arguments
    (none for a run given others, e.g. another controller; the default ones named are fine)."""
    return {} if other_task_arguments(cfg.task_id, cfg.env_kwargs) else stored_bounds(cfg.task_id)


def held(run_dir: Path, window: int = 50) -> bool:
    """Whether the opponent kept its strategy in at least 90% of the run's last ``window``
    interactions (a run shorter than that has not shown it)."""
    return _held(_last(run_dir, window), window)


def _held(tail: pd.DataFrame, window: int) -> bool:
    stability = kept_fraction(tail)
    return len(tail) == window and stability is not None and stability >= HOLDING


def worked(run_dir: Path, window: int = 50) -> bool:
    """Held the opponent and earned more per interaction than standing still: a run can hold by
    parking away from the goal, which shows stability but not the method's trade-off."""
    return _worked(_last(run_dir, window), _references(read_config(run_dir)).get("still"), window)


def _worked(tail: pd.DataFrame, still: dict[str, float] | None, window: int) -> bool:
    beat_still = still is None or float(tail["task_reward"].mean()) > still["task_reward"]
    return _held(tail, window) and beat_still


def verdict(run_dir: Path, window: int = 50) -> str:
    """E.g. "SILI held the opponent (kept its strategy in 96% of its last 50 interactions;
    standing still: 0%) and earned -8.1 per interaction (standing still: -50.0, the scripted
    stabilizing policy that sees z: -4.0)"."""
    cfg = read_config(run_dir)
    rows = _rows(run_dir)
    tail = rows.tail(check_count("window", window))
    stability = kept_fraction(tail)
    reward = float(tail["task_reward"].mean())
    bounds = _references(cfg)
    still, stab = bounds.get("still"), bounds.get("stabilizing")
    name = METHOD_NAMES.get(cfg.method, cfg.method)
    if len(tail) < window or stability is None:  # its first interactions say little
        ran = f"{len(tail)} interaction" + ("s" if len(tail) != 1 else "")
        line = f"{name} ran {ran}, too few to tell whether it holds the opponent"
        line += f" (the verdict reads the last {window})"
        if stability is not None:  # the game's first interaction has no strategy to keep
            line += f": the opponent kept its strategy in {stability:.0%} of those after the first"
            if still:
                line += f" (standing still: {still['stability']:.0%})"
    else:
        judged = int(kept(tail).notna().sum())  # a game's first interaction keeps nothing
        kept_text = f"kept its strategy in {_share(stability)} of its last {judged} interactions"
        if stability < HOLDING:
            kept_text += f", {HOLDING:.0%} needed"
        if still:
            kept_text += f"; standing still: {still['stability']:.0%}"
        outcome = "held" if stability >= HOLDING else "did not hold"
        line = f"{name} {outcome} the opponent ({kept_text})"
    line += f" and earned {reward:.1f} per interaction"
    refs = []
    if still:
        refs.append(f"standing still: {still['task_reward']:.1f}")
    if stab:
        refs.append(f"the scripted stabilizing policy that sees z: {stab['task_reward']:.1f}")
    line += f" ({', '.join(refs) if refs else _no_reference(cfg)})"
    why = random_only(cfg, len(rows))
    return line + (f"; {why}: they say nothing of its policy" if why else "")


def across_seeds(run_dirs: list[Path], window: int = 50) -> tuple[str, Path]:
    """The line for runs of one method that differ in their seed, e.g. "SILI worked in 1 of 2
    seeds (held the opponent in 90% or more of its last 50 interactions and earned more than
    standing still's -50.0): seed 1 (100%, -25.9 per interaction); not seed 0 (0%, -17.1 per
    interaction)", and the run to look at further: the best-earning one that worked, else the
    first seed's."""
    if isinstance(run_dirs, str | Path) or not run_dirs:
        raise ConfigError(f"give a list of run directories to judge, got {run_dirs!r}")
    configs = sorted(((read_config(d), Path(d)) for d in run_dirs), key=lambda c: c[0].seed)
    runs = [(c.seed, d) for c, d in configs]
    cfg = configs[0][0]
    for other, run_dir in configs[1:]:
        differ = _settings_that_differ(cfg, other)
        if differ:
            named = [f"{k} ({a!r} vs {b!r})" for k, a, b in differ[:4]]
            more = f" and {len(differ) - 4} more" if len(differ) > 4 else ""
            raise ConfigError(
                f"{run_dir} is not another seed of {runs[0][1]}: {', '.join(named)}{more} differ "
                "(runs judged together differ only in the seed and in settings chosen per machine: "
                f"{', '.join(MACHINE_SETTINGS)})"
            )
    seeds = [seed for seed, _ in runs]
    if len(set(seeds)) < len(seeds):
        raise ConfigError(f"seeds {seeds}: runs judged together are one run per seed")
    still = _references(cfg).get("still")
    judged = []  # (worked, reward, what to print, run)
    for seed, run_dir in runs:
        tail = _last(run_dir, window)
        reward = float(tail["task_reward"].mean())
        stability = kept_fraction(tail)
        said = f"seed {seed} ({'-' if stability is None else _share(stability)}, "
        said += f"{reward:.1f} per interaction"
        said += f"; {len(tail)} interactions, too few to tell)" if len(tail) < window else ")"
        judged.append((_worked(tail, still, window), reward, said, run_dir))
    good = [j for j in judged if j[0]]
    rule = f"held the opponent in {HOLDING:.0%} or more of its last {window} interactions"
    rule += (
        f" and earned more than standing still's {still['task_reward']:.1f}"
        if still
        else f"; {_no_reference(cfg)}"
    )
    name = METHOD_NAMES.get(cfg.method, cfg.method)
    line = f"{name} worked in {len(good)} of {len(runs)} seeds ({rule}): "
    parts = [", ".join(j[2] for j in good)] if good else []
    if len(good) < len(judged):
        parts.append("not " + ", ".join(j[2] for j in judged if not j[0]))
    best = max(good, key=lambda j: j[1])[3] if good else runs[0][1]
    return line + "; ".join(parts), best


#: ``python -m sili_robots.verdict``'s exit status when no run worked (1 is a failure of its own)
NONE_WORKED = 3


def _settings_that_differ(a: RunConfig, b: RunConfig) -> list[tuple[str, Any, Any]]:
    """(dotted name, value in ``a``, in ``b``) of the settings two runs differ in, other than
    the seed and the per-machine settings; the top-level ones (task, method) first."""
    found = run_differences(a.to_dict(), b.to_dict(), {"seed", *MACHINE_SETTINGS})
    return sorted(found, key=lambda d: d[0].count("."))


def main(argv: list[str] | None = None) -> int:
    """``python -m sili_robots.verdict RUN_DIR...``: the line across seeds on stderr, the run to
    look at further on stdout; exit status NONE_WORKED when no run worked, 2 on bad input."""
    import sys

    args = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in args):
        print(
            "usage: python -m sili_robots.verdict RUN_DIR [RUN_DIR ...]\n\n"
            "Judges seeds of one variant together: the line across them on stderr, the run to\n"
            f"look at further on stdout; exit {NONE_WORKED} when no seed worked, 2 on bad input."
        )
        return 0
    try:
        if not args:
            raise ConfigError("give the run directories to judge together")
        line, best = across_seeds([Path(a) for a in args])
    except ConfigError as err:
        print(f"python -m sili_robots.verdict: error: {err}", file=sys.stderr)
        return 2
    print(line, file=sys.stderr)
    print(best)
    return 0 if worked(best) else NONE_WORKED


if __name__ == "__main__":
    raise SystemExit(main())
