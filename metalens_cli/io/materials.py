"""Parse the material a user names (``--material``, a preset key) into an optics material.

Accepted forms (whitespace around the text ignored):

- a built-in name, any case: ``sinx``, ``fused-silica``, ``tio2``, ``a-si``, ``air`` (or
  ``vacuum``); see :data:`metalens_cli.optics.materials.BUILTIN` for their sources;
- a number, a constant index: ``2.0`` or ``2.0+0.01j`` (n + ik with n > 0, k ≥ 0: absorbing in
  the exp(−iωt) convention; ``2.0-0.1j`` would be gain and is refused);
- ``cauchy:A,B[,C]``: n = A + B/λ² + C/λ⁴ with λ in µm;
- a path to a CSV file of a wavelength column and ``n`` (and ``k``): ``#`` comments and blank
  lines skipped, at least 2 rows of numbers, wavelengths strictly increasing within 100-10000
  nm (the rules of :mod:`metalens_cli.io.tables`), n > 0, k ≥ 0; interpolated linearly in
  wavelength and refused outside the table. The columns are read by the names of the header
  line (any case): the wavelength in nm first, named ``wavelength_nm``, ``wavelength``,
  ``lambda_nm`` or ``lambda``, then ``n`` and optionally ``k`` in either order
  (``wavelength_nm,k,n`` is read as named). A header naming other columns, or not ``n``, is
  refused; a file without a header (its first line numbers) is ``wavelength_nm,n[,k]``.

Dispersion models must give a refractive index where they are used: n > 0 everywhere, and
n ≥ 1 for the models of transparent dielectrics (Cauchy, Sellmeier), checked at every
wavelength a command evaluates (:meth:`metalens_cli.optics.materials.Material.index`).

A built-in name wins over a file of the same name in the working folder (write ``./sinx`` for
the file). Every error is one :class:`InputError` line naming the field and these forms.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_text
from metalens_cli.io.tables import read_spectrum_csv
from metalens_cli.optics.materials import BUILTIN, Cauchy, Constant, Material, Tabulated

MATERIAL_FORM = ("a built-in (sinx, fused-silica, tio2, a-si, air), a number such as 2.0 or 2.0+0.01j, "
                 "cauchy:A,B[,C] with λ in µm, or a CSV file wavelength_nm,n[,k]")
WAVELENGTH_NAMES = ("wavelength_nm", "wavelength", "lambda_nm", "lambda")
CSV_FORM = "a CSV file wavelength_nm,n[,k] (wavelengths in nm, ascending)"
HEADER_FORM = (f"a header naming the wavelength in nm first ({', '.join(WAVELENGTH_NAMES)}), then n and optionally k "
               "in either order, e.g. wavelength_nm,n,k")

_REAL = r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
_NONFINITE = r"[+-]?(?:nan|inf(?:inity)?)"
_PART = rf"(?:{_REAL}|{_NONFINITE})"
# A real number or n±kj (Python's complex literal; "nan" and "inf" are caught to be refused).
_NUMBER_RE = re.compile(rf"{_PART}(?:[+-](?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+|nan|inf(?:inity)?)(?:[eE][+-]?[0-9]+)?[jJ])?",
                        re.IGNORECASE)
_REAL_RE = re.compile(_REAL)


def _quote(text: str) -> str:
    """``repr`` of the user's text (one line), shortened when it is long."""
    return repr(text) if len(text) <= 60 else f"{text[:50]!r}… ({len(text)} characters)"


def _relabel(exc: InputError, field: str, prefix: str = "") -> InputError:
    """An error of the optics core (raised on field ``material``) as an error of ``field``."""
    return InputError(field, prefix + exc.message, exc.expected)


def parse_material(text: str, field: str) -> Material:
    """The material ``text`` names (the forms are in this module's docstring); an
    :class:`InputError` naming ``field`` and the accepted forms otherwise."""
    raw = str(text)
    s = raw.strip()
    if not s:
        raise InputError(field, "no material given", MATERIAL_FORM)
    if s.lower() in BUILTIN:
        return BUILTIN[s.lower()]
    if s.lower().startswith("cauchy:"):
        return _cauchy(s, field)
    compact = re.sub(r"\s+", "", s)
    if _NUMBER_RE.fullmatch(compact):
        return _constant(compact, raw, field)
    if not _looks_like_path(s):
        raise InputError(field, f"{_quote(raw)} is not a material", MATERIAL_FORM)
    return _table(Path(s), field)


def material_file(text: str) -> str | None:
    """The path ``text`` names when it is the CSV form (not a built-in, a number or Cauchy), else None."""
    s = str(text).strip()
    if not s or s.lower() in BUILTIN or s.lower().startswith("cauchy:") or _NUMBER_RE.fullmatch(re.sub(r"\s+", "", s)):
        return None
    return s if _looks_like_path(s) else None


def _constant(compact: str, raw: str, field: str) -> Constant:
    try:
        value = complex(compact)
    except ValueError:
        raise InputError(field, f"{_quote(raw)} is not a number", MATERIAL_FORM) from None
    if not (math.isfinite(value.real) and math.isfinite(value.imag)):
        raise InputError(field, f"{_quote(raw)} is not a finite index", "a finite index n or n+kj, e.g. 2.0 or 2.0+0.01j")
    if not value.real > 0:
        raise InputError(field, f"{_quote(raw)}: the index must have n > 0", "a constant index n > 0, e.g. 2.0 or 2.0+0.01j")
    if value.imag < 0:
        raise InputError(field, f"{_quote(raw)} has k < 0, which is gain",
                         "n+kj with k >= 0 (absorbing in the exp(-iωt) convention), e.g. 2.0+0.01j")
    try:
        return Constant(value, name=compact, source="user")
    except InputError as exc:
        raise _relabel(exc, field) from None


def _cauchy(s: str, field: str) -> Cauchy:
    form = "cauchy:A,B[,C] with n = A + B/λ² + C/λ⁴, λ in µm, e.g. cauchy:1.9,0.012"
    cells = [cell.strip() for cell in s.split(":", 1)[1].split(",")]
    if len(cells) not in (2, 3):
        raise InputError(field, f"{_quote(s)} has {len(cells)} coefficient{'s' if len(cells) != 1 else ''}", form)
    for cell in cells:
        if not _REAL_RE.fullmatch(cell):
            raise InputError(field, f"{_quote(cell)} in {_quote(s)} is not a number", form)
    values = [float(cell) for cell in cells]
    if not all(math.isfinite(v) for v in values):
        raise InputError(field, f"{_quote(s)} has a coefficient out of float range", form)
    try:
        return Cauchy(*values, name=re.sub(r"\s+", "", s), source="user")
    except InputError as exc:
        raise InputError(field, f"{_quote(s)}: {exc.message}", form) from None


def _looks_like_path(s: str) -> bool:
    """Whether ``s`` is meant as a file: it exists, holds a folder separator, or has a suffix
    such as ``.csv`` (not ``.01j``)."""
    return os.path.lexists(s) or "/" in s or os.sep in s or re.fullmatch(r"\.[A-Za-z][A-Za-z0-9]*", Path(s).suffix) is not None


def _table(path: Path, field: str) -> Tabulated:
    columns, n_at, k_at = _columns(path, read_text(path, field, CSV_FORM), field)
    rows = read_spectrum_csv(path, columns, field)  # the shared CSV rules, errors with line numbers
    for row in rows:
        if not row[n_at] > 0:
            raise InputError(field, f"{path.name}: n = {row[n_at]:g} at {row[0]:g} nm", "n > 0")
        if k_at is not None and row[k_at] < 0:
            raise InputError(field, f"{path.name}: k = {row[k_at]:g} at {row[0]:g} nm (gain)",
                             "k >= 0 (absorbing in the exp(-iωt) convention)")
    try:
        return Tabulated([row[0] / 1e9 for row in rows], [row[n_at] for row in rows],
                         None if k_at is None else [row[k_at] for row in rows], name=path.name, source=str(path))
    except InputError as exc:
        raise _relabel(exc, field, f"{path.name}: ") from None


def _columns(path: Path, text: str, field: str) -> tuple[int, int, int | None]:
    """(number of columns, index of n, index of k or None) of a material table, from its first
    line with content: a header (named as in the module docstring) or, when that line is
    numbers, the order wavelength_nm,n[,k]."""
    for line in text.splitlines():
        content = line.split("#", 1)[0].strip()
        if content:
            break
    else:
        raise InputError(field, f"{path.name}: no rows", CSV_FORM)
    cells = [cell.strip() for cell in content.split(",")]
    if all(_is_number(cell) for cell in cells):
        if len(cells) not in (2, 3):
            raise InputError(field, f"{path.name}: {len(cells)} columns and no header", f"{CSV_FORM}, or {HEADER_FORM}")
        return len(cells), 1, 2 if len(cells) == 3 else None
    names = [cell.strip("\"'").lower() for cell in cells]
    rest = names[1:]
    if names[0] not in WAVELENGTH_NAMES or "n" not in rest or not set(rest) <= {"n", "k"} or len(set(rest)) != len(rest):
        raise InputError(field, f"{path.name}: header {content!r} does not name its columns", HEADER_FORM)
    return len(names), 1 + rest.index("n"), 1 + rest.index("k") if "k" in rest else None


def _is_number(text: str) -> bool:
    """Whether ``float`` reads ``text``, as :func:`metalens_cli.io.tables.read_spectrum_csv` tells
    data from a header (``nan`` is a number there, refused later as not finite)."""
    try:
        float(text)
    except ValueError:
        return False
    return True
