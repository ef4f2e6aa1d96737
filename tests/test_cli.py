"""The ``sili`` command line: bad input exits 2 with a message; good input prints a result."""

import subprocess
import sys


def _sili(*args):
    return subprocess.run(
        [sys.executable, "-m", "sili_robots.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_rollout_prints_result():
    out = _sili("rollout", "circle-3", "--interactions", "5")
    assert out.returncode == 0, out.stderr
    assert "unchanged: 1.000" in out.stdout


def test_unknown_task_exits_2_with_choices():
    out = _sili("rollout", "circle-4")
    assert out.returncode == 2
    assert "unknown task 'circle-4'" in out.stderr and "circle-3" in out.stderr
    assert "Traceback" not in out.stderr


def test_non_positive_count_exits_2():
    out = _sili("rollout", "circle-3", "--interactions", "0")
    assert out.returncode == 2 and "need an integer >= 1" in out.stderr


def test_a_parse_error_is_one_line_naming_the_value_and_the_choices():
    out = _sili("train", "--task", "circle-3", "--method", "foo")
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()  # no usage block before it
    assert (
        line.startswith("sili train: error:")
        and "'foo'" in line
        and "sili" in line.split("'foo'")[1]
    )
