"""A disk that refuses writes, for tests: the process's file size limit (``ulimit -f``). A write
past it fails with EFBIG, as a full disk's fails with ENOSPC: partly written, then refused (Python
ignores the SIGXFSZ that would otherwise stop the process)."""

from __future__ import annotations

import contextlib
import resource
from collections.abc import Iterator


@contextlib.contextmanager
def file_size_limit(nbytes: int) -> Iterator[None]:
    """No file grows past ``nbytes`` while the block runs (pytest's own files neither: keep
    the block short)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
