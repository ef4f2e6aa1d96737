"""scripts/setup.sh installs what each of the two commands needs, once: the main job the package
alone, the tests its ``dev`` group. A stand-in interpreter records what pip is asked for (the
real installation is what the test command itself runs on a fresh clone)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _checkout(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "setup.sh", tmp_path / "scripts" / "setup.sh")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    log = tmp_path / "pip.log"
    python = tmp_path / "venv" / "bin" / "python"
    python.parent.mkdir(parents=True)
    python.write_text(f'#!/usr/bin/env bash\necho "$*" >> {log}\n')
    python.chmod(0o755)
    return tmp_path, log


def _setup(repo: Path, *groups: str) -> None:
    subprocess.run(
        ["bash", "scripts/setup.sh", *groups],
        cwd=repo,
        env={"PATH": "/usr/bin:/bin", "SILI_VENV": "venv"},
        check=True,
    )


def _installs(log: Path) -> list[str]:
    lines = log.read_text().splitlines() if log.exists() else []
    return [line.split()[-1] for line in lines if " install -q -e " in line]


def test_the_main_job_installs_the_package_and_the_tests_add_their_group(tmp_path):
    repo, log = _checkout(tmp_path)
    _setup(repo)
    assert _installs(log) == ["."]
    _setup(repo)  # nothing new
    assert _installs(log) == ["."]
    _setup(repo, "dev")
    assert _installs(log) == [".", ".[dev]"]
    _setup(repo)  # the package is already there with its dev group
    _setup(repo, "dev")
    assert _installs(log) == [".", ".[dev]"]
    assert (repo / "venv" / ".sili-installed").read_text().split()[1:] == ["dev"]


def test_a_changed_pyproject_installs_again(tmp_path):
    repo, log = _checkout(tmp_path)
    _setup(repo, "dev")
    with open(repo / "pyproject.toml", "a") as f:
        f.write("\n# changed\n")
    _setup(repo)
    assert _installs(log) == [".[dev]", "."]
