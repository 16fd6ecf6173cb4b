"""psf-scan over the field: a field cube (EXR), per-field JSON, and its refusals."""

import json
import math

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.io.exr import read_exr_cube

SMALL = ["--design", "hyperbolic:532nm", "--f", "200um", "--aperture", "100um", "--pixels", "31"]
SMALL += ["--pixel-pitch", "1um", "--wavelengths", "500nm,560nm", "--depths", "10mm,inf"]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_field_scan_writes_a_field_cube_whose_field_zero_is_the_on_axis_scan(capsys, tmp_path):
    field_file, axis_file = tmp_path / "field.exr", tmp_path / "axis.exr"
    code, out, _ = invoke(capsys, "psf-scan", *SMALL, "--field-angles", "0:8:4deg", "-o", field_file, "--json")
    assert code == 0
    report = json.loads(out)
    assert [round(f["angle_deg"], 9) for f in report["fields"]] == [0, 4, 8]
    assert invoke(capsys, "psf-scan", *SMALL, "-o", axis_file)[0] == 0
    cube, axis = read_exr_cube(field_file), read_exr_cube(axis_file)
    assert cube.field_psf.shape == (3, 2, 2, 31, 31)
    np.testing.assert_array_equal(cube.psf, axis.psf)  # field 0 is what on-axis readers read
    np.testing.assert_allclose(cube.field_angles_rad, np.radians([0, 4, 8]), rtol=1e-12)
    for f, (x, y), (col, row) in zip(report["fields"], cube.chief_ray_m, cube.window_centre_px):
        # a flat-centred lens: the chief ray at f·tan α, the window centred on its pixel
        assert x == pytest.approx(200e-6 * math.tan(f["angle_rad"]), rel=1e-9) and y == 0
        assert (col, row) == (round(x / 1e-6), 0) and f["window_centre_px"] == [col, row]
        for psf in f["psfs"]:
            assert psf["energy_in_window"] > 0.97
            assert psf["fwhm_tangential_m"] > 0 and psf["ee80_radius_m"] >= psf["ee50_radius_m"]
    # coma pushes the in-focus (532 nm is near the design λ, ∞) centroid outward, more at 8° than at 4°
    offsets = [f["psfs"][3]["centroid_from_chief_ray_m"][0] for f in report["fields"]]
    assert abs(offsets[0]) < 1e-9 and 0 < offsets[1] < offsets[2]
    np.testing.assert_allclose(cube.metadata["field_kept"], cube.field_psf.sum(axis=(-2, -1)), rtol=1e-6)


def test_field_heights_are_chief_ray_positions(capsys, tmp_path):
    out_file = tmp_path / "f.exr"
    plot = tmp_path / "fields.png"
    code, out, _ = invoke(
        capsys, "psf-scan", *SMALL, "--field-heights", "0um,20um", "-o", out_file, "--plot", plot, "--json"
    )
    assert code == 0
    assert json.loads(out)["plot"] == str(plot) and plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    fields = json.loads(out)["fields"]
    assert fields[1]["angle_rad"] == pytest.approx(math.atan(20e-6 / 200e-6))
    assert fields[1]["chief_ray_m"][0] == pytest.approx(20e-6) and fields[1]["window_centre_px"] == [20, 0]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--field-angles", "0deg,5deg", "-o", "{tmp}/f.npz"], "written as .exr"),
        (["--field-angles", "5deg", "--field-heights", "3um", "-o", "{tmp}/f.exr"], "--field-heights"),
        (["--field-angles", "5deg", "--propagator", "radial", "-o", "{tmp}/f.exr"], "--propagator"),
        (["--field-angles", "5deg,5deg", "-o", "{tmp}/f.exr"], "--field-angles: the fields repeat"),
        # within psf compare's 1e-6 rad: the same field
        (["--field-angles", "5deg,5.00000000001deg", "-o", "{tmp}/f.exr"], "--field-angles: the fields repeat"),
        (["--field-heights", "0um,10um,0um", "-o", "{tmp}/f.exr"], "--field-heights: the fields repeat"),
        (["--field-angles", "95deg", "-o", "{tmp}/f.exr"], "--field-angles"),
        (["--field-angles", "0:5deg", "-o", "{tmp}/f.exr"], "--field-angles"),
        (["--field-angles", "5deg", "--field-azimuth", "400deg", "-o", "{tmp}/f.exr"], "--field-azimuth"),
        (["--field-azimuth", "90deg", "-o", "{tmp}/f.exr"], "--field-azimuth: given without fields"),
    ],
)
def test_field_scan_refusals(capsys, tmp_path, args, message):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    code, _, err = invoke(capsys, "psf-scan", *SMALL, *args)
    assert code == 2 and message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())
