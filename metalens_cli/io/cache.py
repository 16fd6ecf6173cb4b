"""An on-disk cache of computed arrays, keyed by a hash of everything that went into them.

Entries are ``.npz`` files under ``$METALENS_CACHE``, else the platform's user cache folder for
``metalens`` (``platformdirs.user_cache_dir``: ``$XDG_CACHE_HOME/metalens``, else
``~/.cache/metalens``, on Linux; ``~/Library/Caches/metalens`` on macOS), in one folder per kind
(``nanofin``, ``nanofin-sweep``, ``nanofin-refine``). The key is the SHA-256 of the inputs
written as canonical JSON (sorted keys; arrays as lists), so a changed input (a geometry, an
index at one wavelength, a solver version) is a different entry and a stale one is never read.

An entry is checked before it is used: besides its arrays it holds ``_meta``, a JSON text with
the entry format (``FORMAT``), its kind, its key and the SHA-256 of its arrays (names, dtypes,
shapes, bytes).
Read by :func:`cached`, an entry that is unreadable, of another format (an older metalens's,
without ``_meta``, included), written for another kind or key, whose checksum does not match or
that the caller's ``validate`` rejects (NaN, η outside 0..1, another shape) is renamed
``KEY.npz.bad`` (replacing an earlier one), named with the reason in a :class:`CacheWarning`
and recomputed.

A process computing an entry holds an exclusive ``flock`` on ``KEY.lock`` beside it; another
process asking for the same entry waits, then reads the entry the first wrote: it is computed
and written once (a temporary file renamed into place), and every process gets the same
arrays. The holder removes the lock file before letting go; the kernel lets go of a killed
holder's lock, and the next process computes. A cache folder that cannot be used (a file,
``/dev/null``, read-only, full) is named once per process in a :class:`CacheWarning`: results
are then computed, not stored (the sound entries of a read-only one are still read).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import platformdirs

from metalens_cli.io.atomic import atomic_write

FORMAT = 2  # the entry layout: arrays + _meta (1: arrays alone, before the checksum)
META = "_meta"  # the entry's reserved array name

Arrays = dict[str, np.ndarray]
Validator = Callable[[Arrays], str | None]


class CacheWarning(UserWarning):
    """A cache entry was set aside, or the cache folder cannot be used; the result is recomputed."""


class Entry(NamedTuple):
    """What :func:`cached` returns: the ``arrays``, the entry's ``path`` (None when not stored)
    and whether they were read from the cache (``hit``) rather than computed."""

    arrays: Arrays
    path: Path | None
    hit: bool


_UNUSABLE_WARNED: set[str] = set()  # cache folders already named in a warning by this process


def cache_folder() -> Path:
    """The cache's root folder (not created): ``$METALENS_CACHE``, else the platform's user cache
    folder for metalens (platformdirs reads ``$XDG_CACHE_HOME`` on Linux)."""
    if os.environ.get("METALENS_CACHE"):
        return Path(os.environ["METALENS_CACHE"])
    return Path(platformdirs.user_cache_dir("metalens", appauthor=False))


def input_key(inputs: dict[str, Any]) -> str:
    """The hex SHA-256 (first 24 digits) of ``inputs`` as canonical JSON; numpy arrays and
    complex numbers are written as lists of their parts."""
    return hashlib.sha256(json.dumps(inputs, sort_keys=True, default=_plain).encode()).hexdigest()[:24]


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, complex):
        return [value.real, value.imag]
    if isinstance(value, list):
        return [_plain(v) if isinstance(v, complex) else v for v in value]
    if isinstance(value, np.generic):
        return _plain(value.item())
    raise TypeError(f"{type(value).__name__} is not cacheable input")


def entry_path(kind: str, key: str) -> Path:
    """Where the entry ``key`` of ``kind`` lives: ``cache_folder()/kind/key.npz`` (nothing is
    created)."""
    return cache_folder() / kind / f"{key}.npz"


def cached(kind: str, key: str, compute: Callable[[], Arrays], validate: Validator) -> Entry:
    """The arrays stored under ``key``, else ``compute()``'s, stored (see the module docstring).

    ``validate(arrays)`` says why an entry's arrays cannot be the ones asked for (a short
    reason naming the array), or None; it is called only with checksummed arrays, whichever
    names they have. ``compute`` runs holding the entry's lock, so that no other process
    computes it meanwhile."""
    path = entry_path(kind, key)
    found = _read(path, kind, key, validate)
    if isinstance(found, dict):
        return Entry(found, path, True)
    with _locked(path) as locked:
        if locked:  # written while this process waited, or still to be set aside
            found = _read(path, kind, key, validate)
            if isinstance(found, dict):
                return Entry(found, path, True)
        if found is not None:
            _set_aside(path, found)
        arrays = {name: np.asarray(value) for name, value in compute().items()}
        return Entry(arrays, _store(path, kind, key, arrays) if locked else None, False)


def load(kind: str, key: str, validate: Validator = lambda arrays: None) -> Arrays | None:
    """The arrays of a sound entry under ``key`` (checked as by :func:`cached`), else None;
    nothing is warned about or moved."""
    found = _read(entry_path(kind, key), kind, key, validate)
    return found if isinstance(found, dict) else None


def check_array(
    arrays: Arrays,
    name: str,
    shape: tuple[int | None, ...] | None = None,
    low: float = -np.inf,
    high: float = np.inf,
    where: np.ndarray | bool = True,
) -> str | None:
    """None when ``arrays[name]`` is a real number array of ``shape`` (None: any; a None in it:
    any length) whose values are finite and within [low, high] where ``where`` is True; else
    why not, starting with ``name``."""
    if name not in arrays:
        return f"{name}: missing"
    value = arrays[name]
    if value.dtype.kind not in "iuf":
        return f"{name}: of type {value.dtype}, not real numbers"
    if shape is not None and (value.ndim != len(shape) or any(n not in (None, m) for n, m in zip(shape, value.shape))):
        return f"{name}: of shape {value.shape}, expected {tuple('any' if n is None else n for n in shape)}"
    checked = value[np.broadcast_to(where, value.shape)]
    if not np.isfinite(checked).all():
        return f"{name}: {np.count_nonzero(~np.isfinite(checked))} of {checked.size} value(s) not finite"
    outside = checked[(checked < low) | (checked > high)]
    if outside.size:
        return f"{name}: {outside.size} value(s) outside {low:g}..{high:g} (such as {outside[0]:g})"
    return None


def _read(path: Path, kind: str, key: str, validate: Validator) -> Arrays | str | None:
    """The entry's arrays when it is sound; None when there is none; else why not."""
    try:
        with open(path, "rb") as handle:  # closed even when np.load fails half-way
            data = np.load(handle, allow_pickle=False)
            if not isinstance(data, np.lib.npyio.NpzFile):  # a plain .npy
                return "not an .npz archive"
            arrays = {name: data[name] for name in data.files}
    except (FileNotFoundError, NotADirectoryError):
        return None
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, NotImplementedError) as exc:
        return f"unreadable ({type(exc).__name__}: {exc})"
    if not all(isinstance(value, np.ndarray) for value in arrays.values()):  # a member that is not .npy reads as bytes
        return "a member that is not an array"
    return _meta_problem(arrays.pop(META, None), kind, key, arrays) or validate(arrays) or arrays


def _meta_problem(meta: np.ndarray | None, kind: str, key: str, arrays: Arrays) -> str | None:
    """Why an entry's metadata does not vouch for ``arrays`` under ``kind`` and ``key`` (None: it does)."""
    if meta is None:
        return f"no format version (an older metalens's entry; this one writes format {FORMAT})"
    try:
        fields = json.loads(str(meta))
        found = [fields["format"], fields["kind"], fields["key"], fields["sha256"]]
    except (ValueError, TypeError, KeyError):
        return "unreadable metadata"
    if found[0] != FORMAT:
        return f"format {found[0]!r}, expected {FORMAT}"
    if found[1:3] != [kind, key]:
        return f"written as {found[1]!r} entry {found[2]!r}"
    if found[3] != _checksum(arrays):
        return "checksum mismatch: the arrays changed after they were written"
    return None


def _checksum(arrays: Arrays) -> str:
    """SHA-256 of the arrays' names, dtypes, shapes and bytes (C order), by name."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        value = arrays[name]
        digest.update(json.dumps([name, value.dtype.str, list(value.shape)]).encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def _set_aside(path: Path, reason: str) -> None:
    """Rename a bad entry ``KEY.npz.bad`` and warn, naming it and ``reason``."""
    aside = path.with_name(path.name + ".bad")
    try:
        if aside.is_dir() and not aside.is_symlink():
            shutil.rmtree(aside)
        aside.unlink(missing_ok=True)  # the earlier one: a rename replaces no folder, nor a file by a folder
        os.replace(path, aside)
        fate = f"moved to {aside.name}"
    except OSError as exc:
        fate = f"left in place ({exc.strerror})"
    warnings.warn(f"cache entry {str(path)!r}: {reason}; {fate}, recomputing", CacheWarning, stacklevel=3)


def _store(path: Path, kind: str, key: str, arrays: Arrays) -> Path | None:
    """Write ``arrays`` with their metadata as the entry at ``path``; None (warned) when it cannot be."""
    meta = json.dumps({"format": FORMAT, "kind": kind, "key": key, "sha256": _checksum(arrays)})
    try:
        with atomic_write(path) as temporary:
            np.savez(temporary, **{META: np.array(meta)}, **arrays)
    except OSError as exc:
        _warn_unusable(exc)
        return None
    return path


@contextmanager
def _locked(path: Path) -> Iterator[bool]:
    """Hold the exclusive lock of the entry at ``path`` (creating its folder), waiting while
    another process holds it; yield False, having warned, when the folder cannot hold it."""
    lock = path.with_suffix(".lock")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor = _acquire(lock)
    except OSError as exc:
        _warn_unusable(exc)
        descriptor = None
    if descriptor is None:
        yield False
        return
    try:
        yield True
    finally:
        with suppress(OSError):  # before letting go: whoever waited on this file then takes the next one
            os.unlink(lock)
        os.close(descriptor)


def _acquire(lock: Path) -> int:
    """A descriptor of ``lock`` holding its flock, the file still at that path (a holder removes
    it before letting go: a waiter that then gets the lock of the removed file tries again)."""
    while True:
        descriptor = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX)
            with suppress(FileNotFoundError):
                if os.path.samestat(os.fstat(descriptor), os.stat(lock)):
                    return descriptor
        except BaseException:
            os.close(descriptor)
            raise
        os.close(descriptor)


def _warn_unusable(exc: OSError) -> None:
    """Warn, once per process and folder, that the cache folder cannot be used."""
    folder = str(cache_folder())
    if folder in _UNUSABLE_WARNED:
        return
    _UNUSABLE_WARNED.add(folder)
    warnings.warn(
        f"cache folder {folder!r} cannot be used ({exc.strerror or exc}): results are computed on every run, not "
        "stored (set METALENS_CACHE to a writable folder)",
        CacheWarning,
        stacklevel=4,
    )
