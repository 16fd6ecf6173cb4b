"""A catalogue of filters one can buy, for a learned filter to snap to (``[filter] catalogue``).

CSV with a header ``name, center_nm, fwhm_nm, edge_nm, peak``: one row per pass band; the rows
of one ``name`` are one multi-band filter (bands in any order). ``edge_nm`` is the 10-90 % edge
width, ``peak`` the peak transmission (0-1 or percent). Wavelengths in the file are nm; the
filters come back in metres.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_text
from metalens_cli.optics.band_rules import check_bands

COLUMNS = ("name", "center_nm", "fwhm_nm", "edge_nm", "peak")
FORM = (
    "a CSV with the header name,center_nm,fwhm_nm,edge_nm,peak: one row per pass band, a filter's bands under one name"
)


@dataclass(frozen=True)
class CatalogueFilter:
    """One purchasable filter: band centres and FWHMs (ascending centres), edge width, peak (m, 0-1)."""

    name: str
    centers_m: tuple[float, ...]
    widths_m: tuple[float, ...]
    edge_width_m: float
    peak_transmission: float


def read_catalogue(path: str | Path, field: str = "filter.catalogue") -> list[CatalogueFilter]:
    """The filters of a catalogue CSV, in the order of their first row; a row listed twice, a
    filter whose bands overlap or are narrower than its edges allow is refused naming its rows."""
    text = read_text(Path(path), field, FORM)
    rows = list(csv.reader(line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")))
    if not rows or [c.strip().lower() for c in rows[0]] != list(COLUMNS):
        raise InputError(field, f"{Path(path).name} does not start with the header {','.join(COLUMNS)}", FORM)
    bands: dict[str, list[tuple[float, float, float, float]]] = {}
    first_row: dict[tuple, int] = {}
    for number, row in enumerate(rows[1:], start=2):
        if len(row) != len(COLUMNS):
            raise InputError(field, f"{Path(path).name} row {number} has {len(row)} fields", FORM)
        try:
            centre, fwhm, edge, peak = (float(v) for v in row[1:])
        except ValueError:
            raise InputError(
                field, f"{Path(path).name} row {number} holds a value that is not a number", FORM
            ) from None
        peak = peak / 100 if peak > 1.5 else peak
        if not (all(math.isfinite(v) and v > 0 for v in (centre, fwhm, edge)) and 0 < peak <= 1):
            raise InputError(
                field, f"{Path(path).name} row {number}: {row}", "positive centre, FWHM and edge (nm), peak in (0, 1]"
            )
        key = (row[0].strip(), centre, fwhm, edge, peak)
        if key in first_row:
            raise InputError(
                field, f"{Path(path).name} row {number} repeats row {first_row[key]}", "each band of a filter once"
            )
        first_row[key] = number
        bands.setdefault(row[0].strip(), []).append((centre * 1e-9, fwhm * 1e-9, edge * 1e-9, peak))
    if not bands:
        raise InputError(field, f"{Path(path).name} lists no filter", FORM)
    out = []
    for name, entries in bands.items():
        entries.sort()
        if len({(e[2], e[3]) for e in entries}) != 1:
            raise InputError(
                field, f"filter {name!r} has bands with different edges or peaks", "one edge_nm and peak per filter"
            )
        try:
            check_bands([e[0] for e in entries], [e[1] for e in entries], entries[0][2], entries[0][3])
        except InputError as exc:
            raise InputError(field, f"{Path(path).name}: filter {name!r}: {exc.message}", exc.expected) from None
        out.append(
            CatalogueFilter(
                name, tuple(e[0] for e in entries), tuple(e[1] for e in entries), entries[0][2], entries[0][3]
            )
        )
    return out
