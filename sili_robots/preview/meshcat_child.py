"""Run meshcat's server so that it dies with the process that started it.

Usage: ``python -m sili_robots.preview.meshcat_child PARENT_PID [meshcat-server args]``. Linux's
``PR_SET_PDEATHSIG`` makes the kernel send SIGKILL when the parent exits for any reason (even
SIGKILL); if the parent is already gone when this starts, it exits at once.
"""

from __future__ import annotations

import ctypes
import os
import runpy
import signal
import sys

PR_SET_PDEATHSIG = 1


def main() -> None:
    parent = int(sys.argv[1])
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: the parent's cleanup is all there is
        pass
    if os.getppid() != parent:
        sys.exit(0)
    sys.argv = ["meshcat-server", *sys.argv[2:]]
    runpy.run_module("meshcat.servers.zmqserver", run_name="__main__")


if __name__ == "__main__":
    main()
