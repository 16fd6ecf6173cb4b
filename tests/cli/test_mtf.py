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
from metalens_cli.io.exr import write_exr_cube

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
    write_exr_cube(
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


@pytest.fixture
def field_file(tmp_path):
    """A field cube of 3 fields (0, 5°, 10° along +x), 2 depths, 3 wavelengths, with R, G, B: elliptic
    Gaussians σx = 1.5 + 0.5·field + 0.2·wavelength, σy = 1.5 + depth (pixels)."""
    y, x = np.mgrid[:32, :32] - 16
    sigmas = np.array([[[(1.5 + 0.5 * k + 0.2 * j, 1.5 + i) for j in range(3)] for i in range(2)] for k in range(3)])
    psf = np.exp(-(x**2) / (2 * sigmas[..., 0, None, None] ** 2) - y**2 / (2 * sigmas[..., 1, None, None] ** 2))
    angles = np.radians([0.0, 5.0, 10.0])
    chief = [[4e-3 * math.tan(a), 0.0] for a in angles]
    extra = {
        "na": 0.3,
        "field_angles_rad": angles.tolist(),
        "field_azimuth_rad": 0.0,
        "chief_ray_m": chief,
        "window_centre_px": [[round(c / PITCH), 0] for c, _ in chief],
    }
    path = tmp_path / "field.exr"
    write_exr_cube(
        path, psf, WAVELENGTHS, [0.045, math.inf], PITCH, "field test cube", rgb=psf[:, :, ::-1], extra=extra
    )
    return path, sigmas


def test_field_cube_json_csv_plot(capsys, tmp_path, field_file):
    path, sigmas = field_file
    table, plot = tmp_path / "field.csv", tmp_path / "field.png"
    code, out, err = invoke(capsys, "mtf", path, "--json", "--csv", table, "--plot", plot)
    assert code == 0 and err == "" and plot.stat().st_size > 0
    data = json.loads(out)
    assert data["field_azimuth_rad"] == 0.0 and len(data["curves"]) == 12  # radial curves: field 0
    fields = data["fields"]
    assert [f["field"] for f in fields] == [0, 1, 2] and [f["angle_deg"] for f in fields] == pytest.approx([0, 5, 10])
    assert set(fields[1]) == {"field", "angle_rad", "angle_deg", "chief_ray_m", "window_centre_px", "mtf50_lpmm"}
    assert fields[2]["window_centre_px"] == [381, 0] and fields[2]["chief_ray_m"][0] == pytest.approx(
        7.053e-4, rel=1e-3
    )
    records = fields[2]["mtf50_lpmm"]
    assert len(records) == 12 and set(records[0]) == {"depth_m", "wavelength_m", "tangential", "sagittal"}
    assert records[-1]["channel"] == "B" and records[-1]["depth_m"] is None
    # ψ = 0: tangential along x (σx = 2.9 px), sagittal along y (σy = 2.5 px); MTF50 =
    # √(ln 2/(2π²σ²))/p. The 32-px curves are h = 1/32 cycle/px apart: linear interpolation errs
    # by h²/8·|MTF''|/|MTF'| at the crossing, 1.1 % and 0.8 % of MTF50: rel 0.02.
    expected = np.sqrt(np.log(2) / (2 * np.pi**2 * sigmas[2, 1, 2] ** 2)) / PITCH * 1e-3
    wavelength_record = records[5]
    assert wavelength_record["depth_m"] is None and wavelength_record["wavelength_m"] == 630e-9
    assert wavelength_record["tangential"] == pytest.approx(expected[0], rel=0.02)
    assert wavelength_record["sagittal"] == pytest.approx(expected[1], rel=0.02)
    rows = list(csv.reader(table.open()))
    assert rows[0] == [
        "depth_m",
        "wavelength_m",
        "channel",
        "frequency_lpmm",
        "mtf",
        "field",
        "field_angle_deg",
        "direction",
    ]
    assert len(rows) == 1 + 12 * 17 + 3 * 12 * 2 * 17
    assert rows[1][5:] == ["0", "0.0", "radial"] and rows[-1][5] == "2" and rows[-1][7] == "sagittal"
    assert {row[7] for row in rows[1:]} == {"radial", "tangential", "sagittal"}
    code, out, _ = invoke(capsys, "mtf", path)
    assert code == 0 and "MTF50 over the field" in out and "MTF50 T (lp/mm)" in out


def test_a_field_cube_reads_as_its_field_0_on_axis(capsys, tmp_path, field_file):
    """The radial curves of a field cube are those of an on-axis cube holding its field 0, whose
    output has no field keys (the on-axis output is unchanged)."""
    from metalens_cli.io.exr import read_exr_cube

    path, _ = field_file
    cube = read_exr_cube(path)
    plain = tmp_path / "plain.exr"
    write_exr_cube(plain, cube.psf, WAVELENGTHS, [0.045, math.inf], PITCH, "field 0", rgb=cube.rgb, extra={"na": 0.3})
    field_data = json.loads(invoke(capsys, "mtf", path, "--json")[1])
    plain_data = json.loads(invoke(capsys, "mtf", plain, "--json")[1])
    assert field_data["curves"] == plain_data["curves"]
    assert "fields" not in plain_data and "field_azimuth_rad" not in plain_data
