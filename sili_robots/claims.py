"""The paper's claims, decided from a results collection of the paper grid (``sili claims``).

Every number is a run's mean over its last ``WINDOW`` interactions, then the mean over seeds.
SILI on a task is ``--method sili`` there: the grid's runs in the task's registered profile
(``TaskSpec.sili_profile``; the paper's on Driving, decided by the last rule below).
Task rewards are compared as a *score*: 0 = standing still, 1 = the task's scripted oracle (its
reference bounds, ``sili bounds``), so one margin means the same on every task. A claim is
decided only from runs at the grid's full budget for their block (``paper_grid.py``); with any
of its runs missing it is "not measured yet" and says how many it has, and so is a claim decided
by scores on a task version without reference bounds. A run is the grid's by its name, its
budget and its task's registered dynamics: runs with other task arguments (an ablation's
``--env-kwarg``) are left out and named. Agent settings (``--set``) do not change a run's name:
keep such sweeps out of the folder the claims read.

Rules (the margins are the table's, fixed before the grid ran):

- *SILI comparable to Oracle*: SILI's score at least Oracle's - 0.1 holds; at least - 0.25 holds
  in part.
- *SILI above LILI, SAC and SMiRL*: SILI's score beats a baseline's by more than 0.05, each
  compared over the same interactions (SMiRL runs half the budget: SILI's window at the same
  point). All three: holds; one or two: in part.
- *Stable stabilizes but ignores the task*: Stable's true stability >= 0.9 and its score below
  SILI's by more than 0.1: holds; one of the two: in part.
- *Driving: only SILI avoids all collisions*: collision rate (the share of interactions with a
  collision, -task reward), each method against SILI over the same interactions (Stable and
  SMiRL end at half the budget): at most 1% in every SILI seed and above 1% for every other
  method: holds; SILI's rate below every other method's: in part.
- *Speaker-Listener: SILI stabilizes by about interaction 250 and beats the baselines*: every
  seed's first 50-interaction window of true stability >= 0.9 starts by 350, and SILI is above
  every other method (the paper: "all other baselines ..., including Oracle"): holds; one of the
  two: in part.
- *The package default over the paper profile* (not a claim of the paper: the grid's choice of
  the default for ``--method sili``, on each task the paper profile runs on, over every seed
  the grid runs of both there: five on Driving, three elsewhere): the package profile's score
  above the paper profile's by more than 0.05 holds (the default stays); within 0.05 holds in
  part; below does not hold (the paper profile is the better default there).
- *b sweet spot 0.4-0.8* (Circle 3, 5 seeds per b, 1,000 interactions): the b with the best
  score lies in [0.4, 0.8] and beats b = 0 and b = 1 by more than 0.05: holds; the best b in
  the range alone: in part.

Claims of stabilizing (added after the grid ran, from the paper's text; true stability, no
score). "Stabilizes" is a mean true stability >= 0.9 over the seeds' last windows (a choice, as
for scores: one seed's lapse lowers the mean, it does not decide alone):

- *SILI stabilizes* (its figure's right column, every task): on every task holds; on some in part.
- *Circle (Continuous): SILI and Oracle stabilize*: both holds; one in part.
- *Circle (Unequal): only SILI stabilizes*: SILI does and none of Oracle, LILI, SAC and SMiRL
  does holds ("the other baselines ... greedily try to track"; Stable, rewarded for stability
  alone, is no such baseline); SILI does and some of them too, or none does, in part.
- *b >= 0.4 stabilizes* (the b figure's right panel): every b >= 0.4 stabilizes and every smaller
  b does not: holds; every b >= 0.4 stabilizes: in part.
- *SMiRL does not stabilize consistently* (the paper's limitations): SMiRL does not stabilize
  on more than half the tasks: holds; on some: in part.

A verdict "in part" names the part that does not hold.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache

import numpy as np
import pandas as pd

from sili_robots.bounds import stored_bounds
from sili_robots.metrics import HOLDING, first_stable
from sili_robots.paper_grid import SWEEP_BETAS, TASKS, Block, block
from sili_robots.tasks import task_spec

WINDOW = 100
COMPARABLE, COMPARABLE_PART = 0.1, 0.25
ABOVE = 0.05
STABLE_BY = 350
NO_COLLISIONS = 0.01
SWEET_SPOT = (0.4, 0.8)
STABILIZING_B = 0.4

HOLDS, PART, NO = "holds", "holds in part", "does not hold"


@dataclass(frozen=True)
class Claim:
    claim: str
    task: str
    measured: str
    verdict: str
    #: for a verdict in part: the part that does not hold
    short_of: str = ""


def run_finals(df: pd.DataFrame, upto: dict[str, int] | None = None) -> pd.DataFrame:
    """One row per run: identity, interactions logged, and its final-window task reward, true
    stability and score (``upto``: run -> the interaction count its window ends at)."""
    rows = []
    for run, g in df.groupby("run", sort=False):
        g = g.sort_values("interaction")
        n = len(g) if upto is None else min(len(g), upto.get(run, len(g)))
        tail = g.iloc[max(n - WINDOW, 0) : n]
        first = g.iloc[0]
        reward = float(tail["task_reward"].mean())
        rows.append(
            {
                "run": run,
                "task": first["task"],
                "method": first["method"],
                "profile": first.get("profile", "package"),
                "config_beta": float(first["config_beta"]),
                "seed": int(first["seed"]),
                "task_id": str(first["task_id"]),
                "task_args": "" if pd.isna(first.get("task_args")) else str(first["task_args"]),
                "logged": len(g),
                "task_reward": reward,
                "stability": float(tail["true_stability"].mean()),
                "score": score(reward, str(first["task_id"])),
                "first_stable": first_stable(g["true_stability"].to_numpy()),
            }
        )
    return pd.DataFrame(rows)


def score(task_reward: float, task_id: str) -> float:
    """0 = standing still, 1 = the scripted oracle (the task version's stored bounds)."""
    b = stored_bounds(task_id)
    if "still" not in b or "oracle" not in b:
        return float("nan")
    still, best = b["still"]["task_reward"], b["oracle"]["task_reward"]
    if best == still:  # no range to score in
        return float("nan")
    return (task_reward - still) / (best - still)


def _block_runs(finals: pd.DataFrame, b: Block, task: str, method: str) -> pd.DataFrame:
    """The block's runs of ``method`` on ``task`` that are in and at full budget: selected by the
    names the grid gives them, so no other run of the same method (another seed, latent kind,
    b or budget) is counted, and on the task's own dynamics (an ablation's task arguments, e.g.
    ``--env-kwarg``, keep the run's name but are not the grid's task)."""
    grids = finals.run.isin(grid_names(b, task, method)) & (finals.task_args == "")
    rows = finals[grids & (finals.logged == b.budget(task))]
    return rows.sort_values("seed")


@cache
def grid_names(b: Block, task: str, method: str) -> frozenset[str]:
    """The names the grid gives a block's runs of ``method`` on ``task`` (planning builds every
    run's config: once per block, task and method)."""
    from sili_robots.sweep.runner import plan

    planned = plan(b.specs((task,)))
    return frozenset(r.name for r in planned if r.config.method == method)


def _mean(rows: pd.DataFrame, col: str) -> float:
    return float(rows[col].mean())


def _reward_and_stability(rows: pd.DataFrame) -> str:
    return f"reward {_mean(rows, 'task_reward'):.2f}, stability {_mean(rows, 'stability'):.2f}"


#: how a claim's verdict begins while the grid's runs at its budget are missing
BELOW_BUDGET = "not measured yet (runs at the grid's budget"


def _missing(have: dict[str, pd.DataFrame], want: dict[str, int]) -> str | None:
    parts = [f"{m} {len(have[m])}/{n}" for m, n in want.items() if len(have[m]) != n]
    if not parts:
        return None
    return f"{BELOW_BUDGET}: {', '.join(parts)})"


#: each method's block in the grid (SILI: its task's registered profile, ``_sili_runs``)
METHOD_BLOCKS = {
    "SILI": "sili-oracle",
    "Oracle": "sili-oracle",
    "LILI": "lili-sac",
    "SAC": "lili-sac",
    "Stable": "stable-smirl",
    "SMiRL": "stable-smirl",
}


#: (method label, task) -> the grid's runs of it there
Runs = dict[tuple[str, str], pd.DataFrame]


def _method_runs(finals: pd.DataFrame, task: str, label: str) -> pd.DataFrame:
    """The grid's runs of a method (a ``METHOD_BLOCKS`` label) on ``task``."""
    if label == "SILI":
        return _sili_runs(finals, task)
    return _block_runs(finals, block(METHOD_BLOCKS[label]), task, label.lower())


def decide(finals: pd.DataFrame, df: pd.DataFrame) -> list[Claim]:
    """Every claim of the paper, in the table's order."""
    claims: list[Claim] = []
    n = len(block("sili-oracle").seeds)
    runs = {(m, task): _method_runs(finals, task, m) for m in METHOD_BLOCKS for task in TASKS}
    for task in TASKS:
        sili = runs["SILI", task]
        baselines = {m: runs[m, task] for m in ("LILI", "SAC", "SMiRL")}
        claims.append(_comparable(task, sili, runs["Oracle", task], n))
        claims.append(_above(task, sili, baselines, df, n))
        claims.append(_stable(task, sili, runs["Stable", task], df, n))
    claims.append(_driving(runs, df, n))
    claims.append(_speaker_listener(runs, df, n))
    claims.append(_sweet_spot(finals))
    claims.append(_stabilizing_b(finals))
    claims += _stabilizing(runs, n)
    for task in block("paper-profile").tasks:
        claims.append(_default_profile(task, finals))
    return [_only_in_part(_unscored(c, finals)) for c in claims]


def _only_in_part(claim: Claim) -> Claim:
    """``short_of`` is kept for a verdict in part alone (what falls short of holding)."""
    return claim if claim.verdict == PART else replace(claim, short_of="")


#: the claims on one task decided from task rewards or true stability alone, which need no
#: score (those on every task, ``ALL``, have no one task version to lack bounds)
UNSCORED_CLAIMS = (
    "only SILI avoids all collisions",
    "b >= 0.4 stabilizes",
    "SILI and Oracle stabilize",
    "only SILI stabilizes",
)
ALL = "all"


def _unscored(claim: Claim, finals: pd.DataFrame) -> Claim:
    """A claim on a task version without reference bounds is not measured, whatever its scores
    (NaN) would have decided."""
    if (
        claim.task == ALL
        or claim.claim in UNSCORED_CLAIMS
        or claim.verdict not in (HOLDS, PART, NO)
    ):
        return claim
    runs = finals[finals.task == claim.task]
    ids = sorted(runs.loc[runs.score.isna(), "task_id"].unique())
    if not ids:
        return claim
    bounds = f"no reference bounds for {', '.join(ids)}: `sili bounds --all --write`"
    return replace(claim, verdict=f"not measured yet ({bounds})")


#: the blocks that run SILI in each profile for the choice of the default
PROFILE_BLOCKS = {
    "package": ("sili-oracle", "default-seeds"),
    "paper": ("paper-profile", "paper-seeds"),
}


def _profile_runs(finals: pd.DataFrame, task: str, profile: str) -> tuple[pd.DataFrame, int]:
    """SILI's runs in ``profile`` on ``task`` over the blocks that run it, and how many the
    grid plans."""
    blocks = [block(name) for name in PROFILE_BLOCKS[profile]]
    blocks = [b for b in blocks if task in b.tasks]
    rows = pd.concat([_block_runs(finals, b, task, "sili") for b in blocks])
    return rows.sort_values("seed"), sum(len(b.seeds) for b in blocks)


def _sili_runs(finals: pd.DataFrame, task: str) -> pd.DataFrame:
    """The grid's runs of ``--method sili`` on ``task``, in its registered profile (three
    seeds, as every other method)."""
    profile = task_spec(task).sili_profile
    return _block_runs(finals, block(PROFILE_BLOCKS[profile][0]), task, "sili")


def _comparable(task: str, sili: pd.DataFrame, oracle: pd.DataFrame, n: int) -> Claim:
    name = "SILI comparable to Oracle"
    missing = _missing({"SILI": sili, "Oracle": oracle}, {"SILI": n, "Oracle": n})
    if missing:
        return Claim(name, task, "", missing)
    s, o = _mean(sili, "score"), _mean(oracle, "score")
    measured = (
        f"score SILI {s:.2f} ({_reward_and_stability(sili)}), "
        f"Oracle {o:.2f} ({_mean(oracle, 'task_reward'):.2f})"
    )
    verdict = HOLDS if s >= o - COMPARABLE else PART if s >= o - COMPARABLE_PART else NO
    return Claim(name, task, measured, verdict, f"more than {COMPARABLE:g} below Oracle")


def _same_window(sili: pd.DataFrame, other: pd.DataFrame, df: pd.DataFrame) -> float:
    """SILI's mean score over the window where ``other``'s runs end (they may be shorter)."""
    end = int(other["logged"].min())
    rows = df[df.run.isin(sili.run)]
    return _mean(run_finals(rows, {r: end for r in sili.run}), "score")


def _above(
    task: str,
    sili: pd.DataFrame,
    baselines: dict[str, pd.DataFrame],
    df: pd.DataFrame,
    n: int,
) -> Claim:
    name = "SILI above LILI, SAC and SMiRL"
    missing = _missing({"SILI": sili, **baselines}, {k: n for k in ("SILI", *baselines)})
    if missing:
        return Claim(name, task, "", missing)
    below, parts = [], []
    for label, rows in baselines.items():
        s, b = _same_window(sili, rows, df), _mean(rows, "score")
        if not s - b > ABOVE:
            below.append(label)
        parts.append(f"{label} {b:.2f} (SILI {s:.2f})")
    verdict = NO if len(below) == len(baselines) else PART if below else HOLDS
    short_of = f"not above {_listed(below)}"
    return Claim(name, task, "score " + ", ".join(parts), verdict, short_of)


def _listed(names: list[str], last: str = "or") -> str:
    """``a, b or c``, for the parts of a verdict."""
    return ", ".join(names[:-1]) + f" {last} " + names[-1] if len(names) > 1 else "".join(names)


def _too(names: list[str], verb: str) -> str:
    """``a and b stabilize too``, ``a stabilizes too``."""
    return f"{_listed(names, 'and')} {verb if len(names) > 1 else verb + 's'} too"


def _stable(task: str, sili: pd.DataFrame, stable: pd.DataFrame, df: pd.DataFrame, n: int) -> Claim:
    name = "Stable: stable, poor task reward"
    missing = _missing({"Stable": stable, "SILI": sili}, {"Stable": n, "SILI": n})
    if missing:
        return Claim(name, task, "", missing)
    st, sc, s = _mean(stable, "stability"), _mean(stable, "score"), _same_window(sili, stable, df)
    held, poor = st >= HOLDING, sc < s - COMPARABLE
    measured = f"Stable: stability {st:.2f}, score {sc:.2f} (SILI {s:.2f})"
    verdict = HOLDS if held and poor else PART if held or poor else NO
    short_of = "not stable" if poor else f"score not more than {COMPARABLE:g} below SILI's"
    return Claim(name, task, measured, verdict, short_of)


def _driving(grid_runs: Runs, df: pd.DataFrame, n: int) -> Claim:
    name, task = "only SILI avoids all collisions", "driving"
    runs = {m: grid_runs[m, task] for m in METHOD_BLOCKS}
    missing = _missing(runs, {k: n for k in runs})
    if missing:
        return Claim(name, task, "", missing)
    sili = runs.pop("SILI")
    rates, sili_rates, sili_worst = {}, {}, {}
    for label, rows in runs.items():  # each method against SILI over the same interactions
        end = int(rows["logged"].min())
        at_end = run_finals(df[df.run.isin(sili.run)], {r: end for r in sili.run})
        rates[label] = 0.0 - _mean(rows, "task_reward")
        sili_rates[label] = 0.0 - _mean(at_end, "task_reward")
        sili_worst[label] = float((0.0 - at_end["task_reward"]).max())
    final = 0.0 - _mean(sili, "task_reward")
    measured = f"collision rate SILI {final:.0%}; " + ", ".join(
        f"{k} {r:.0%} (SILI {sili_rates[k]:.0%})" for k, r in rates.items()
    )
    if all(sili_worst[k] <= NO_COLLISIONS < rates[k] for k in rates):
        verdict = HOLDS
    else:
        verdict = PART if all(sili_rates[k] < rates[k] for k in rates) else NO
    short_of = []
    if max(sili_worst.values()) > NO_COLLISIONS:
        short_of.append(f"a SILI seed collides in over {NO_COLLISIONS:.0%}")
    clean = [k for k in rates if rates[k] <= NO_COLLISIONS]
    if clean:
        short_of.append(f"at most {NO_COLLISIONS:.0%} for {_listed(clean, 'and')} too")
    return Claim(name, task, measured, verdict, "; ".join(short_of))


def _speaker_listener(runs: Runs, df: pd.DataFrame, n: int) -> Claim:
    name = "SILI stable by ~250, beats baselines"
    task = "speaker-listener"
    sili = runs["SILI", task]
    # every other method: "all other baselines ..., including Oracle"
    baselines = {m: runs[m, task] for m in METHOD_BLOCKS if m != "SILI"}
    above = _above(task, sili, baselines, df, n)
    if above.verdict.startswith("not measured"):
        return Claim(name, task, "", above.verdict)
    firsts = [None if pd.isna(f) else int(f) for f in sili["first_stable"]]
    early = all(f is not None and f <= STABLE_BY for f in firsts)
    ok = early + (above.verdict == HOLDS)
    firsts_text = ", ".join("never" if f is None else str(f) for f in firsts)
    measured = f"first stable at {firsts_text}; {above.measured}"
    short_of = above.short_of if early else f"not stable by {STABLE_BY} in every seed"
    return Claim(name, task, measured, HOLDS if ok == 2 else PART if ok else NO, short_of)


def _b_sweep(finals: pd.DataFrame) -> tuple[dict[float, pd.DataFrame], str | None]:
    """The b sweep's runs on Circle (3 Goals) per b, and what is missing of them."""
    b = block("b-sweep")
    rows = _block_runs(finals, b, "circle-3", "sili")
    per_b = {beta: rows[np.isclose(rows.config_beta, beta)] for beta in SWEEP_BETAS}
    have = {f"b={k:g}": v for k, v in per_b.items()}
    return per_b, _missing(have, {k: len(b.seeds) for k in have})


def _sweet_spot(finals: pd.DataFrame) -> Claim:
    name, task = "b sweet spot 0.4-0.8", "circle-3"
    per_b, missing = _b_sweep(finals)
    if missing:
        return Claim(name, task, "", missing)
    scores = {beta: _mean(r, "score") for beta, r in per_b.items()}
    best = max(scores, key=scores.__getitem__)
    in_range = SWEET_SPOT[0] <= best <= SWEET_SPOT[1]
    ends = min(SWEEP_BETAS), max(SWEEP_BETAS)
    separated = all(scores[best] - scores[e] > ABOVE for e in ends)
    measured = "score (stability) " + ", ".join(
        f"b={k:g} {v:.2f} ({_mean(per_b[k], 'stability'):.2f})" for k, v in scores.items()
    )
    verdict = HOLDS if in_range and separated else PART if in_range else NO
    short_of = f"b={best:g} not above both ends by more than {ABOVE:g}"
    return Claim(name, task, measured, verdict, short_of)


def _stabilizing_b(finals: pd.DataFrame) -> Claim:
    name, task = "b >= 0.4 stabilizes", "circle-3"
    per_b, missing = _b_sweep(finals)
    if missing:
        return Claim(name, task, "", missing)
    held = {beta: _mean(r, "stability") >= HOLDING for beta, r in per_b.items()}
    large = [beta for beta in SWEEP_BETAS if beta >= STABILIZING_B]
    measured = "true stability " + ", ".join(
        f"b={k:g} {_mean(r, 'stability'):.2f}" for k, r in per_b.items()
    )
    small_held = [f"b={k:g}" for k in SWEEP_BETAS if k < STABILIZING_B and held[k]]
    large_not = [f"b={k:g}" for k in large if not held[k]]
    verdict = NO if large_not else PART if small_held else HOLDS
    return Claim(name, task, measured, verdict, _too(small_held, "stabilize"))


def _stabilizes(rows: pd.DataFrame) -> bool:
    return _mean(rows, "stability") >= HOLDING


def _stabilizing(runs: Runs, n: int) -> list[Claim]:
    """The paper's claims of who stabilizes (true stability alone), each decided once all the
    runs it reads are in."""
    continuous, unequal = "circle-continuous", "circle-unequal"
    rules = (
        ("SILI stabilizes", ALL, {"SILI": TASKS}, _sili_everywhere),
        ("SILI and Oracle stabilize", continuous, {"SILI": (continuous,), "Oracle": (continuous,)},
         _sili_and_oracle),
        ("only SILI stabilizes", unequal, {m: (unequal,) for m in ("SILI", *UNEQUAL_OTHERS)},
         _only_sili),
        ("SMiRL does not stabilize consistently", ALL, {"SMiRL": TASKS}, _smirl_inconsistent),
    )  # fmt: skip
    claims = []
    for name, task, want, rule in rules:
        have = {
            f"{m} on {t}" if len(ts) > 1 else m: runs[m, t] for m, ts in want.items() for t in ts
        }
        missing = _missing(have, {k: n for k in have})
        claims.append(Claim(name, task, "", missing) if missing else rule(name, task, runs))
    return claims


#: the baselines that "greedily try to track" on Circle (Unequal); Stable, rewarded for
#: stability alone, is shown beside them, not counted
UNEQUAL_OTHERS = ("Oracle", "LILI", "SAC", "SMiRL")


def _stability_text(runs: Runs, task: str, labels: tuple[str, ...]) -> str:
    return ", ".join(f"{m} {_mean(runs[m, task], 'stability'):.2f}" for m in labels)


def _per_task_stability(runs: Runs, label: str) -> str:
    return ", ".join(f"{t} {_mean(runs[label, t], 'stability'):.2f}" for t in TASKS)


def _sili_everywhere(name: str, task: str, runs: Runs) -> Claim:
    not_held = [t for t in TASKS if not _stabilizes(runs["SILI", t])]
    verdict = NO if len(not_held) == len(TASKS) else PART if not_held else HOLDS
    measured = "true stability " + _per_task_stability(runs, "SILI")
    return Claim(name, task, measured, verdict, f"not on {_listed(not_held)}")


def _sili_and_oracle(name: str, task: str, runs: Runs) -> Claim:
    both = ("SILI", "Oracle")
    not_held = [m for m in both if not _stabilizes(runs[m, task])]
    verdict = NO if len(not_held) == 2 else PART if not_held else HOLDS
    measured = "true stability " + _stability_text(runs, task, both)
    return Claim(name, task, measured, verdict, f"{_listed(not_held)} does not")


def _only_sili(name: str, task: str, runs: Runs) -> Claim:
    sili = _stabilizes(runs["SILI", task])
    too = [m for m in UNEQUAL_OTHERS if _stabilizes(runs[m, task])]
    measured = "true stability " + _stability_text(runs, task, ("SILI", *UNEQUAL_OTHERS))
    if len(runs["Stable", task]):
        stable = _mean(runs["Stable", task], "stability")
        measured += f" (Stable {stable:.2f}: rewarded for stability alone, not counted)"
    verdict = HOLDS if sili and not too else PART if sili or not too else NO
    short_of = _too(too, "stabilize") if sili else "SILI does not stabilize"
    return Claim(name, task, measured, verdict, short_of)


def _smirl_inconsistent(name: str, task: str, runs: Runs) -> Claim:
    held = [t for t in TASKS if _stabilizes(runs["SMiRL", t])]
    not_held = len(TASKS) - len(held)
    verdict = HOLDS if not_held > len(TASKS) / 2 else PART if not_held else NO
    measured = "true stability (half the budget) " + _per_task_stability(runs, "SMiRL")
    return Claim(name, task, measured, verdict, f"stabilizes on {_listed(held)}")


def _default_profile(task: str, finals: pd.DataFrame) -> Claim:
    name = "package default over paper profile"
    package, n_package = _profile_runs(finals, task, "package")
    paper, n_paper = _profile_runs(finals, task, "paper")
    missing = _missing(
        {"package": package, "paper": paper}, {"package": n_package, "paper": n_paper}
    )
    if missing:
        return Claim(name, task, "", missing)
    s, p = _mean(package, "score"), _mean(paper, "score")
    measured = (  # more seeds than the other claims' SILI rows on Driving: said, not implied
        f"{n_package} seeds each: score package {s:.2f} ({_reward_and_stability(package)}), "
        f"paper {p:.2f} ({_reward_and_stability(paper)})"
    )
    verdict = HOLDS if s - p > ABOVE else PART if s - p >= -ABOVE else NO
    return Claim(name, task, measured, verdict, f"within {ABOVE:g}")


def claims_table(df: pd.DataFrame) -> list[Claim]:
    """The claims from a results table (``plot_data.load_results`` of a collection)."""
    return decide(run_finals(df), df)


def other_dynamics(df: pd.DataFrame) -> list[str]:
    """The runs no claim counts because they ran with other task arguments than their task's
    registered version (the grid runs none)."""
    if "task_args" not in df:  # a table from before task arguments were told apart
        return []
    return sorted(df.loc[df.task_args.fillna("") != "", "run"].unique())


def markdown(claims: list[Claim]) -> str:
    lines = [
        "| claim | task | measured (last 100 interactions, mean of seeds; SILI in parentheses: "
        "at the end of the other method's runs, half the budget for Stable and SMiRL) | verdict |"
    ]
    lines.append("|---|---|---|---|")
    for c in claims:
        verdict = f"**{c.verdict}**" if c.verdict in (HOLDS, NO, PART) else c.verdict
        if c.verdict == PART and c.short_of:
            verdict += f": {c.short_of}"
        lines.append(f"| {c.claim} | {c.task} | {c.measured} | {verdict} |")
    return "\n".join(lines) + "\n"
