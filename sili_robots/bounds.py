"""Reference bounds: what the scripted policies score on each task version.

For every task version, each scripted kind that exists for it (``random``, ``still``,
``oracle``, ``stabilizing`` always; ``blind`` and ``tracking`` where they exist, see
``sili_robots.policies.scripted``) is played for ``interactions`` interactions from ``seed``:

- ``task_reward``: the mean over interactions of the summed task reward;
- ``stability``: the fraction of interactions 2..N whose true strategy stayed (did not change
  at the boundary or within the interaction), as ``sili rollout`` reports it.

``sili bounds --all --write`` stores every registered version's bounds (current and earlier
versions, 100 interactions from seed 0) in the packaged ``sili_robots/tasks/bounds.json``, keyed by
gymnasium id; ``sili plot`` draws them from there, so plotting never runs a simulator.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sili_robots.errors import ConfigError
from sili_robots.policies.scripted import KIND_DESCRIPTIONS, available_kinds, scripted_policy
from sili_robots.rollout import run_interactions
from sili_robots.tasks import make_task, task_spec

BOUND_KINDS = ("random", "still", "oracle", "stabilizing", "blind", "tracking")
DEFAULT_INTERACTIONS = 100
DEFAULT_SEED = 0
BOUNDS_FILE = Path(__file__).resolve().parent / "tasks" / "bounds.json"
#: how the packaged file was made (shown by ``sili bounds`` and in the file itself)
WRITE_COMMAND = "sili bounds --all --write"


def check_interactions(n: Any) -> int:
    """At least two interactions: stability compares consecutive ones."""
    try:
        value = int(str(n))
    except ValueError:
        value = None
    if value is None or value < 2:
        raise ConfigError(
            f"--interactions must be an integer >= 2 (stability compares consecutive "
            f"interactions), got {n!r}"
        )
    return value


def compute_bounds(
    task: str, interactions: int = DEFAULT_INTERACTIONS, seed: int = DEFAULT_SEED
) -> dict[str, Any]:
    """``{"task", "task_id", "interactions", "seed", "bounds": {kind: {task_reward,
    stability}}}`` for one task version (a CLI name or a gymnasium id)."""
    spec = task_spec(task)
    n = check_interactions(interactions)
    env = make_task(spec.gym_id)
    try:
        kinds = [k for k in BOUND_KINDS if k in available_kinds(env)]
        bounds = {}
        for kind in kinds:
            summary = run_interactions(env, scripted_policy(env, kind), n, seed=seed)
            bounds[kind] = {
                "task_reward": round(float(np.mean([s.task_reward for s in summary])), 4),
                "stability": round(
                    float(np.mean([not s.strategy_changed for s in summary[1:]])), 4
                ),
            }
    finally:
        env.close()
    return {
        "task": spec.name,
        "task_id": spec.gym_id,
        "interactions": n,
        "seed": int(seed),
        "bounds": bounds,
    }


def format_table(result: dict[str, Any]) -> str:
    """The bounds of one task as an aligned text table."""
    lines = [
        f"{result['task']} ({result['task_id']}): {result['interactions']} interactions, "
        f"seed {result['seed']}",
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
    return json.loads(path.read_text())


def write_bounds_file(results: list[dict[str, Any]], path: Path = BOUNDS_FILE) -> Path:
    """Add (or replace) ``results`` in the bounds file, keyed by gymnasium id."""
    data = read_bounds_file(path)
    for result in results:
        data["tasks"][result["task_id"]] = result
    data["tasks"] = dict(sorted(data["tasks"].items()))
    path = Path(path)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    tmp.replace(path)
    return path


def stored_bounds(task_id: str, path: Path = BOUNDS_FILE) -> dict[str, dict[str, float]]:
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
