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
  wavelength and refused outside the table. A header line places the columns by name, in any
  order and case (:func:`metalens_cli.io.tables.read_table_csv`): the wavelength in nm
  (``wavelength_nm``, ``wavelength``, ``lambda_nm``, ``lambda``, ``nm``, ``wl``; a unit in
  brackets is ignored), ``n`` and optionally ``k`` (``wavelength_nm,k,n`` is read as named). A
  header naming other columns, or not ``n``, is refused; a file without a header is
  ``wavelength_nm,n[,k]``.

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
from metalens_cli.io.tables import WAVELENGTH, Column, read_table_csv
from metalens_cli.optics.materials import BUILTIN, Cauchy, Constant, Material, Tabulated

MATERIAL_FORM = (
    "a built-in (sinx, fused-silica, tio2, a-si, air), a number such as 2.0 or 2.0+0.01j, "
    "cauchy:A,B[,C] with λ in µm, or a CSV file wavelength_nm,n[,k]"
)
MATERIAL_TABLE = (WAVELENGTH, Column("n", ("n",)), Column("k", ("k",), optional=True))

_REAL = r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
_NONFINITE = r"[+-]?(?:nan|inf(?:inity)?)"
_PART = rf"(?:{_REAL}|{_NONFINITE})"
# A real number or n±kj (Python's complex literal; "nan" and "inf" are caught to be refused).
_NUMBER_RE = re.compile(
    rf"{_PART}(?:[+-](?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+|nan|inf(?:inity)?)(?:[eE][+-]?[0-9]+)?[jJ])?", re.IGNORECASE
)
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
        raise InputError(
            field, f"{_quote(raw)} is not a finite index", "a finite index n or n+kj, e.g. 2.0 or 2.0+0.01j"
        )
    if not value.real > 0:
        raise InputError(
            field, f"{_quote(raw)}: the index must have n > 0", "a constant index n > 0, e.g. 2.0 or 2.0+0.01j"
        )
    if value.imag < 0:
        raise InputError(
            field,
            f"{_quote(raw)} has k < 0, which is gain",
            "n+kj with k >= 0 (absorbing in the exp(-iωt) convention), e.g. 2.0+0.01j",
        )
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
    return (
        os.path.lexists(s)
        or "/" in s
        or os.sep in s
        or re.fullmatch(r"\.[A-Za-z][A-Za-z0-9]*", Path(s).suffix) is not None
    )


def _table(path: Path, field: str) -> Tabulated:
    rows, names = read_table_csv(path, MATERIAL_TABLE, field)  # the shared CSV rules, errors with line numbers
    has_k = "k" in names
    for row in rows:
        if not row[1] > 0:
            raise InputError(field, f"{path.name}: n = {row[1]:g} at {row[0]:g} nm", "n > 0")
        if has_k and row[2] < 0:
            raise InputError(
                field,
                f"{path.name}: k = {row[2]:g} at {row[0]:g} nm (gain)",
                "k >= 0 (absorbing in the exp(-iωt) convention)",
            )
    try:
        return Tabulated(
            [row[0] / 1e9 for row in rows],
            [row[1] for row in rows],
            [row[2] for row in rows] if has_k else None,
            name=path.name,
            source=str(path),
        )
    except InputError as exc:
        raise _relabel(exc, field, f"{path.name}: ") from None
