"""Running ``sili`` in the test's own process (a fresh process costs seconds of imports)."""

from __future__ import annotations

import contextlib
import io
from types import SimpleNamespace

from sili_robots.cli import main


def sili(*args: object) -> SimpleNamespace:
    """``sili ARGS``: returncode, stdout, stderr. An exception the CLI does not turn into an exit
    code escapes and fails the test."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exit_:  # argparse's own errors
            code = exit_.code if isinstance(exit_.code, int) else 1
    return SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())
