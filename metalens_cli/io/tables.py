"""Spectral tables in CSV: ``wavelength_nm, value[, value…]`` rows (pure Python, no numpy).

Shared by the filter, camera-response, efficiency and material readers so that every CSV the
tool accepts follows one set of rules: blank lines and ``#`` comments skipped; an optional
header line whose names place the columns (``wavelength_nm,k,n`` is read as named; each
reader's :class:`Column` lists the names it accepts); at least two rows, finite numbers,
wavelengths strictly increasing in 100-10000 nm.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_text

OPTICAL_RANGE_NM = (100.0, 10000.0)  # wavelengths this tool models: UV to mid-infrared
PERCENT_THRESHOLD = 1.5  # a column whose maximum exceeds this is in percent
FRACTION_TOLERANCE = 0.05  # measurement noise tolerated outside 0..1 before clipping


@dataclass(frozen=True)
class Column:
    """A column of a spectral table: its ``name`` (its place when a file has no header) and the
    header ``aliases`` that name it (lower case; empty: any name the other columns do not take,
    for the one value of a two-column table, whose vendors name it every way)."""

    name: str
    aliases: tuple[str, ...] = ()
    optional: bool = False


WAVELENGTH = Column("wavelength_nm", ("wavelength_nm", "wavelength", "lambda_nm", "lambda", "nm", "wl"))
TRANSMISSION_TABLE = (WAVELENGTH, Column("transmission"))  # a filter: wavelength and one value, named any way


def read_table_csv(
    path: str | Path, columns: tuple[Column, ...], field: str
) -> tuple[list[list[float]], tuple[str, ...]]:
    """Rows of numbers, reordered as ``columns`` (wavelength in nm first), and the names of the
    columns present. A header line is read by its names (any case and order, quotes stripped);
    a name no column takes, a name twice, or a required column missing is refused listing the
    accepted names. Without a header the columns are in ``columns``' order (optional ones may be
    left off the end). Errors name ``field`` and the line."""
    path = Path(path)
    lines = read_text(path, field, "a CSV file").splitlines()
    order: list[int] | None = None
    names: tuple[str, ...] = ()
    rows: list[list[float]] = []
    for number, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        cells = [cell.strip() for cell in text.split(",")]
        try:
            values = [float(cell) for cell in cells]
        except ValueError:
            if order is not None:
                raise InputError(
                    field, f"{path.name}:{number}: not a number in {text!r}", f"numeric columns {', '.join(names)}"
                ) from None
            order, names = _header(cells, columns, path, field)
            continue
        if order is None:
            order, names = _unnamed(len(cells), columns, path, number, field)
        if len(values) != len(order):
            raise InputError(
                field, f"{path.name}:{number}: {len(values)} columns", f"{len(order)} columns: {', '.join(names)}"
            )
        rows.append([values[i] for i in order])
    _check(rows, path, field)
    return rows, names


def _header(cells: list[str], columns: tuple[Column, ...], path: Path, field: str) -> tuple[list[int], tuple[str, ...]]:
    """Where each present column is among ``cells`` (in ``columns``' order) and their names."""
    labels = [_label(cell) for cell in cells]
    found: dict[str, int] = {}
    for i, label in enumerate(labels):
        named = [c for c in columns if label in c.aliases] or [
            c for c in columns if not c.aliases and c.name not in found
        ]
        if not named or named[0].name in found:
            raise InputError(
                field, f"{path.name}: header {','.join(cells)!r} does not name its columns", _header_form(columns)
            )
        found[named[0].name] = i
    missing = [c.name for c in columns if not c.optional and c.name not in found]
    if missing:
        raise InputError(
            field, f"{path.name}: header {','.join(cells)!r} lacks {', '.join(missing)}", _header_form(columns)
        )
    present = tuple(c.name for c in columns if c.name in found)
    return [found[name] for name in present], present


def _label(cell: str) -> str:
    """A header cell as matched against the aliases: lower case, quotes and a unit in brackets
    dropped, spaces as underscores (``"Wavelength (nm)"`` → ``wavelength``)."""
    text = re.sub(r"[(\[].*?[)\]]", "", cell.strip().strip("\"'").lower())
    return re.sub(r"\s+", "_", text.strip()).strip("_")


def _unnamed(
    count: int, columns: tuple[Column, ...], path: Path, number: int, field: str
) -> tuple[list[int], tuple[str, ...]]:
    """The columns of a table without a header: the first ``count`` of ``columns``."""
    required = sum(not c.optional for c in columns)
    if not required <= count <= len(columns):
        accepted = " or ".join(str(n) for n in range(required, len(columns) + 1))
        raise InputError(
            field,
            f"{path.name}:{number}: {count} columns and no header",
            f"{accepted} columns {','.join(c.name for c in columns)}, or {_header_form(columns)}",
        )
    return list(range(count)), tuple(c.name for c in columns[:count])


def _header_form(columns: tuple[Column, ...]) -> str:
    """The accepted header names, for an error's 'expected' part."""
    parts = [
        f"{c.name}{' (optional)' if c.optional else ''}: {' or '.join(c.aliases) if c.aliases else 'any other name'}"
        for c in columns
    ]
    return "a header naming its columns, in any order (" + "; ".join(parts) + ")"


def _check(rows: list[list[float]], path: Path, field: str) -> None:
    if len(rows) < 2:
        raise InputError(field, f"{path.name}: fewer than 2 data rows", "a tabulated spectrum")
    if not all(math.isfinite(v) for row in rows for v in row):
        raise InputError(field, f"{path.name}: non-finite values", "finite numbers")
    wavelengths = [row[0] for row in rows]
    if any(b <= a for a, b in zip(wavelengths, wavelengths[1:])):
        raise InputError(
            field, f"{path.name}: wavelengths not strictly increasing", "one row per wavelength, ascending"
        )
    if wavelengths[0] < OPTICAL_RANGE_NM[0] or wavelengths[-1] > OPTICAL_RANGE_NM[1]:
        raise InputError(
            field, f"{path.name}: wavelengths {wavelengths[0]:g}-{wavelengths[-1]:g} do not look like nm", "nanometres"
        )


def check_wavelengths(values_m, field: str) -> None:
    """Refuse wavelengths (metres) outside ``OPTICAL_RANGE_NM``: a metre-long "wavelength" is a
    typo, and would image as an all-dark PSF."""
    lo, hi = (v * 1e-9 for v in OPTICAL_RANGE_NM)
    for value in values_m:
        if not lo <= value <= hi:
            raise InputError(
                field,
                f"{value * 1e9:g} nm is not an optical wavelength",
                f"wavelengths within {OPTICAL_RANGE_NM[0]:g}-{OPTICAL_RANGE_NM[1]:g} nm",
            )


def as_fractions(values: list[float], field: str, path: str | Path) -> list[float]:
    """Fractions in 0..1 from a column in 0..1 or in percent (maximum above 1.5), clipped."""
    if max(values) > PERCENT_THRESHOLD:
        values = [v / 100.0 for v in values]
    if min(values) < -FRACTION_TOLERANCE or max(values) > 1 + FRACTION_TOLERANCE:
        raise InputError(field, f"{Path(path).name}: values outside 0..1 (or 0..100 %)", "fractions or percent")
    return [min(max(v, 0.0), 1.0) for v in values]
