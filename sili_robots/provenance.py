"""Where a run's numbers came from: the code's git revision, the libraries and the processor
(``config.json``'s ``versions``). Seeded runs repeat exactly only when all of them match."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import os
import platform
import subprocess
from pathlib import Path

import torch

from sili_robots.plugins import class_path

#: the libraries behind the tasks' dynamics and the agent's numbers beyond torch and numpy
#: (recorded where installed): simulators, solvers, SciPy (category matching, k-means)
RECORDED_PACKAGES = (
    "mujoco",
    "robosuite",
    "mink",
    "qpsolvers",
    "daqp",
    "libsumo",
    "eclipse-sumo",
    "traci",
    "scipy",
)


#: ``versions`` key of the code's git revision (``code_revision``)
REVISION = "sili_robots_revision"


#: the checkout this package runs from, if it does
CHECKOUT = Path(__file__).resolve().parents[1]


@functools.cache
def code_revision(root: Path = CHECKOUT) -> str | None:
    """This package's git commit when it runs from a checkout, ``+`` a digest of its local
    changes to the package's code when there are any (edits elsewhere, e.g. to results or
    docs, do not count; nor do untracked files but Python modules, such as an editor's); None
    when installed otherwise or git cannot tell. Its version number alone does not change with
    every change of its numbers."""
    if not (root / ".git").exists():
        return None
    git = ["git", "-C", str(root), "-c", f"safe.directory={root}", "--no-optional-locks"]
    status = ["status", "--porcelain=v1", "-z", "--no-renames", "--untracked-files=all"]
    try:  # (no index lock: a sweep's workers ask at once)
        commit, changes = (
            subprocess.run([*git, *ask], capture_output=True, timeout=30, check=True).stdout
            for ask in (["rev-parse", "HEAD"], [*status, "--", "sili_robots"])
        )
    except (OSError, subprocess.SubprocessError):
        return None
    changed = sorted(
        entry[3:]
        for entry in changes.split(b"\0")
        if entry and (not entry.startswith(b"??") or entry.endswith(b".py"))
    )
    head = commit.decode().strip()[:12]
    return f"{head}+{_digest(root, changed)}" if changed else head


def _digest(root: Path, names: list[bytes]) -> str:
    """12 hex digits of the files' names and contents as they are now (a removed or unreadable
    one by its name and state)."""
    digest = hashlib.sha256()
    for name in names:
        path = root / os.fsdecode(name)
        digest.update(name + b"\0")
        try:
            if path.is_symlink():
                digest.update(os.fsencode(os.readlink(path)))
            elif path.is_file():
                digest.update(hashlib.sha256(path.read_bytes()).digest())  # package files: small
            else:
                digest.update(b"absent")
        except OSError:
            digest.update(b"unreadable")
    return digest.hexdigest()[:12]


#: prefix of the ``versions`` keys of a user's classes' code (``source_digests``)
OWN_CODE = "code of "


def source_digests(classes: list[type]) -> dict[str, str]:
    """12 hex digits of the file each of a user's classes (a task or an add-on named by
    ``module:Class``) is defined in, keyed ``code of module:Class``: the package's revision does
    not cover them, and an add-on's settings are its class attributes. (Modules they import are
    not covered.) A class whose file cannot be read is left out."""
    found = {}
    for cls in classes:
        with contextlib.suppress(OSError, TypeError):  # a built-in, or a file gone since
            source = Path(inspect.getsourcefile(cls) or "").read_bytes()
            found[OWN_CODE + class_path(cls)] = hashlib.sha256(source).hexdigest()[:12]
    return found


def versions(threads: int = 1) -> dict[str, str]:
    """The software and the processor a run used: seeded runs repeat exactly only on the same
    code (``sili_robots_revision``), the same kernels, which torch picks by CPU, instruction-set
    cap and thread count (``machine``), and the same libraries."""
    from importlib.metadata import PackageNotFoundError, version

    import gymnasium
    import numpy

    import sili_robots
    from sili_robots.agent.matmul import machine_key

    found = {
        "machine": machine_key(threads),
        "sili_robots": sili_robots.__version__,
        **({REVISION: code_revision()} if code_revision() else {}),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "gymnasium": gymnasium.__version__,
        "python": platform.python_version(),
    }
    for name in RECORDED_PACKAGES:
        with contextlib.suppress(PackageNotFoundError):
            found[name] = version(name)
    return found
