"""A cap on a training process's memory at what the machine can give when it starts.

Linux grants allocations beyond the memory left, and when they are touched its out-of-memory
killer ends the process without a word, after starving everything else on the machine. Under the
cap (``RLIMIT_DATA``, which counts the process's private writable memory) such an allocation
fails at once instead: torch and numpy raise, and ``sili`` prints its one-line "out of memory"."""

from __future__ import annotations

import contextlib
import re
import resource
from collections.abc import Iterator
from pathlib import Path


def _kib(path: str, *fields: str) -> dict[str, int]:
    try:
        text = Path(path).read_text()
    except OSError:
        return {}
    pattern = rf"^({'|'.join(fields)}):\s+(\d+) kB"
    return {k: 1024 * int(v) for k, v in re.findall(pattern, text, re.M)}


def available_memory() -> int | None:
    """Bytes the machine can still give (MemAvailable + SwapFree; None where unknown)."""
    found = _kib("/proc/meminfo", "MemAvailable", "SwapFree")
    return sum(found.values()) if "MemAvailable" in found else None


@contextlib.contextmanager
def capped_at_available() -> Iterator[None]:
    """Within the block, the process's data may grow by at most what the machine has available
    now (any lower limit already set stays); the previous limit is restored afterwards."""
    free = available_memory()
    used = _kib("/proc/self/status", "VmData").get("VmData")
    if free is None or used is None:  # not Linux: no cap
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    cap = min(limit for limit in (used + free, soft, hard) if limit != resource.RLIM_INFINITY)
    resource.setrlimit(resource.RLIMIT_DATA, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))
