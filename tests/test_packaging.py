"""What ``pip install`` delivers: the wheel holds every module, the packaged bounds and the
license, reports the one version the code states, and requires every library the package
imports (one it only reached through another library's requirements could vanish with it);
the source distribution holds the package, not tests that need the rest of the repository."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

import sili_robots

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(sili_robots.__file__).parent
#: imported only where an optional group is installed (``pyproject.toml``'s extras)
OPTIONAL = {"ray", "grpc", "tensorboard", "stable_baselines3"}


def _requirement_name(spec: str) -> str:
    return canonicalize_name(Requirement(spec).name)


def _third_party_imports() -> set[str]:
    names: set[str] = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"sili_robots", "__future__"}


def _module_distributions(modules: set[str]) -> dict[str, set[str]]:
    """Each of ``modules`` (top-level names) -> the installed distributions that provide it.
    ``packages_distributions`` reads only ``top_level.txt`` before Python 3.11, which pyzmq and
    eclipse-sumo do not ship: those are found in the distributions' file lists."""
    from importlib.metadata import distributions, packages_distributions

    known = packages_distributions()
    out = {m: set(known[m]) for m in modules if m in known}
    missing = modules - set(out)
    for dist in distributions() if missing else ():
        for file in dist.files or ():
            top = file.parts[0].removesuffix(".py")
            if top in missing:
                out.setdefault(top, set()).add(dist.metadata["Name"])
    return out


def test_every_imported_library_is_a_declared_requirement(wheel: zipfile.ZipFile) -> None:
    declared = {
        _requirement_name(line.removeprefix("Requires-Dist: "))
        for line in _metadata(wheel)
        if line.startswith("Requires-Dist: ") and "extra ==" not in line  # not optional
    }
    modules = _third_party_imports() - OPTIONAL
    distributions = _module_distributions(modules)
    undeclared = {
        module: distributions.get(module)
        for module in modules
        if not {_requirement_name(d) for d in distributions.get(module, [module])} & declared
    }
    assert undeclared == {}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> zipfile.ZipFile:
    """The wheel, built from a copy of the sources (a build in place leaves build/ behind)."""
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    shutil.copytree(PACKAGE, src / "sili_robots", ignore=shutil.ignore_patterns("__pycache__"))
    out = src / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "-w", str(out), str(src)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    (path,) = out.glob("*.whl")
    return zipfile.ZipFile(path)


def test_the_wheel_holds_every_module_the_bounds_and_the_license(wheel: zipfile.ZipFile) -> None:
    names = set(wheel.namelist())
    modules = {p.relative_to(PACKAGE.parent).as_posix() for p in PACKAGE.rglob("*.py")}
    assert modules - names == set()
    assert "sili_robots/tasks/bounds.json" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)


@pytest.fixture(scope="module")
def sdist(tmp_path_factory: pytest.TempPathFactory) -> tarfile.TarFile:
    """The source distribution, built from a copy of the checkout's files it could take."""
    src = tmp_path_factory.mktemp("sdist-src")
    for name in ("pyproject.toml", "README.md", "LICENSE", "MANIFEST.in"):
        shutil.copy(ROOT / name, src / name)
    for name in ("sili_robots", "tests"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    out = src / "dist"
    build = f"from setuptools import build_meta; build_meta.build_sdist({str(out)!r})"
    subprocess.run(
        [sys.executable, "-c", build], cwd=src, check=True, capture_output=True, timeout=300
    )
    (path,) = out.glob("*.tar.gz")
    return tarfile.open(path)


def test_the_sdist_holds_the_package_and_no_tests_cut_from_their_repository(
    sdist: tarfile.TarFile,
) -> None:
    names = {name.split("/", 1)[1] for name in sdist.getnames() if "/" in name}
    modules = {p.relative_to(PACKAGE.parent).as_posix() for p in PACKAGE.rglob("*.py")}
    assert modules - names == set()
    assert {"sili_robots/tasks/bounds.json", "LICENSE", "README.md"} <= names
    assert not [name for name in names if name.startswith("tests/")]  # they need the checkout


def _metadata(wheel: zipfile.ZipFile) -> list[str]:
    (meta,) = [n for n in wheel.namelist() if n.endswith(".dist-info/METADATA")]
    return wheel.read(meta).decode().splitlines()


def test_the_wheel_reports_the_version_the_code_states(wheel: zipfile.ZipFile) -> None:
    lines = _metadata(wheel)
    assert f"Version: {sili_robots.__version__}" in lines
    assert "License-Expression: MIT" in lines
