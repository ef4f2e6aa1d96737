"""The learning benchmark's table mode refuses folders that hold no runs, with a clear error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_learning.py"


def run_script(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120
    )


def test_from_runs_without_runs_exits_2_and_says_why(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()  # a sweep folder: its runs sit one level down
    result = run_script("--from-runs", str(tmp_path))
    assert result.returncode == 2
    assert "no finished runs" in result.stderr and "runs/ folder" in result.stderr
    assert "Traceback" not in result.stderr


def test_from_runs_missing_folder_exits_2(tmp_path: Path) -> None:
    result = run_script("--from-runs", str(tmp_path / "absent"))
    assert result.returncode == 2
    assert "not a folder" in result.stderr
    assert "Traceback" not in result.stderr
