"""`metalens mtf` end to end: JSON keys, CSV, plots, table, one-line errors."""

import csv
import json
import math

import cv2
import numpy as np
import OpenEXR
import pytest
from synthetic import render_edge

from metalens_cli.cli.main import run
from metalens_cli.io.exr import write_psf_cube

PITCH = 1.85e-6
WAVELENGTHS = [450e-9, 530e-9, 630e-9]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def cube_file(tmp_path):
    """Gaussian PSFs (σ = 1 … 3.5 px) at 45 mm and infinity, 3 wavelengths, R, G, B channels, NA 0.3."""
    y, x = np.mgrid[:32, :32] - 16
    psf = np.array([[np.exp(-(x**2 + y**2) / (2 * (1 + i + 0.5 * j) ** 2)) for j in range(3)] for i in range(2)])
    path = tmp_path / "cube.exr"
    write_psf_cube(
        path, psf, WAVELENGTHS, [0.045, math.inf], PITCH, "gaussian test cube", rgb=psf[:, ::-1], extra={"na": 0.3}
    )
    return path


def test_cube_json_csv_plot(capsys, tmp_path, cube_file):
    table, plot = tmp_path / "mtf.csv", tmp_path / "mtf.png"
    code, out, err = invoke(capsys, "mtf", cube_file, "--at", "50,100", "--json", "--csv", table, "--plot", plot)
    assert code == 0 and err == ""
    data = json.loads(out)
    assert {"frequencies_lpmm", "curves"} <= set(data) and data["na"] == 0.3 and data["pixel_mtf"] == "included"
    assert data["frequencies_lpmm"][-1] == pytest.approx(1e3 / 3.7)  # Nyquist of 1.85 µm pixels
    curves = data["curves"]
    assert len(curves) == 2 * 3 + 2 * 3
    assert set(curves[0]) == {"depth_m", "wavelength_m", "mtf", "mtf50_lpmm", "mtf_at"}
    assert set(curves[-1]) == {"depth_m", "channel", "mtf", "mtf50_lpmm", "mtf_at"}
    assert curves[0]["depth_m"] == 0.045 and curves[3]["depth_m"] is None and curves[-1]["channel"] == "B"
    assert all(len(c["mtf"]) == len(data["frequencies_lpmm"]) and len(c["mtf_at"]) == 2 for c in curves)
    assert len(data["diffraction_limited"]) == 3 and plot.stat().st_size > 0
    rows = list(csv.reader(table.open()))
    assert rows[0] == ["depth_m", "wavelength_m", "channel", "frequency_lpmm", "mtf"]
    assert len(rows) == 1 + 12 * 17 and rows[-1][0] == "inf" and rows[-1][2] == "B"


def test_cube_table_and_removed_pixel_mtf(capsys, cube_file):
    code, out, _ = invoke(capsys, "mtf", cube_file, "--at", "100")
    assert code == 0 and "MTF50 (lp/mm)" in out and "pixel aperture included" in out
    code, out, _ = invoke(capsys, "mtf", cube_file, "--remove-pixel-mtf", "--na", "0.1", "--json")
    data = json.loads(out)
    assert code == 0 and data["pixel_mtf"] == "removed" and data["na"] == 0.1 and "mtf_at" not in data["curves"][0]


def test_edge_json_csv_plot(capsys, tmp_path):
    image, table, plot = tmp_path / "edge.png", tmp_path / "edge.csv", tmp_path / "edge.png.png"
    edge = render_edge(96, 96, 5.0, 1.0)
    cv2.imwrite(str(image), np.round(np.dstack([edge] * 3) * 65535).astype(np.uint16))
    code, out, err = invoke(
        capsys, "mtf", "--edge", image, "--pixel-pitch", "1.85um", "--json", "--csv", table, "--plot", plot
    )
    assert code == 0 and err == ""
    data = json.loads(out)
    assert [e["channel"] for e in data["edge"]] == ["R", "G", "B"]
    entry = data["edge"][0]
    assert set(entry) == {
        "channel",
        "angle_deg",
        "frequencies_cy_per_px",
        "mtf",
        "mtf50_cy_per_px",
        "frequencies_lpmm",
        "mtf50_lpmm",
    }
    assert entry["angle_deg"] == pytest.approx(5.0, abs=0.05)
    assert entry["mtf50_lpmm"] == pytest.approx(entry["mtf50_cy_per_px"] / 1.85e-3)
    rows = list(csv.reader(table.open()))
    assert rows[0] == ["channel", "angle_deg", "frequency_cy_per_px", "frequency_lpmm", "mtf"]
    assert len(rows) == 1 + 3 * len(entry["mtf"]) and plot.stat().st_size > 0
    code, out, _ = invoke(capsys, "mtf", "--edge", image)
    assert code == 0 and "MTF50 (cy/px)" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["nothing.exr"], "no such file"),
        (["CUBE", "--at", "300"], "outside the frequency axis"),
        (["CUBE", "--at", "fifty"], "not a list of numbers"),
        (["CUBE", "--roi", "1,2,3,4"], "--roi only applies with --edge"),
        (["CUBE", "--edge", "EDGE"], "either a PSF cube"),
        (["--edge", "EDGE", "--at", "50"], "--at only applies to a PSF cube"),
        (["--edge", "FLAT"], "no edge"),
        (["BAD"], "not a readable OpenEXR file"),
        (["FOREIGN"], "no 'metalens' header attribute"),
    ],
)
def test_errors_are_one_line_exit_2(capsys, tmp_path, cube_file, args, message):
    edge, flat, bad = tmp_path / "e.png", tmp_path / "flat.png", tmp_path / "bad.exr"
    cv2.imwrite(str(edge), np.round(render_edge(64, 64, 0.3, 1.0) * 255).astype(np.uint8))
    cv2.imwrite(str(flat), np.full((64, 64), 128, np.uint8))
    bad.write_text("not an EXR")
    foreign = tmp_path / "foreign.exr"  # a valid EXR image that is not a PSF cube
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Y": np.ones((8, 8), np.float32)}).write(str(foreign))
    paths = {"CUBE": cube_file, "EDGE": edge, "FLAT": flat, "BAD": bad, "FOREIGN": foreign}
    code, out, err = invoke(capsys, "mtf", *[paths.get(a, a) for a in args])
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("metalens: error:") and message in err
