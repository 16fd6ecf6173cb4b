"""Output files: checked before any work, written to a temporary file beside the target, renamed.

A reader never sees a half-written target: it sees the old file (or none) until
``os.replace`` swaps the finished file in, and a failed or interrupted write leaves nothing
behind. :func:`check_output_file` and :func:`check_output_folder` refuse, before a command
starts its work, every target that would fail or do harm at the end: a missing or read-only
folder, a name too long for the file system, a folder, device or FIFO in the target's place;
:func:`check_folder_unused`, an output folder already holding files; :func:`claim_folder`
holds an output folder for one run, so that two runs never write into one.
"""

from __future__ import annotations

import errno
import hashlib
import os
import resource
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, contextmanager, suppress
from pathlib import Path

from metalens_cli.errors import InputError

SUFFIX_KEPT = 16  # longest target suffix the temporary name repeats (writers pick formats by it)
FULL_MARGIN_BYTES = 1 << 20  # free space below which a failed write is blamed on a full disk


@contextmanager
def atomic_write(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a fresh temporary path in ``target``'s directory; on success rename it onto ``target``.

    The temporary file exists (empty) when yielded and ends with the target's suffix, so
    writers that choose a format from the extension (OpenCV, matplotlib) behave as for the
    target. It is created with mode 0o666 minus the umask, like an ordinary new file, and
    flushed to disk before the rename. If the ``with`` body raises (any exception,
    KeyboardInterrupt included), the temporary file is removed, ``target`` is left untouched
    and the exception propagates; a library error caused by a full disk or the file-size limit
    (``ulimit -f``) is raised as that :class:`OSError` (ENOSPC, EFBIG) naming ``target``. The
    target's directory must exist.
    """
    target = Path(target)
    temporary = _create_temporary(target)
    try:
        try:
            yield temporary
            _fsync(temporary)
            os.replace(temporary, target)
        except OSError as exc:
            if exc.filename not in (None, str(temporary)):
                raise
            cause = exc.errno if exc.errno is not None else _storage_exhausted(temporary)
            if cause is None:  # a library's own OSError without an errno: its words, the target's name
                raise OSError(errno.EIO, str(exc) or type(exc).__name__, str(target)) from None
            raise OSError(cause, exc.strerror if exc.errno is not None else os.strerror(cause), str(target)) from None
        except Exception as exc:
            cause = _storage_exhausted(temporary)
            if cause is None:
                raise
            raise OSError(cause, os.strerror(cause), str(target)) from exc
    except BaseException:
        with suppress(FileNotFoundError):
            os.unlink(temporary)
        raise


@contextmanager
def atomic_files(*targets: str | os.PathLike[str] | None) -> Iterator[list[Path | None]]:
    """Several outputs of one command published together (``align -o --warp-out``, ``psf compare
    --csv --plot``): one :func:`atomic_write` temporary per target (None for a None target, an
    output not asked for), renamed, the last target first, only once the ``with`` body has
    written them all. If the body raises (a full disk, the file-size limit, Ctrl-C), every
    temporary is removed and no target is touched."""
    with ExitStack() as stack:
        yield [None if target is None else stack.enter_context(atomic_write(target)) for target in targets]


@contextmanager
def atomic_folder(target: str | os.PathLike[str], field: str = "--output") -> Iterator[Path]:
    """Yield a fresh hidden folder beside ``target`` to write a command's files into; on success
    it becomes ``target`` (renamed when ``target`` does not exist, else its files are moved in one
    by one, once every one of them is known to replace at most a regular file of that name: a
    folder, FIFO, device or symbolic link there is an :class:`InputError` naming ``field`` and
    the path, before anything is moved), on any exception (Ctrl-C, SIGTERM included) it is
    removed: ``target`` never holds part of one run's files. Missing parents of ``target`` are
    created; a new ``target`` gets the permissions of a folder made by ``mkdir`` (the staging
    folder is private while written). An OSError about a staging file names its target file."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".metalens-", suffix=".tmp", dir=target.parent))
    try:
        try:
            yield staging
        except OSError as exc:  # name the file the user asked for, not its staging copy
            inside = exc.filename is not None and Path(exc.filename).is_relative_to(staging)
            if not inside:
                raise
            raise OSError(exc.errno, exc.strerror, str(target / Path(exc.filename).relative_to(staging))) from None
        if target.exists():
            items = sorted(staging.iterdir())
            for item in items:
                _check_replaceable(target / item.name, field)
            for item in items:
                os.replace(item, target / item.name)
            staging.rmdir()
        else:
            os.chmod(staging, 0o777 & ~_umask())
            os.rename(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _check_replaceable(path: Path, field: str) -> None:
    """Refuse to publish a file over anything but a regular file (never through a link)."""
    if path.is_symlink() or (path.exists() and not path.is_file()):
        what = (
            "a symbolic link"
            if path.is_symlink()
            else "a folder"
            if path.is_dir()
            else "not a regular file (a FIFO, device or socket)"
        )
        raise InputError(
            field,
            f"{str(path)!r}, where this run writes a file, is {what}",
            "an output folder whose same-named entries are regular files, or another folder",
        )


def _umask() -> int:
    """The process's file-creation mask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_output_file(path: str | os.PathLike[str], field: str, *, suffixes: Iterable[str] | None = None) -> Path:
    """Refuse, before any work, an output file that cannot be written where it is asked for.

    Refused with an :class:`InputError` naming ``field``: an empty name, a name longer than
    the file system allows, a suffix outside ``suffixes`` (lower-case, with the dot), a missing
    or unwritable folder (tried by creating and removing a file there, so a read-only file
    system is caught even for root), an existing folder, device, FIFO or socket at ``path``.
    """
    target = Path(path)
    if target.name in ("", ".", ".."):
        raise InputError(field, f"{str(path)!r} names a folder", "a file path")
    _check_name_lengths(target, field)
    if suffixes is not None:
        check_suffix(target, field, tuple(suffixes))
    if not target.parent.is_dir():
        raise InputError(field, f"folder {str(target.parent)!r} does not exist", "a file in an existing folder")
    if target.is_symlink():  # replacing it would cut the link; writing through it, surprise its target
        raise InputError(field, f"{str(target)!r} is a symbolic link", "a regular file path (the link's target itself)")
    if target.is_dir():
        raise InputError(field, f"{str(target)!r} is a folder", "a file path")
    if target.exists() and not target.is_file():
        raise InputError(
            field,
            f"{str(target)!r} exists and is not a regular file (a device, FIFO or socket)",
            "a new or regular file",
        )
    _probe_writable(target.parent, field)
    return target


def check_output_folder(path: str | os.PathLike[str], field: str) -> Path:
    """Refuse, before any work, an output folder that cannot be created or written: an existing
    non-folder, a name too long, or a nearest existing ancestor that is not a writable folder.
    Nothing is created."""
    folder = Path(path)
    _check_name_lengths(folder, field)
    if folder.exists() and not folder.is_dir():
        raise InputError(field, f"{str(folder)!r} exists and is not a folder", "a folder path")
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(field, f"{str(existing)!r} is not a folder", "a path inside folders")
    _probe_writable(existing, field)
    return folder


def check_folder_unused(path: str | os.PathLike[str], field: str) -> None:
    """Refuse, before any work, an existing output folder that holds anything: a command that
    writes a folder of files (:func:`atomic_folder`) then replaces no file it did not create in
    this run. Commands skip this check under their ``--overwrite``."""
    folder = Path(path)
    held = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    if held:
        more = f" (and {len(held) - 1} more)" if len(held) > 1 else ""
        raise InputError(
            field,
            f"folder {str(folder)!r} already holds {held[0]!r}{more}",
            "a new or empty folder, or --overwrite to write into it and replace same-named files",
        )


@contextmanager
def claim_folder(path: str | os.PathLike[str], field: str) -> Iterator[Path]:
    """Hold the output folder ``path`` for one run, from before its first step to its end: an
    exclusive ``flock`` on the hidden file ``.NAME.metalens-lock`` beside it (missing parents
    are created, and removed again if the run leaves them empty). A second run into the folder
    while this one holds it is an :class:`InputError` naming ``field`` and the folder; the
    kernel drops the lock when a process dies, so a killed run never blocks the next (its lock
    file is taken over and removed)."""
    import fcntl

    folder = Path(path)
    made = [parent for parent in folder.parents if not parent.exists()]
    folder.parent.mkdir(parents=True, exist_ok=True)
    name = folder.name if len(os.fsencode(folder.name)) < 200 else hashlib.sha256(os.fsencode(folder.name)).hexdigest()
    lock = folder.parent / f".{name}.metalens-lock"
    while True:
        handle = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(handle)
            raise InputError(
                field,
                f"folder {str(folder)!r} is being written by another run",
                "another folder, or this one once that run has ended (with --overwrite to replace its files)",
            ) from None
        try:
            if os.stat(lock).st_ino == os.fstat(handle).st_ino:
                break  # still the lock file: the last holder removes it before it lets go
        except FileNotFoundError:
            pass
        os.close(handle)
    try:
        yield folder
    finally:
        with suppress(FileNotFoundError):
            os.unlink(lock)
        os.close(handle)
        for parent in made:  # the parents it made, innermost first, where the run left them empty
            with suppress(OSError):
                parent.rmdir()


def ensure_folder(path: str | os.PathLike[str], field: str) -> Path:
    """Check (:func:`check_output_folder`) and create the output folder ``path`` with its parents."""
    folder = check_output_folder(path, field)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name one file or folder (through links), existing or not."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_suffix(
    path: str | os.PathLike[str], field: str, allowed: tuple[str, ...], expected: str = "a file name"
) -> str:
    """The lower-case suffix of ``path`` if it is one of ``allowed``, else an InputError naming
    ``field``; a bare suffix (``.exr``, which pathlib reads as a hidden file without one) is told
    so."""
    name, suffix = Path(path).name, Path(path).suffix.lower()
    if suffix in allowed:
        return suffix
    if name.lower() in allowed:
        raise InputError(
            field, f"{name!r} has no name before its suffix", f"{expected} ending in {_either(allowed)}, e.g. out{name}"
        )
    raise InputError(field, f"{name!r} does not end in {_either(allowed)}", f"{expected} ending in {_either(allowed)}")


def _either(suffixes: tuple[str, ...]) -> str:
    return suffixes[0] if len(suffixes) == 1 else ", ".join(suffixes[:-1]) + " or " + suffixes[-1]


def _check_name_lengths(path: Path, field: str) -> None:
    """Every component of ``path`` within the file system's name limit (checked before any stat,
    which would fail on a long name with an OSError of its own)."""
    try:
        limit = os.pathconf(".", "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > limit:
            raise InputError(
                field,
                f"the name {part[:24]!r}… is {size} bytes; this file system allows {limit}",
                f"names of at most {limit} bytes",
            )


def _probe_writable(folder: Path, field: str) -> None:
    """Create and remove a file in ``folder``: the one test of writability that root, ACLs and
    read-only mounts all answer truthfully."""
    try:
        os.unlink(_create_temporary(folder / "probe"))
    except OSError as exc:
        raise InputError(
            field, f"cannot write in folder {str(folder)!r}: {exc.strerror}", "a writable folder"
        ) from None


def _create_temporary(target: Path) -> Path:
    """Create an empty, uniquely named hidden file beside ``target`` and return its path.

    The name is short (a 255-byte target name still fits) and keeps the target's suffix."""
    suffix = target.suffix if len(target.suffix) <= SUFFIX_KEPT else ""
    while True:
        candidate = target.with_name(f".metalens-{secrets.token_hex(6)}.tmp{suffix}")
        try:
            descriptor = os.open(candidate, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
        except FileExistsError:
            continue
        os.close(descriptor)
        return candidate


def _storage_exhausted(temporary: Path) -> int | None:
    """ENOSPC or EFBIG when the disk is (nearly) full or ``temporary`` reached the process's
    file-size limit; None when storage is not to blame."""
    with suppress(OSError):
        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if limit != resource.RLIM_INFINITY and temporary.stat().st_size >= limit - FULL_MARGIN_BYTES:
            return errno.EFBIG
        if shutil.disk_usage(temporary.parent).free < FULL_MARGIN_BYTES:
            return errno.ENOSPC
    return None


def _fsync(path: Path) -> None:
    """Flush the file's data to stable storage (the writer may not have)."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)
