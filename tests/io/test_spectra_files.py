"""Measured spectra from CSV files (io.spectra_files): exact decimal tables interpolated
linearly, percent detected, garbage refused with the field and the reason."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from metalens_cli.errors import InputError
from metalens_cli.io import spectra_files
from metalens_cli.optics import spectra

NM = 1e-9
PAPER_CENTRES = np.array([457, 530, 628]) * NM


def test_filter_csv_in_percent_with_header(tmp_path):
    path = tmp_path / "filter.csv"
    path.write_text("wavelength_nm,transmission_percent\n500,0\n510,80\n520,90\n530,0\n")
    transmission = spectra_files.filter_from_csv(path, np.array([490, 505, 515, 520, 540]) * NM)
    # Linear interpolation of exact decimal inputs: float64 rounding only.
    assert_allclose(transmission, [0.0, 0.4, 0.85, 0.9, 0.0], atol=1e-12)


def test_filter_csv_refuses_garbage(tmp_path):
    path = tmp_path / "filter.csv"
    path.write_text("wavelength_nm,t\n500,0.1\n490,0.2\n")
    with pytest.raises(InputError, match="increasing"):
        spectra_files.filter_from_csv(path, spectra.wavelength_grid())
    path.write_text("500,0.1\n510,abc\n")
    with pytest.raises(InputError, match="not a number"):
        spectra_files.filter_from_csv(path, spectra.wavelength_grid())
    path.write_text("5.0e-7,0.1\n5.1e-7,0.2\n")
    with pytest.raises(InputError, match="nm"):
        spectra_files.filter_from_csv(path, spectra.wavelength_grid())
    with pytest.raises(InputError, match="no such file"):
        spectra_files.filter_from_csv(tmp_path / "missing.csv", spectra.wavelength_grid())


def test_efficiency_csv_and_refusals(tmp_path):
    path = tmp_path / "eta.csv"
    path.write_text("# RCWA\n457,78.4\n530,72.9\n628,66.9\n")
    assert_allclose(spectra_files.efficiency_from_csv(path, PAPER_CENTRES), [0.784, 0.729, 0.669], atol=1e-12)
    with pytest.raises(InputError, match="0..1"):
        spectra.efficiency_from_table(PAPER_CENTRES, PAPER_CENTRES, [78.4, 72.9, 66.9])


def test_camera_csv_and_unknown_name(tmp_path):
    path = tmp_path / "crf.csv"
    path.write_text("wavelength_nm,r,g,b\n400,0,0,1\n600,1,0.5,-0.01\n")
    assert_allclose(spectra_files.camera_from_csv(path, np.array([500 * NM])), [[0.5], [0.25], [0.5]], atol=1e-12)
    assert np.all(
        spectra_files.camera_from_csv(path, np.array([300 * NM, 700 * NM])) == 0
    )  # no response outside the table
    with pytest.raises(InputError, match="unknown camera"):
        spectra.camera_response(spectra.wavelength_grid(), "Canon 5D")


def test_a_camera_table_is_read_by_its_header_in_any_order(tmp_path):
    """B, G, R as a vendor writes them (OpenCV's order) are R, G, B by name; without a header the
    order is wavelength, r, g, b; a header naming a channel twice or missing one is refused."""
    grid = np.array([450, 550, 650]) * NM
    rows = [(400, 0.1, 0.2, 0.9), (700, 0.7, 0.3, 0.0)]  # wavelength, r, g, b
    plain = tmp_path / "plain.csv"
    plain.write_text("".join(f"{w},{r},{g},{b}\n" for w, r, g, b in rows))
    named = tmp_path / "named.csv"
    named.write_text("Wavelength (nm),Blue,G,r\n" + "".join(f"{w},{b},{g},{r}\n" for w, r, g, b in rows))
    expected = np.array([[0.1 + (0.7 - 0.1) * t, 0.2 + 0.1 * t, 0.9 * (1 - t)] for t in (1 / 6, 0.5, 5 / 6)]).T
    assert_allclose(spectra_files.camera_from_csv(plain, grid), expected, atol=1e-12)
    assert_allclose(spectra_files.camera_from_csv(named, grid), expected, atol=1e-12)
    for header, why in (
        ("nm,r,g,g", "does not name its columns"),
        ("nm,r,g,x", "does not name its columns"),
        ("nm,r,g", "lacks b"),
    ):
        named.write_text(f"{header}\n400,0.1,0.2,0.9\n700,0.7,0.3,0.0\n")
        with pytest.raises(InputError, match=f"camera: named.csv: header '{header}' {why}.*r: r or red"):
            spectra_files.camera_from_csv(named, grid)


def test_a_filter_table_with_the_wavelength_last_is_read_as_named(tmp_path):
    path = tmp_path / "filter.csv"
    path.write_text("T (%),Wavelength [nm]\n0,500\n80,510\n90,520\n0,530\n")
    transmission = spectra_files.filter_from_csv(path, np.array([505, 515]) * NM)
    assert_allclose(transmission, [0.4, 0.85], atol=1e-12)
