"""A cap on a training process's memory at what the machine can give when it starts.

Linux grants allocations beyond the memory left, and when they are touched its out-of-memory
killer ends the process without a word, after starving everything else on the machine. Under the
cap (``RLIMIT_DATA``, which counts the process's private writable memory, touched or not) such an
allocation fails at once instead: torch and numpy raise, and ``sili`` prints its one-line "out of
memory". What the machine can give is the smaller of the system's (MemAvailable + SwapFree) and a
container's (its memory cgroup's limit less its usage)."""

from __future__ import annotations

import contextlib
import re
import resource
import threading
from collections.abc import Iterator
from pathlib import Path

#: allowed beyond what is free: memory counted but never touched (the replay buffer's newly
#: doubled half, thread stacks)
HEADROOM = 512 * 2**20
#: (limit, usage) files of a memory cgroup: v2, then v1
CGROUP_FILES = (
    ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
    ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
)

_lock = threading.Lock()
_depth = 0  # trainings inside the cap (threads of one process share it)
_before: tuple[int, int] | None = None


def _kib(path: str, *fields: str) -> dict[str, int]:
    try:
        text = Path(path).read_text()
    except OSError:
        return {}
    pattern = rf"^({'|'.join(fields)}):\s+(\d+) kB"
    return {k: 1024 * int(v) for k, v in re.findall(pattern, text, re.M)}


def _cgroup_free() -> int | None:
    """A memory cgroup's limit less its usage (None when it has no limit or none is readable)."""
    for limit_file, usage_file in CGROUP_FILES:
        try:
            limit = Path(limit_file).read_text().strip()
            usage = int(Path(usage_file).read_text())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 2**60:  # "max" or v1's huge number: no limit
            return max(int(limit) - usage, 0)
        return None
    return None


def available_memory() -> int | None:
    """Bytes the machine (or its container) can still give; None where unknown."""
    found = _kib("/proc/meminfo", "MemAvailable", "SwapFree")
    if "MemAvailable" not in found:
        return None
    cgroup = _cgroup_free()
    return sum(found.values()) if cgroup is None else min(sum(found.values()), cgroup)


@contextlib.contextmanager
def capped_at_available() -> Iterator[None]:
    """Within the block, the process's data may grow by at most what is available now (plus
    ``HEADROOM``; a lower limit already set stays); the limit before the first of nested or
    concurrent blocks is restored when the last ends."""
    global _depth, _before
    with _lock:
        if _depth == 0:
            free = available_memory()
            used = _kib("/proc/self/status", "VmData").get("VmData")
            if free is not None and used is not None:  # else not Linux: no cap
                soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
                limits = (used + free + HEADROOM, soft, hard)
                cap = min(v for v in limits if v != resource.RLIM_INFINITY)
                resource.setrlimit(resource.RLIMIT_DATA, (cap, hard))
                _before = (soft, hard)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _before is not None:
                resource.setrlimit(resource.RLIMIT_DATA, _before)
                _before = None
