"""An on-disk cache of computed arrays, keyed by a hash of everything that went into them.

Entries are ``.npz`` files under ``$METALENS_CACHE``, else ``$XDG_CACHE_HOME/metalens``, else
``~/.cache/metalens``, in one folder per kind (``nanofin``, ``nanofin-sweep``). The key is the
SHA-256 of the inputs written as canonical JSON (sorted keys; arrays as lists), so a changed
input (a geometry, an index at one wavelength, a solver version) is a different entry and a
stale one is never read. Entries are written to a temporary file and renamed: a reader sees a
whole entry or none, and two processes computing the same entry both succeed. A cache that
cannot be written (read-only home, full disk) only costs the recomputation next time.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from metalens_cli.io.atomic import atomic_write


def cache_folder() -> Path:
    """The cache's root folder (not created)."""
    if os.environ.get("METALENS_CACHE"):
        return Path(os.environ["METALENS_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "metalens"


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
    return cache_folder() / kind / f"{key}.npz"


def load(kind: str, key: str) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``key``, or None when there are none (or the entry is unreadable)."""
    path = entry_path(kind, key)
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return None


def store(kind: str, key: str, arrays: dict[str, np.ndarray]) -> Path | None:
    """Write ``arrays`` under ``key``; the entry's path, or None when the cache is not writable."""
    path = entry_path(kind, key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path) as temporary:
            np.savez(temporary, **arrays)
    except OSError:
        return None
    return path
