"""Atomic file replacement: write to a temporary file beside the target, then rename.

A reader never sees a half-written target: it sees the old file (or none) until
``os.replace`` swaps the finished file in, and a failed write leaves nothing behind.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path


@contextmanager
def atomic_write(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a fresh temporary path in ``target``'s directory; on success rename it onto ``target``.

    The temporary file exists (empty) when yielded and ends with the target's suffix, so
    writers that choose a format from the extension (OpenCV, matplotlib) behave as for the
    target. It is created with mode 0o666 minus the umask, like an ordinary new file, and
    flushed to disk before the rename. If the ``with`` body raises (any exception,
    KeyboardInterrupt included), the temporary file is removed, ``target`` is left untouched
    and the exception propagates. The target's directory must exist.
    """
    target = Path(target)
    temporary = _create_temporary(target)
    try:
        yield temporary
        _fsync(temporary)
        os.replace(temporary, target)
    except BaseException:
        with suppress(FileNotFoundError):
            os.unlink(temporary)
        raise


def _create_temporary(target: Path) -> Path:
    """Create an empty, uniquely named hidden file beside ``target`` and return its path."""
    while True:
        candidate = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp{target.suffix}")
        try:
            descriptor = os.open(candidate, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
        except FileExistsError:
            continue
        os.close(descriptor)
        return candidate


def _fsync(path: Path) -> None:
    """Flush the file's data to stable storage (the writer may not have)."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)
