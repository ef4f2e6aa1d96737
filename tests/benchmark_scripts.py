"""A script of ``benchmarks/`` (not a package) imported as a module, or run, for its tests."""

from __future__ import annotations

import importlib.util
import io
import sys
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from sili_robots.errors import one_line_errors

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
    """``benchmarks/NAME.py`` run on ``args`` in this process, as its ``__main__`` runs it (no
    interpreter to start and torch to import again: seconds a call). Anything but its exit is
    raised, where a process would print a traceback."""
    script = load_script(name)
    out, err = io.StringIO(), io.StringIO()
    argv, sys.argv = sys.argv, [f"{name}.py", *args]
    code: int | str | None = 0
    try:
        with redirect_stdout(out), redirect_stderr(err):
            one_line_errors(script.main, f"{name}.py")
    except SystemExit as stop:
        code = stop.code
    finally:
        sys.argv = argv
    if isinstance(code, str):  # SystemExit("message"): printed, status 1
        err.write(code + "\n")
    returncode = 0 if code is None else code if isinstance(code, int) else 1
    return ScriptRun(returncode, out.getvalue(), err.getvalue())
