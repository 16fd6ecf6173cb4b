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


def ensure_folder(path: str | os.PathLike[str], field: str) -> Path:
    """Create the output folder ``path`` (and its parents) or raise an :class:`InputError`
    naming ``field``; refuses an existing non-folder."""
    from metalens_cli.errors import InputError

    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise InputError(field, f"{str(folder)!r} exists and is not a folder", "a writable folder path")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(field, f"cannot create folder {str(folder)!r}: {exc.strerror or exc}", "a writable folder path") from None
    if not os.access(folder, os.W_OK):
        raise InputError(field, f"folder {str(folder)!r} is not writable", "a writable folder path")
    return folder


def check_output_file(path: str | os.PathLike[str], field: str) -> Path:
    """Refuse, before any work, an output file whose folder is missing or read-only, or which
    exists and is not a regular file."""
    from metalens_cli.errors import InputError

    target = Path(path)
    folder = target.parent
    if not folder.is_dir():
        raise InputError(field, f"folder {str(folder)!r} does not exist", "a file in an existing folder")
    if not os.access(folder, os.W_OK):
        raise InputError(field, f"folder {str(folder)!r} is not writable", "a file in a writable folder")
    if target.exists() and not target.is_file():
        raise InputError(field, f"{str(target)!r} exists and is not a regular file", "a new or regular file")
    return target


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
