"""Reference bounds: what the scripted policies score on each task version.

For every task version, each scripted kind that exists for it (``random``, ``still``,
``oracle``, ``stabilizing`` always; ``blind`` and ``tracking`` where they exist, see
``sili_robots.policies.scripted``) plays ``games`` repeated games (seeds ``seed``,
``seed + 1``, ...) that share ``interactions`` interactions between them; where a task has
finitely many strategies the games start from each in turn. Over every interaction but each
game's first (the one without a previous interaction to learn from or to compare with):

- ``task_reward``: the mean summed task reward per interaction;
- ``stability``: the fraction of interactions whose true strategy stayed (did not change at the
  boundary or within the interaction), as ``sili rollout`` reports it.

Starting the games from every strategy in turn averages exactly over the first strategy, which a
stabilizing policy then keeps (on Circle (8 Goals) a location on an axis costs 1.46 more per
interaction than a diagonal one; docs/tasks.md). Defaults: 1,000 interactions (Sawyer-Reach: 200),
seed 0, as many games as the smallest multiple of the number of strategies that is at least 10
(Circle (3 Goals): 12, Circle (8 Goals): 16, Circle (Continuous): 10 from drawn angles).

``sili bounds --all --write`` stores every registered version's bounds (current and earlier) in
the packaged ``sili_robots/tasks/bounds.json``, keyed by gymnasium id; ``sili plot`` draws them
from there, so plotting never runs a simulator.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sili_robots.agent.config import LARGEST_INT
from sili_robots.atomic import write_text
from sili_robots.errors import MAX_SEED, ConfigError, check_seed
from sili_robots.policies.scripted import KIND_DESCRIPTIONS, available_kinds, scripted_policy
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task, task_spec
from sili_robots.tasks.registry import title_arguments

BOUND_KINDS = ("random", "still", "oracle", "stabilizing", "blind", "tracking")
DEFAULT_INTERACTIONS = 1000
#: tasks whose simulator is slow get fewer interactions by default
TASK_INTERACTIONS = {"sawyer-reach": 200}
DEFAULT_GAMES = 10
DEFAULT_SEED = 0
BOUNDS_FILE = Path(__file__).resolve().parent / "tasks" / "bounds.json"
#: how the packaged file was made (recorded in the file itself)
WRITE_COMMAND = "sili bounds --all --write"


def default_interactions(task: str) -> int:
    return TASK_INTERACTIONS.get(task_spec(task).family, DEFAULT_INTERACTIONS)


def check_games(games: Any) -> int:
    """A count of games as an integer >= 1, or ConfigError naming it."""
    g = _integer(games)
    if g is None or not 1 <= g <= LARGEST_INT:
        raise ConfigError(f"--games must be an integer in [1, {LARGEST_INT}], got {games!r}")
    return g


def check_game_seeds(seed: int, games: int, games_given: bool = True) -> None:
    """ConfigError unless the ``games`` games' seeds (``seed``, ``seed + 1``, ...) are seeds."""
    if seed + games - 1 > MAX_SEED:
        fewer = "fewer --games" if games_given else f"--games {MAX_SEED - seed + 1} or fewer"
        raise ConfigError(
            f"--seed {seed} gives {games} games the seeds {seed} to {seed + games - 1}, past the "
            f"largest seed {MAX_SEED}: give --seed {MAX_SEED - games + 1} or lower, or {fewer}"
        )


def check_counts(interactions: Any, games: Any = None, strategies: int = 1) -> tuple[int, int]:
    """(interactions, games) as integers: at least two interactions per game (a game's first is
    not counted). ``games=None`` takes the smallest multiple of ``strategies`` (how many first
    strategies the games cycle through) that is at least ``DEFAULT_GAMES``, fewer if the
    interactions are few."""
    n = _integer(interactions)
    if n is None or not 2 <= n <= LARGEST_INT:
        raise ConfigError(
            f"--interactions must be an integer in [2, {LARGEST_INT}] (a game's first "
            f"interaction is not counted), got {interactions!r}"
        )
    if games is None:
        balanced = strategies * -(-DEFAULT_GAMES // strategies)
        while balanced > strategies and 2 * balanced > n:
            balanced -= strategies
        return n, min(balanced, n // 2)
    g = check_games(games)
    if n < 2 * g:
        raise ConfigError(
            f"--interactions must be >= {2 * g} for {g} games (two per game: a game's first "
            f"interaction is not counted), got {n}"
        )
    return n, g


def _integer(value: Any) -> int | None:
    try:
        return int(str(value))
    except ValueError:
        return None


def counts_for(env: Any, task: str, interactions: Any, games: Any) -> tuple[int, int]:
    """(interactions, games) of ``task``'s bounds on its instance ``env``: its defaults where
    None (the games cycle through its first strategies, ``check_counts``)."""
    choices = env.unwrapped.strategy_choices()
    asked = default_interactions(task) if interactions is None else interactions
    return check_counts(asked, games, len(choices) if choices else 1)


def default_games(task: str, interactions: Any = None) -> int:
    """How many games ``task``'s bounds play by default (at ``interactions``)."""
    env = make_task(task)
    try:
        return counts_for(env, task, interactions, None)[1]
    finally:
        env.close()


def compute_bounds(
    task: str,
    interactions: int | None = None,
    seed: int = DEFAULT_SEED,
    games: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """``{"task", "task_id", "task_args", "interactions", "games", "seed", "bounds": {kind:
    {task_reward, stability}}}`` for one task version (a CLI name or a gymnasium id), built
    with ``env_kwargs`` (e.g. another controller: the references of an ablation)."""
    spec, seed = task_spec(task), check_seed(seed)
    env_kwargs = dict(env_kwargs or {})
    env = make_task(spec.gym_id, **env_kwargs)
    try:
        choices = env.unwrapped.strategy_choices()
        n, g = counts_for(env, task, interactions, games)
        check_game_seeds(seed, g, games is not None)
        lengths = [n // g + (1 if i < n % g else 0) for i in range(g)]
        kinds = [k for k in BOUND_KINDS if k in available_kinds(env)]
        bounds = {}
        for kind in kinds:
            rewards: list[float] = []
            stayed: list[bool] = []
            for i, length in enumerate(lengths):
                policy = scripted_policy(env, kind)
                first = {"strategy": choices[i % len(choices)]} if choices else None
                summary = run_interactions(env, policy, length, seed + i, options=first)[1:]
                rewards += [s.task_reward for s in summary]
                stayed += [not s.strategy_changed for s in summary]
            bounds[kind] = {
                "task_reward": round(float(np.mean(rewards)), 4),
                "stability": round(float(np.mean(stayed)), 4),
            }
    finally:
        env.close()
    return {
        "task": spec.name,
        "task_id": spec.gym_id,
        **({"task_args": env_kwargs} if env_kwargs else {}),
        "interactions": n,
        "games": g,
        "seed": seed,
        "bounds": bounds,
    }


def format_table(result: dict[str, Any]) -> str:
    """The bounds of one task as an aligned text table."""
    named = title_arguments(result["task_id"], result.get("task_args", {}))
    args = "".join(f", {k}={v!r}" for k, v in named.items())
    lines = [
        f"{result['task']} ({result['task_id']}{args}): {result['interactions']} interactions in "
        f"{result['games']} game{'s' if result['games'] > 1 else ''} from seed {result['seed']} "
        "(each game's first not counted)",
        f"  {'policy':<12} {'task reward':>12} {'stability':>10}  what it is",
    ]
    for kind, b in result["bounds"].items():
        lines.append(
            f"  {kind:<12} {b['task_reward']:>12.2f} {b['stability']:>10.2f}  "
            f"{KIND_DESCRIPTIONS[kind]}"
        )
    return "\n".join(lines)


def read_bounds_file(path: Path = BOUNDS_FILE) -> dict[str, Any]:
    """The stored bounds file (``{"command", "tasks": {gym_id: result}}``); empty if none."""
    path = Path(path)
    if not path.is_file():
        return {"command": WRITE_COMMAND, "tasks": {}}
    try:
        data = json.loads(path.read_text())
    except ValueError as err:
        data, problem = None, f"not JSON: {err}"
    else:
        problem = "no object of tasks"
    if not isinstance(data, dict) or not isinstance(data.get("tasks"), dict):
        raise ConfigError(
            f"{path} is not a bounds file ({problem}); give --write a new file or one that "
            "sili bounds wrote"
        )
    return data


def write_bounds_file(
    results: list[dict[str, Any]], path: Path = BOUNDS_FILE, command: str = WRITE_COMMAND
) -> Path:
    """Add (or replace) ``results`` in the bounds file, keyed by gymnasium id; ``command``: the
    last command that wrote it."""
    data = read_bounds_file(path)
    data["command"] = command
    for result in results:
        data["tasks"][result["task_id"]] = result
    data["tasks"] = dict(sorted(data["tasks"].items()))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(data, indent=1) + "\n", shared=True)
    return path


def stored_bounds(task_id: str | None, path: Path = BOUNDS_FILE) -> dict[str, dict[str, float]]:
    """The stored bounds of one task version, ``{kind: {task_reward, stability}}``; ``{}`` when
    none are stored (an unknown or unmeasured version: nothing is drawn)."""
    if not isinstance(task_id, str) or not task_id:
        return {}
    entry = read_bounds_file(path)["tasks"].get(task_id)
    if entry is None:
        return {}
    return {
        kind: b
        for kind, b in entry["bounds"].items()
        if all(math.isfinite(float(b[m])) for m in ("task_reward", "stability"))
    }
