"""scripts/setup.sh installs what each of the two commands needs, once: the main job the package
alone, the tests its ``dev`` group. A stand-in interpreter records what pip is asked for (the
real installation is what the test command itself runs on a fresh clone)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _checkout(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "setup.sh", tmp_path / "scripts" / "setup.sh")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    log = tmp_path / "pip.log"
    python = tmp_path / "venv" / "bin" / "python"
    python.parent.mkdir(parents=True)
    _stand_in(python, log)
    return tmp_path, log


def _script(path: Path, body: str) -> None:
    """An executable bash script running ``body``."""
    path.write_text(f"#!/usr/bin/env bash\n{body}\n")
    path.chmod(0o755)


def _stand_in(path: Path, log: Path, body: str = "") -> None:
    """An interpreter that logs its arguments, then runs ``body`` (bash; ``$*`` the arguments)."""
    _script(path, f'echo "$*" >> {log}\n{body}')


def _setup(
    repo: Path,
    *groups: str,
    venv: str = "venv",
    python: Path | None = None,
    check: bool = True,
    platform: tuple[str, str] = ("Linux", "x86_64"),
) -> subprocess.CompletedProcess:
    """setup.sh with a stand-in `uname` naming ``platform`` (system, machine)."""
    bin_dir = repo / "platform-bin"
    bin_dir.mkdir(exist_ok=True)
    _script(
        bin_dir / "uname", f'case "$1" in -s) echo {platform[0]};; -m) echo {platform[1]};; esac'
    )
    env = {"PATH": f"{bin_dir}:/usr/bin:/bin", "SILI_VENV": venv}
    if python is not None:
        env["PYTHON"] = str(python)
    return subprocess.run(
        ["bash", "scripts/setup.sh", *groups],
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
        check=check,
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
    _script(repo / "venv" / "bin" / "python", "exit 1")
    (repo / "venv" / "pyvenv.cfg").write_text("home = /gone\n")
    system = tmp_path / "python3"  # as `python3 -m venv --clear venv` would, a working one
    _stand_in(
        system,
        log,
        "rm -rf venv && mkdir -p venv/bin\n"
        f"printf '%s' '{working}' > venv/bin/python && chmod +x venv/bin/python",
    )
    _setup(repo, "dev", python=system)
    assert "-m venv --clear venv" in log.read_text()
    assert _installs(log) == [".[dev]", ".[dev]"]


def test_a_folder_that_is_not_an_environment_is_never_cleared(tmp_path):
    repo, _ = _checkout(tmp_path)
    mine = repo / "mine"
    (mine / "project").mkdir(parents=True)
    (mine / "project" / "data.csv").write_text("1,2\n")
    done = _setup(repo, venv="mine", check=False)
    assert done.returncode == 2 and "mine is a folder, not a virtual environment" in done.stderr
    assert (mine / "project" / "data.csv").read_text() == "1,2\n"


def _torch_installs(log: Path) -> list[str]:
    return [
        line.split(" install -q ")[1] for line in log.read_text().splitlines() if "torch==" in line
    ]


def test_torch_is_the_cpu_build_from_disk_then_pytorchs_cpu_index_never_the_cuda_one(tmp_path):
    """PyPI's torch is the CUDA build on Linux x86-64 (several GB): the CPU build is asked for
    first where pip finds it already, then from PyTorch's CPU index; when neither installs, setup
    stops and says so, and the next run tries again. Elsewhere PyPI's is the CPU build."""
    repo, log = _checkout(tmp_path)
    cpu_index = "torch==2.13.0+cpu --extra-index-url https://download.pytorch.org/whl/cpu"
    _setup(repo)
    assert _torch_installs(log) == ["torch==2.13.0+cpu"]
    stamp = repo / "venv" / ".sili-installed"
    for failing, asked in (("*+cpu", ["torch==2.13.0+cpu", cpu_index]), ("*torch==*", None)):
        log.unlink()
        stamp.unlink(missing_ok=True)
        _stand_in(repo / "venv" / "bin" / "python", log, f'case "$*" in {failing}) exit 1;; esac')
        done = _setup(repo, check=False)
        if asked is not None:  # none on disk or in the configured indexes: PyTorch's CPU index
            assert done.returncode == 0 and _torch_installs(log) == asked
            assert _installs(log) == ["."] and stamp.is_file()
        else:  # no CPU build anywhere: no CUDA build instead, and no stamp
            assert done.returncode == 1
            assert "could not install torch 2.13.0's CPU build" in done.stderr
            assert _torch_installs(log) == ["torch==2.13.0+cpu", cpu_index]
            assert _installs(log) == [] and not stamp.exists()
    _stand_in(repo / "venv" / "bin" / "python", log)
    for platform in (("Darwin", "arm64"), ("Linux", "aarch64")):
        log.unlink()
        stamp.unlink(missing_ok=True)
        _setup(repo, platform=platform)
        assert _torch_installs(log) == ["torch==2.13.0"]


def test_a_changed_torch_pin_installs_again(tmp_path):
    repo, log = _checkout(tmp_path)
    _setup(repo)
    script = repo / "scripts" / "setup.sh"
    script.write_text(script.read_text().replace("TORCH=2.13.0", "TORCH=2.13.1"))
    _setup(repo)
    assert _torch_installs(log) == ["torch==2.13.0+cpu", "torch==2.13.1+cpu"]
    assert _installs(log) == [".", "."]


def test_an_environment_on_another_python_is_made_anew_with_the_one_given(tmp_path):
    """A leftover .venv below requires-python, or on another version than PYTHON names, would
    keep its Python (pip then fails on torch, or PYTHON is silently ignored)."""
    repo, log = _checkout(tmp_path)
    venv_python = repo / "venv" / "bin" / "python"
    _stand_in(venv_python, log, 'case "$*" in *version_info[:2]*) echo 3.11;; esac')
    made = venv_python.read_text()  # what `python3 -m venv --clear venv` makes: a 3.11
    system = tmp_path / "python3"
    _stand_in(
        system,
        log,
        'case "$*" in *version_info[:2]*) echo 3.11;; *-m\\ venv*) rm -rf venv && mkdir -p '
        f"venv/bin && printf '%s' '{made}' > venv/bin/python && chmod +x venv/bin/python && "
        "touch venv/pyvenv.cfg;; esac",
    )
    for old in ("exit 1", "echo 3.12"):  # 3.9: below 3.10; 3.12: not PYTHON's
        _stand_in(venv_python, log, f'case "$*" in *sys.exit*|*version_info*) {old};; esac')
        (repo / "venv" / "pyvenv.cfg").write_text("home = /old\n")
        log.write_text("")
        _setup(repo, python=system)
        assert "-m venv --clear venv" in log.read_text()
        assert _installs(log) == ["."]
    _setup(repo, python=system)
    assert _installs(log) == ["."]  # the same version now: nothing to do


def test_a_python_below_requires_python_is_named_not_used(tmp_path):
    repo, log = _checkout(tmp_path)
    shutil.rmtree(repo / "venv")  # none yet
    old = tmp_path / "python3"
    _stand_in(old, log, 'case "$*" in *sys.exit*) exit 1;; *version_info*) echo 3.9;; esac')
    done = _setup(repo, python=old, check=False)
    assert done.returncode == 2
    assert f"sili-robots needs Python >= 3.10; {old} is 3.9" in done.stderr
    assert "-m venv" not in log.read_text()


def test_both_commands_run_in_the_environment_sili_venv_names(tmp_path):
    """setup.sh makes SILI_VENV's environment, so the two commands must run in it too: a
    checkout without .venv, the environment running these tests named by its path (setup.sh a
    stand-in here, so no install can touch that environment)."""
    (tmp_path / "scripts").mkdir()
    for script in ("main.sh", "test.sh"):
        shutil.copy(ROOT / "scripts" / script, tmp_path / "scripts" / script)
    log = tmp_path / "setup.log"
    (tmp_path / "scripts" / "setup.sh").write_text(f'echo "$SILI_VENV $*" >> {log}\n')
    venv = Path(sys.prefix)  # the environment running these tests
    bin_dir = tmp_path / "bin"  # chromium found: test.sh installs nothing
    bin_dir.mkdir()
    _script(bin_dir / "chromium", "")
    path = f"{bin_dir}:{os.environ['PATH']}"
    env = {**os.environ, "PATH": path, "SILI_VENV": str(venv), "SILI_MAIN_OUT": str(tmp_path / "m")}
    run = dict(cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    main = subprocess.run(["bash", "scripts/main.sh", "--dry-run"], **run)
    assert main.returncode == 0, main.stderr[-2000:]
    assert "2 runs" in main.stdout
    tests = subprocess.run(["bash", "scripts/test.sh", "--version"], **run)
    assert tests.returncode == 0, tests.stderr[-2000:]
    assert "pytest" in tests.stdout + tests.stderr
    assert log.read_text().splitlines() == [f"{venv} ", f"{venv} dev"]
    assert not (tmp_path / ".venv").exists()
