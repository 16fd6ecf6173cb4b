"""`metalens psf import` and `psf compare` end to end: bench frames → cube → mtf and compare;
one-line errors with nothing written."""

import json

import cv2
import numpy as np
import OpenEXR
import pytest
from synthetic import bench_frame, gaussian_spot

from metalens_cli.cli.main import run


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def bench(tmp_path):
    """Two depths × two wavelengths of 16-bit frames, a dark frame, and their CSV manifest."""
    rng = np.random.default_rng(11)
    rows = ["file,wavelength,depth,exposure"]
    for i, depth in enumerate(("45mm", "inf")):
        for j, wavelength in enumerate((530, 630)):
            spot = gaussian_spot(96, 96, (47.3 + i, 49.6 - j), 1.5 + 1.5 * i + 0.3 * j)
            cv2.imwrite(str(tmp_path / f"psf_{i}{j}.png"), bench_frame(spot, rng, photons=4e5))
            rows.append(f"psf_{i}{j}.png,{wavelength}nm,{depth},20ms")
    cv2.imwrite(str(tmp_path / "dark.png"), bench_frame(np.zeros((96, 96)), rng, background=0.0))
    (tmp_path / "psf.csv").write_text("\n".join(rows) + "\n")
    return tmp_path


def test_import_then_mtf_then_compare(capsys, bench):
    cube = bench / "measured.exr"
    code, out, err = invoke(
        capsys,
        "psf",
        "import",
        bench / "psf.csv",
        "-o",
        cube,
        "--dark",
        bench / "dark.png",
        "--pixel-pitch",
        "3.7um",
        "--magnification",
        "2",
        "--pixels",
        "33",
        "--plot",
        bench / "psf.png",
        "--json",
    )
    assert code == 0, err
    report = json.loads(out)
    assert report["pixels"] == 33 and report["pixel_pitch_m"] == pytest.approx(1.85e-6)
    assert report["depths_m"] == [0.045, None] and len(report["frames"]) == 4
    assert all(f["saturated_pixels"] == 0 for f in report["frames"]) and (bench / "psf.png").stat().st_size > 0
    code, out, err = invoke(capsys, "mtf", cube, "--json")
    assert code == 0, err
    curves = json.loads(out)["curves"]
    assert [c["mtf50_lpmm"] > 0 for c in curves] == [True] * 4
    code, out, err = invoke(
        capsys, "psf", "compare", cube, cube, "--json", "--csv", bench / "c.csv", "--plot", bench / "c.png"
    )
    assert code == 0, err
    pairs = json.loads(out)["pairs"]
    assert len(pairs) == 4 and all(p["peak_ratio"] == pytest.approx(1) and p["relative_l2"] < 1e-9 for p in pairs)
    assert (bench / "c.csv").read_text().count("\n") == 5
    code, out, _ = invoke(capsys, "psf", "compare", cube, cube)
    assert code == 0 and "peak ratio" in out


def test_mtf_reads_a_cube_without_design_and_version(capsys, tmp_path):
    """A measured cube written by another program: only the keys a reader needs."""
    metadata = {
        "format": "metalens-psf-cube/1",
        "wavelengths_m": [5.3e-07],
        "depths_m": [None],
        "pixel_pitch_m": 1.85e-06,
        "normalization": "peak-one",
    }
    psf = gaussian_spot(33, 33, (16, 16), 2.0).astype(np.float32)
    OpenEXR.File(
        {"type": OpenEXR.scanlineimage, "metalens": json.dumps(metadata)}, {"psf.d00.w000": psf / psf.max()}
    ).write(str(tmp_path / "other.exr"))
    code, out, err = invoke(capsys, "mtf", tmp_path / "other.exr", "--json")
    assert code == 0, err
    assert json.loads(out)["curves"][0]["mtf50_lpmm"] > 0


@pytest.mark.parametrize(
    ("change", "args", "message"),
    [
        (None, [], "--pixel-pitch: the camera's pixel pitch is not given"),
        (
            lambda b: (b / "psf_00.png").write_bytes(b"garbage"),
            ["--pixel-pitch", "2um"],
            "psf.csv line 2: psf_00.png is not a readable image",
        ),
        (
            lambda b: (b / "psf.csv").write_text("file,wavelength\n"),
            ["--pixel-pitch", "2um"],
            "lacks the column(s) depth",
        ),
        (
            lambda b: (b / "psf.csv").write_text("file,wavelength,depth\npsf_00.png,530nm,45 parsecs\n"),
            ["--pixel-pitch", "2um"],
            "unknown unit",
        ),
        (None, ["--pixel-pitch", "2um", "--dark", "nothing.png"], "--dark: no such file"),
        (
            lambda b: cv2.imwrite(str(b / "dark.png"), np.zeros((50, 50), np.uint16)),
            ["--pixel-pitch", "2um", "--dark", "DARK"],
            "is 96 × 96 pixels, the dark frame 50 × 50",
        ),
        (
            lambda b: cv2.imwrite(str(b / "psf_11.png"), np.full((96, 96), 65535, np.uint16)),
            ["--pixel-pitch", "2um"],
            "psf_11.png has 9216 saturated pixel(s)",
        ),
        (
            None,
            ["--pixel-pitch", "2um", "--pattern", "x_{wavelength}_{depth}.png"],
            "--pattern: only applies to a folder",
        ),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(capsys, bench, change, args, message):
    if change is not None:
        change(bench)
    output = bench / "cube.exr"
    code, out, err = invoke(
        capsys,
        "psf",
        "import",
        bench / "psf.csv",
        "-o",
        output,
        *[str(bench / "dark.png") if a == "DARK" else a for a in args],
    )
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err, err
    assert not output.exists() and not list(bench.glob(".metalens-*"))


def test_compare_refuses_cubes_with_nothing_in_common(capsys, bench):
    cube = bench / "m.exr"
    assert invoke(capsys, "psf", "import", bench / "psf.csv", "-o", cube, "--pixel-pitch", "2um", "--quiet")[0] == 0
    other = bench / "other.exr"
    metadata = {
        "format": "metalens-psf-cube/1",
        "wavelengths_m": [4.5e-07],
        "depths_m": [1.0],
        "pixel_pitch_m": 2e-06,
        "normalization": "sum-to-one",
    }
    OpenEXR.File(
        {"type": OpenEXR.scanlineimage, "metalens": json.dumps(metadata)}, {"psf.d00.w000": np.ones((9, 9), np.float32)}
    ).write(str(other))
    code, out, err = invoke(capsys, "psf", "compare", cube, other)
    assert code == 2 and err.count("\n") == 1 and "no simulated PSF at this depth" in err


def test_json_reaches_a_pipe(bench):
    """Frames are read while others are processed: C-library output is captured per read, and
    standard output must come back to the pipe (two threads swapping descriptors once left it
    on a temporary file: `psf import --json | jq` printed nothing)."""
    import subprocess
    import sys

    rows = (bench / "psf.csv").read_text().splitlines()
    (bench / "many.csv").write_text(
        "\n".join([rows[0], *rows[1:] * 3]) + "\n"
    )  # repeats: 12 frames, more than the workers
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "metalens_cli",
            "psf",
            "import",
            str(bench / "many.csv"),
            "--pixel-pitch",
            "2um",
            "-o",
            str(bench / "piped.exr"),
            "--json",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert len(json.loads(done.stdout)["frames"]) == 12


def _write_cube(path, planes, pitch_m):
    """A one-depth (inf), one-wavelength (530 nm) cube of ``planes`` (N × N)."""
    from metalens_cli.io.exr import write_exr_cube

    write_exr_cube(
        path, np.asarray(planes, np.float32)[None, None], np.array([530e-9]), np.array([np.inf]), pitch_m, "test"
    )


def test_compare_refuses_a_3x3_window_and_does_not_report_encircled_energy_beyond_the_window(capsys, tmp_path):
    """A 3 × 3 crop of the simulation gave peak ratio 1.0 and EE 1.000 at radii beyond the
    window, exit 0; now: refused naming SIMULATED; a 9 × 9 crop: EE beyond it is null / —."""
    spot = gaussian_spot(41, 41, (20, 20), 1.5)
    _write_cube(tmp_path / "m.exr", spot, 1.85e-6)
    _write_cube(tmp_path / "s3.exr", spot[19:22, 19:22], 1.85e-6)
    _write_cube(tmp_path / "s9.exr", spot[16:25, 16:25], 1.85e-6)
    code, out, err = invoke(capsys, "psf", "compare", tmp_path / "m.exr", tmp_path / "s3.exr")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert (
        err.startswith("metalens: error: SIMULATED: its window (3 × 3 pixels of 1.85 µm")
        and "(expected a simulated window" in err
    )
    code, out, err = invoke(capsys, "psf", "compare", tmp_path / "m.exr", tmp_path / "s9.exr", "--json")
    assert code == 0, err
    ee = json.loads(out)["pairs"][0]["encircled_energy"]
    assert ee["measured"][1:] == [None, None] and ee["simulated"][1:] == [None, None] and ee["measured"][0] > 0.5
    assert (
        "metalens: warning: encircled energy at 9.25 µm and 18.5 µm is not reported" in err and "16.65 µm across" in err
    )
    code, out, err = invoke(capsys, "psf", "compare", tmp_path / "m.exr", tmp_path / "s9.exr")
    assert code == 0 and "— / —" in out and "1.000 / 1.000" not in out


def _write_field_cube(path, planes, angles, centres, pitch_m=1.85e-6):
    """A field cube of one depth (inf) and one wavelength (530 nm): ``planes`` (F, N, N)."""
    from metalens_cli.io.exr import write_exr_cube

    extra = {
        "field_angles_rad": angles,
        "field_azimuth_rad": 0.0,
        "chief_ray_m": [[c * pitch_m, r * pitch_m] for c, r in centres],
        "window_centre_px": centres,
    }
    psf = np.asarray(planes, np.float32)[:, None, None]
    write_exr_cube(path, psf, np.array([530e-9]), np.array([np.inf]), pitch_m, "test", extra=extra)


def test_compare_field_cubes_per_field(capsys, tmp_path):
    """Measured field 1 lies 2 columns right of its window's centre, the simulated window 2 columns
    right of the measured one's: on the sensor they coincide."""
    measured, simulated, table = tmp_path / "m.exr", tmp_path / "s.exr", tmp_path / "c.csv"
    _write_field_cube(
        measured,
        [gaussian_spot(33, 33, (16, 16), 1.5), gaussian_spot(33, 33, (16, 18), 2.0)],
        [0.0, 0.1],
        [[0, 0], [216, 0]],
    )
    _write_field_cube(
        simulated,
        [gaussian_spot(33, 33, (16, 16), 1.5), gaussian_spot(33, 33, (16, 16), 2.0)],
        [0.0, 0.1],
        [[0, 0], [218, 0]],
    )
    code, out, err = invoke(
        capsys, "psf", "compare", measured, simulated, "--json", "--csv", table, "--plot", tmp_path / "c.png"
    )
    assert code == 0 and err == ""
    data = json.loads(out)
    assert [(f["field"], f["simulated_field"]) for f in data["fields"]] == [(0, 0), (1, 1)]
    assert data["fields"][1]["window_offset_px"] == [0.0, 2.0]
    assert [p["field"] for p in data["pairs"]] == [0, 1]
    assert data["pairs"][1]["shift_px"] == pytest.approx([0, 2], abs=0.05)
    assert data["pairs"][1]["sensor_shift_px"] == pytest.approx([0, 0], abs=0.05)
    rows = table.read_text().splitlines()
    assert rows[0].endswith(",shift_y_px,shift_x_px,field,field_angle_deg,sensor_shift_y_px,sensor_shift_x_px")
    assert len(rows) == 3 and (tmp_path / "c.png").stat().st_size > 0
    code, out, err = invoke(capsys, "psf", "compare", measured, simulated)
    assert code == 0 and "field (°)" in out and "sensor_shift_px" in out
    on_axis = tmp_path / "a.exr"
    _write_cube(on_axis, gaussian_spot(33, 33, (16, 16), 1.5), 1.85e-6)
    code, out, err = invoke(capsys, "psf", "compare", on_axis, simulated, "--json")
    assert code == 0 and "fields" not in json.loads(out) and len(json.loads(out)["pairs"]) == 1
    assert "metalens: warning: the simulated cube holds 2 fields and the measured cube is on axis" in err
