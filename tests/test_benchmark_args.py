"""The benchmark scripts refuse bad input in one line (exit 2) before any timing or training
starts, as the CLI does: a typo never costs minutes of measuring or a traceback."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from benchmark_scripts import BENCHMARKS, run_script

SCRIPTS = sorted(BENCHMARKS.glob("*.py"))


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_every_script_checks_its_numbers_and_reports_bad_input_in_one_line(script: Path) -> None:
    text = script.read_text()
    # a count of 0 divided by zero at the end of a benchmark; a bare int lets it through
    assert not re.search(r"type=int\b", text), "use positive_int / non_negative_int / seed"
    assert "one_line_errors(main, Path(__file__).name)" in text


@pytest.mark.parametrize(
    ("script", "args", "says"),
    [
        ("bench_sac_speed.py", ["--updates", "0"], "argument --updates: 0 is not allowed"),
        ("bench_sac_speed.py", ["--arm", "foo=1"], "--arm 'foo=1': unknown setting 'foo'"),
        ("bench_sweep_scaling.py", ["--runs", "0"], "argument --runs: 0 is not allowed"),
        ("bench_learning.py", ["--methods", "sili,bar"], "--methods bar: unknown method 'bar'"),
        ("bench_learning.py", ["--set", "foo=1"], "with --set foo=1: unknown setting 'foo'"),
        ("bench_learning.py", ["--methods", "sac,sili", "--latent", "x"], "with --latent x:"),
        (
            "bench_learning.py",
            ["--latent", "continuous", "--set", "latent=discrete"],
            "give one of --latent and --set latent, not both",
        ),
        ("bench_preview.py", ["--tasks", "nope"], "invalid choice: 'nope'"),
        ("latent_filter_usage.py", ["/absent"], "/absent does not exist"),
        ("circle_slip_cost.py", ["/absent", "--eps", "nan"], "filter.eps must be in [0, 0.99"),
        ("circle_slip_cost.py", ["/absent", "--noise", "-1"], "filter.noise must be >= 0, got -1"),
    ],
)
def test_bad_input_exits_2_before_any_work(
    script: str, args: list[str], says: str, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    extra = ["--out", str(out)] if script == "bench_learning.py" else []
    result = run_script(script.removesuffix(".py"), *args, *extra)  # a traceback: raised
    assert result.returncode == 2, result.stderr
    assert says in result.stderr
    assert not out.exists()  # no run was started


def test_a_browser_that_will_not_start_is_one_line_as_in_sili_preview() -> None:
    import os

    result = subprocess.run(
        [sys.executable, str(BENCHMARKS / "bench_preview.py"), "--tasks", "circle-3"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "SILI_CHROMIUM": "/bin/false"},  # exits at once
    )
    assert result.returncode == 1, result.stderr
    assert result.stderr.endswith(
        "bench_preview.py: error: Chromium closed its DevTools pipe (/bin/false)\n"
    )
    assert "Traceback" not in result.stderr
