"""The grid's per-task tables are rebuilt from the committed results alone: a row per method
with each seed's last-100 task reward, and equal wall times printed once."""

from __future__ import annotations

from pathlib import Path

from benchmark_scripts import ScriptRun, load_script, run_script

ROOT = Path(__file__).resolve().parents[1]


def test_tables_come_from_the_committed_collection() -> None:
    result = run_script("grid_tables", str(ROOT / "results" / "paper-grid"), "--tasks", "circle-3",
                        "driving")  # fmt: skip
    assert result.returncode == 0, result.stderr
    out = result.stdout
    circle, driving = (
        [line.split(" | ")[0].lstrip("| ") for line in table.splitlines() if line.startswith("| ")]
        for table in out.split("**driving**")
    )
    circle_lines = out.split("**driving**")[0].splitlines()
    rows = {line.split(" | ")[0].lstrip("| "): line for line in circle_lines}
    assert (
        "-16.93, -15.86, -8.32 | -13.70 | 0.79" in rows["SILI, package profile, the task's default"]
    )
    assert "| 16 min |" in rows["SILI, paper profile"]  # all three seeds took 16 min: no "16-16"
    assert "circle-8" not in out
    # the paper's order, runs of other budgets and seeds named so, the b sweep last and by b
    assert circle[1:] == [
        "SILI, package profile, the task's default", "SILI, paper profile", "Oracle", "LILI", "SAC",
        "Stable (1,000)", "SMiRL (1,000)",
        *(f"SILI b={b} (1,000, seeds 0-4)" for b in ("0", "0.2", "0.4", "0.6", "0.8", "1")),
    ]  # fmt: skip
    # Driving's SILI is the paper profile (the claims' SILI there)
    assert driving[1:3] == [
        "SILI, package profile (seeds 0-4)",
        "SILI, paper profile, the task's default (seeds 0-4)",
    ]


def test_tasks_without_runs_are_said_not_skipped_in_silence() -> None:
    collection = str(ROOT / "results" / "main-r-avx2")  # Circle (3 Goals) runs only

    def tables(*tasks: str) -> ScriptRun:
        return run_script("grid_tables", collection, "--tasks", *tasks)  # a traceback: raised

    none = tables("driving")
    assert none.returncode == 2 and none.stdout == ""
    assert "has no runs of driving; its tasks: circle-3" in none.stderr
    some = tables("circle-3", "driving")
    assert some.returncode == 0 and "**circle-3**" in some.stdout
    assert "no runs of driving in" in some.stderr


def test_a_row_names_its_profile_budget_and_seeds_only_where_they_differ() -> None:
    label = load_script("grid_tables")._label
    sawyer = {"b_sweep": False, "method": "sili", "profile": "package", "beta": 0.5}
    sawyer |= {"logged": 1500, "full": 1500, "profiles": {"package"}}
    # SILI in one profile on the task: its name alone; two seeds are listed, three in a row
    # are a range, the budget shown where it is not the table's
    assert label("sawyer-reach", **sawyer, seeds=[0, 1, 2]) == "SILI"
    assert label("sawyer-reach", **sawyer, seeds=[0, 1]) == "SILI (seeds 0, 1)"
    b_sweep = {**sawyer, "b_sweep": True, "beta": 0.2, "logged": 1000, "full": 2000}
    assert label("circle-3", **b_sweep, seeds=[0, 1, 2, 3]) == "SILI b=0.2 (1,000, seeds 0-3)"
    lili = {**sawyer, "method": "lili", "beta": 0.0}
    assert label("circle-3", **lili, seeds=[0, 2, 4]) == "LILI (seeds 0, 2, 4)"
