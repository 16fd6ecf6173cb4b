"""Spectral tables in CSV: ``wavelength_nm, value[, value…]`` rows (pure Python, no numpy).

Shared by the filter, camera-response and efficiency readers so that every CSV the tool
accepts follows one set of rules: an optional header line, blank lines and ``#`` comments
skipped, at least two rows, finite numbers, wavelengths strictly increasing in 100-10000 nm.
"""

from __future__ import annotations

import math
from pathlib import Path

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_text

OPTICAL_RANGE_NM = (100.0, 10000.0)  # wavelengths this tool models: UV to mid-infrared
PERCENT_THRESHOLD = 1.5  # a column whose maximum exceeds this is in percent
FRACTION_TOLERANCE = 0.05  # measurement noise tolerated outside 0..1 before clipping


def read_spectrum_csv(path: str | Path, columns: int, field: str) -> list[list[float]]:
    """Rows of ``columns`` numbers, wavelength (nm) first; errors name ``field`` and the line."""
    path = Path(path)
    lines = read_text(path, field, "a CSV file").splitlines()
    rows: list[list[float]] = []
    seen_line = False
    for number, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        cells = [cell.strip() for cell in text.split(",")]
        try:
            row = [float(cell) for cell in cells]
        except ValueError:
            if seen_line:
                raise InputError(field, f"{path.name}:{number}: not a number in {text!r}", f"{columns} numeric columns") from None
            seen_line = True  # the header
            continue
        seen_line = True
        if len(row) != columns:
            raise InputError(field, f"{path.name}:{number}: {len(row)} columns", f"{columns} columns, wavelength_nm first")
        rows.append(row)
    _check(rows, path, field)
    return rows


def _check(rows: list[list[float]], path: Path, field: str) -> None:
    if len(rows) < 2:
        raise InputError(field, f"{path.name}: fewer than 2 data rows", "a tabulated spectrum")
    if not all(math.isfinite(v) for row in rows for v in row):
        raise InputError(field, f"{path.name}: non-finite values", "finite numbers")
    wavelengths = [row[0] for row in rows]
    if any(b <= a for a, b in zip(wavelengths, wavelengths[1:])):
        raise InputError(field, f"{path.name}: wavelengths not strictly increasing", "one row per wavelength, ascending")
    if wavelengths[0] < OPTICAL_RANGE_NM[0] or wavelengths[-1] > OPTICAL_RANGE_NM[1]:
        raise InputError(field, f"{path.name}: wavelengths {wavelengths[0]:g}-{wavelengths[-1]:g} do not look like nm", "nanometres")


def check_wavelengths(values_m, field: str) -> None:
    """Refuse wavelengths (metres) outside ``OPTICAL_RANGE_NM``: a metre-long "wavelength" is a
    typo, and would image as an all-dark PSF."""
    lo, hi = (v * 1e-9 for v in OPTICAL_RANGE_NM)
    for value in values_m:
        if not lo <= value <= hi:
            raise InputError(field, f"{value * 1e9:g} nm is not an optical wavelength", f"wavelengths within {OPTICAL_RANGE_NM[0]:g}-{OPTICAL_RANGE_NM[1]:g} nm")


def as_fractions(values: list[float], field: str, path: str | Path) -> list[float]:
    """Fractions in 0..1 from a column in 0..1 or in percent (maximum above 1.5), clipped."""
    if max(values) > PERCENT_THRESHOLD:
        values = [v / 100.0 for v in values]
    if min(values) < -FRACTION_TOLERANCE or max(values) > 1 + FRACTION_TOLERANCE:
        raise InputError(field, f"{Path(path).name}: values outside 0..1 (or 0..100 %)", "fractions or percent")
    return [min(max(v, 0.0), 1.0) for v in values]
