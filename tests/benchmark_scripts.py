"""A script of ``benchmarks/`` (not a package) imported as a module, or run, for its tests."""

from __future__ import annotations

import importlib.util
import io
import runpy
import sys
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_script(name: str) -> ModuleType:
    """``benchmarks/NAME.py`` as the module ``NAME`` (registered, so its dataclasses work)."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@dataclass(frozen=True)
class ScriptRun:
    """What ``python benchmarks/NAME.py ARGS`` gives back: exit status and output."""

    returncode: int
    stdout: str
    stderr: str


def run_script(name: str, *args: str) -> ScriptRun:
    """``benchmarks/NAME.py`` run on ``args`` in this process through its own ``__main__``
    block (no interpreter to start and torch to import again: seconds a call). Anything but its
    exit is raised, where a process would print a traceback; the torch threads it sets are put
    back, so later tests in the process keep theirs."""
    import torch

    path = BENCHMARKS / f"{name}.py"
    out, err = io.StringIO(), io.StringIO()
    argv, sys.argv = sys.argv, [str(path), *args]
    threads = torch.get_num_threads()
    code: int | str | None = 0
    try:
        with redirect_stdout(out), redirect_stderr(err):
            runpy.run_path(str(path), run_name="__main__")
    except SystemExit as stop:
        code = stop.code
    finally:
        sys.argv = argv
        torch.set_num_threads(threads)
    if isinstance(code, str):  # SystemExit("message"): printed, status 1
        err.write(code + "\n")
    returncode = 0 if code is None else code if isinstance(code, int) else 1
    return ScriptRun(returncode, out.getvalue(), err.getvalue())
