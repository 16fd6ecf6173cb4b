"""Measured spectra from CSV files (rows ``wavelength_nm, value…``; the rules of
:mod:`metalens_cli.io.tables`): a camera's response, a filter's transmission, the nanofin's
efficiency. Each returns values on the wavelengths asked for (metres), interpolated linearly;
errors name ``field`` (a preset passes its key).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metalens_cli.io.tables import TRANSMISSION_TABLE, WAVELENGTH, Column, as_fractions, read_table_csv
from metalens_cli.optics.spectra import efficiency_from_table, tabulated_response

_NM = 1e-9
CAMERA_TABLE = (WAVELENGTH, Column("r", ("r", "red")), Column("g", ("g", "green")), Column("b", ("b", "blue")))
EFFICIENCY_TABLE = (WAVELENGTH, Column("efficiency"))


def _read(path: str | Path, columns: tuple[Column, ...], field: str) -> np.ndarray:
    """(rows, columns) float64 in ``columns``' order, wavelengths still in nm."""
    return np.array(read_table_csv(Path(path), columns, field)[0], dtype=float)


def camera_from_csv(path: str | Path, wavelengths_m: np.ndarray, field: str = "camera") -> np.ndarray:
    """CRF^c (3, L), channels R, G, B, from a CSV ``wavelength_nm, r, g, b`` (a header, if any,
    places the columns by name: ``nm,B,G,R`` is read as named); zero outside the table (no
    measured response), negative values (noise) clipped to zero."""
    data = _read(path, CAMERA_TABLE, field)
    return tabulated_response(wavelengths_m, data[:, 0], np.clip(data[:, 1:].T, 0.0, None))


def filter_from_csv(path: str | Path, wavelengths_m: np.ndarray, field: str = "filter") -> np.ndarray:
    """Transmission (L,) from a CSV (wavelength_nm, transmission; header optional).

    Transmission in 0..1, or in percent when the column's maximum exceeds 1.5. Values are
    clipped to [0, 1] after a tolerance of 0.05 for measurement noise. Zero outside the
    tabulated range (light there is taken as blocked).
    """
    data = _read(path, TRANSMISSION_TABLE, field)
    values = np.array(as_fractions(data[:, 1].tolist(), field, path))
    return tabulated_response(wavelengths_m, data[:, 0], values[None])[0]


def efficiency_from_csv(path: str | Path, wavelengths_m: np.ndarray, field: str = "efficiency") -> np.ndarray:
    """η(λ) (L,) from a CSV (wavelength_nm, efficiency as a fraction or in percent; header
    optional); percent detected as for :func:`filter_from_csv`, flat beyond the table."""
    data = _read(path, EFFICIENCY_TABLE, field)
    values = np.array(as_fractions(data[:, 1].tolist(), field, path))
    return efficiency_from_table(wavelengths_m, data[:, 0] * _NM, values)
