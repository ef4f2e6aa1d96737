"""Files replaced whole: a reader, or a kill during the write, sees the old file or the new one,
never part of one; the new one is on disk before it replaces the old, so a crash of the machine
does not leave an empty file either."""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

from sili_robots.errors import ConfigError, writing


@contextlib.contextmanager
def replacing(path: Path, shared: bool = False) -> Iterator[Path]:
    """A temporary path beside ``path`` to write, which replaces ``path`` when the block
    completes and is removed when it fails. ``shared``: other processes may write ``path`` at the
    same time (a sweep's tables, caches), so the temporary is this write's own; otherwise it has
    a fixed name, which the next write of a killed one reuses."""
    path = Path(path)
    if path.is_symlink():  # the file it points to is replaced, the link kept (a loop: itself)
        path = Path(os.path.realpath(path))
    tag = f".{os.getpid()}-{uuid.uuid4().hex[:8]}" if shared else ""
    tmp = path.with_name(f"{path.name}{tag}.tmp")
    if path.is_dir():  # os.replace would fail only after the work of writing it
        raise ConfigError(f"{path} is a directory, where a file is written; move it away")
    try:
        with writing(path, tmp):
            yield tmp
            if path.exists():  # the file keeps its permissions
                os.chmod(tmp, stat.S_IMODE(path.stat().st_mode))
            sync(tmp)
            os.replace(tmp, path)
        with contextlib.suppress(OSError):  # the rename itself (not every filesystem can)
            sync(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


def sync(path: Path) -> None:
    """Flush ``path`` (a file or a directory) from the operating system's cache to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_text(path: Path, text: str, shared: bool = False, encoding: str | None = None) -> None:
    """``path`` replaced whole by ``text`` (``replacing``)."""
    with replacing(path, shared) as tmp:
        tmp.write_text(text, encoding=encoding)


def write_bytes(path: Path, data: bytes, shared: bool = False) -> None:
    """``path`` replaced whole by ``data`` (``replacing``)."""
    with replacing(path, shared) as tmp:
        tmp.write_bytes(data)


def nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists: where a write would create folders from,
    so a file there (not a folder) refuses the write before any work is done for it."""
    base = Path(path)
    while not base.exists() and base != base.parent:
        base = base.parent
    return base


def check_can_write_in(path: Path) -> None:
    """``OSError`` unless ``path``, or the nearest ancestor that exists (where a write would
    create folders from), is a folder a file can be written in: asked before work is done for
    the write, by writing nothing that stays."""
    base = nearest_existing(path)
    if not base.is_dir():
        raise NotADirectoryError(0, f"{base} is a file")
    tempfile.TemporaryFile(dir=base).close()
