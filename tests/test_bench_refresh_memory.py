"""The refresh-memory benchmark runs end to end: its children's output is the JSON it parses."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_refresh_memory.py"


def test_short_run_prints_the_machine_and_a_table_row() -> None:
    result = subprocess.run(
        [sys.executable, str(SCRIPT), "--interactions", "250", "--configs", "continuous"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("machine: ")
    assert any(line.strip().startswith("250:") for line in lines)  # one measured row
    assert "latents max difference 0.0e+00" in result.stdout  # padding changes no latent
