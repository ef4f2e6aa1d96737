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


def test_a_broken_environment_is_made_anew(tmp_path):
    """A .venv whose interpreter went with an upgrade, or made without pip, fails every pip
    call: it is cleared and made again, and everything is installed into it."""
    repo, log = _checkout(tmp_path)
    working = (repo / "venv" / "bin" / "python").read_text()
    _setup(repo, "dev")
    (repo / "venv" / "bin" / "python").write_text("#!/usr/bin/env bash\nexit 1\n")
    (repo / "venv" / "pyvenv.cfg").write_text("home = /gone\n")
    system = tmp_path / "python3"  # as `python3 -m venv --clear venv` would, a working one
    system.write_text(
        f'#!/usr/bin/env bash\necho "$*" >> {log}\nrm -rf venv && mkdir -p venv/bin\n'
        f"printf '%s' '{working}' > venv/bin/python && chmod +x venv/bin/python\n"
    )
    system.chmod(0o755)
    subprocess.run(
        ["bash", "scripts/setup.sh", "dev"],
        cwd=repo,
        env={"PATH": "/usr/bin:/bin", "SILI_VENV": "venv", "PYTHON": str(system)},
        check=True,
    )
    assert "-m venv --clear venv" in log.read_text()
    assert _installs(log) == [".[dev]", ".[dev]"]


def test_a_folder_that_is_not_an_environment_is_never_cleared(tmp_path):
    repo, _ = _checkout(tmp_path)
    mine = repo / "mine"
    (mine / "project").mkdir(parents=True)
    (mine / "project" / "data.csv").write_text("1,2\n")
    done = subprocess.run(
        ["bash", "scripts/setup.sh"],
        cwd=repo,
        env={"PATH": "/usr/bin:/bin", "SILI_VENV": "mine"},
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and "mine is a folder, not a virtual environment" in done.stderr
    assert (mine / "project" / "data.csv").read_text() == "1,2\n"
