"""export-phase end to end: files parsed back (.zmx, .json, .csv), JSON report, hostile inputs."""

import json
import math

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.io.phase_files import read_phase_json, read_zmx_binary2

PAPER = ["hyperbolic:532nm", "--f", "4mm", "--aperture", "2.516mm"]
SMALL = ["hyperbolic:532nm", "--f", "4mm", "--aperture", "200um"]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("suffix", [".zmx", ".json"])
def test_file_parses_back_to_the_reported_coefficients(capsys, tmp_path, suffix):
    out_file = tmp_path / f"lens{suffix}"
    code, out, _ = invoke(capsys, "export-phase", *PAPER, "-o", out_file, "--order", "5", "--json")
    report = json.loads(out)
    assert code == 0 and report["order"] == 5 and report["norm_radius_m"] == pytest.approx(1.258e-3)
    assert {"residual", "file", "seconds"} <= set(report) and report["residual"]["max_waves"] < 1e-6
    surface = read_zmx_binary2(out_file) if suffix == ".zmx" else read_phase_json(out_file)["surface"]
    assert surface.coefficients_rad == tuple(report["coefficients_rad"])  # exact: written with repr
    assert surface.norm_radius_m == pytest.approx(1.258e-3, rel=1e-15) and surface.diffraction_order == 1
    assert surface.coefficients_rad[0] == pytest.approx(-math.pi * 1.258e-3**2 / (532e-9 * 4e-3), rel=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == [out_file.name]  # no temporary left


def test_the_cli_cap_is_the_core_cap():
    from metalens_cli.analysis.phase_export import MAX_TERMS
    from metalens_cli.cli.export_phase import MAX_TERMS as CLI_MAX_TERMS

    assert CLI_MAX_TERMS == MAX_TERMS


def test_zmx_is_utf16_with_a_binary2_stop(tmp_path, capsys):
    out_file = tmp_path / "lens.zmx"
    assert invoke(capsys, "export-phase", *SMALL, "-o", out_file)[0] == 0
    data = out_file.read_bytes()
    assert data.startswith(b"\xff\xfe")
    lines = [line.strip() for line in data.decode("utf-16").splitlines()]
    surf = lines.index("SURF 1")
    assert lines[surf + 1 : surf + 3] == ["STOP", "TYPE BINARY_2"] and "DISZ 4.0" in lines and "PARM 0 1" in lines
    assert lines[lines.index("UNIT MM X W X CM MR CPMM") + 1] == "ENPD 0.2"  # 200 µm in mm


def test_csv_columns(capsys, tmp_path):
    out_file = tmp_path / "lens.csv"
    assert invoke(capsys, "export-phase", *SMALL, "-o", out_file, "--order", "2")[0] == 0
    header = out_file.read_text().splitlines()[0]
    table = np.loadtxt(out_file, delimiter=",", skiprows=1)
    r = table[:, 0]
    assert header == "r_m,phase_rad,fitted_rad"
    np.testing.assert_allclose(r, np.arange(254) * 395e-9)  # k·pitch ≤ 100 µm
    closed = -(2 * math.pi / 532e-9) * (np.sqrt(r**2 + 4e-3**2) - 4e-3)
    np.testing.assert_allclose(table[:, 1], closed, atol=1e-9)  # cancellation in the form above: ~1e-12 rad
    assert np.abs(table[:, 2] - closed).max() < 1e-6  # two terms, NA 0.025: the ρ⁶ term is ~1e-7 rad


def test_grid_design_json_and_csv(capsys, tmp_path):
    theta = np.random.default_rng(1).uniform(0, math.pi, (41, 41))
    npy = tmp_path / "theta.npy"
    np.save(npy, theta)
    geometry = ["--f", "4mm", "--aperture", "8um", "--pitch", "395nm"]
    code, out, _ = invoke(capsys, "export-phase", npy, *geometry, "-o", tmp_path / "g.json", "--json")
    header = read_phase_json(tmp_path / "g.json")
    assert code == 0 and json.loads(out)["kind"] == header["kind"] == "grid" and header["axis_index"] == 20
    np.testing.assert_array_equal(header["phase_rad"], 2 * theta)
    assert invoke(capsys, "export-phase", npy, *geometry, "-o", tmp_path / "g.csv")[0] == 0
    table = np.loadtxt(tmp_path / "g.csv", delimiter=",", skiprows=1)
    i, j = np.rint(table[:, 1] / 395e-9).astype(int) + 20, np.rint(table[:, 0] / 395e-9).astype(int) + 20
    assert len(table) == np.sum(np.hypot(*np.meshgrid(np.arange(-20, 21), np.arange(-20, 21))) * 395e-9 <= 4e-6)
    np.testing.assert_array_equal(table[:, 2], 2 * theta[i, j])


@pytest.mark.parametrize(
    "args, option",
    [
        (["--order", "0"], "--order"),
        (["--order", "-3"], "--order"),
        (["--order", "65"], "--order"),
        (["--norm-radius", "-1mm"], "--norm-radius"),
        (["--tolerance", "0"], "--tolerance"),
        (["--tolerance", "1e-9", "--order", "1"], "--tolerance"),
        (["--output", "x.txt"], "--output"),
    ],
)
def test_bad_input(capsys, tmp_path, monkeypatch, args, option):
    monkeypatch.chdir(tmp_path)
    output = [] if "--output" in args else ["-o", "x.zmx"]
    code, out, err = invoke(capsys, "export-phase", *SMALL, *output, *args)
    assert code == 2 and option in err and len(err.strip().splitlines()) == 1 and out == ""
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_unreachable_tolerance_names_it_with_the_best_residual(capsys, tmp_path):
    theta = np.cumsum(np.random.default_rng(0).normal(0, 0.3, 300))  # rough: no polynomial follows it
    npy = tmp_path / "rough.npy"
    np.save(npy, theta)
    code, _, err = invoke(
        capsys, "export-phase", npy, "--f", "4mm", "--aperture", "200um", "--pitch", "1um", "-o", tmp_path / "x.zmx"
    )
    assert code == 2 and err.startswith("metalens: error: --tolerance: no Binary 2 fit of up to 64 terms")
    assert "the best" in err and "wave" in err and not (tmp_path / "x.zmx").exists()


def test_two_dimensional_design_refuses_zmx(capsys, tmp_path):
    npy = tmp_path / "theta.npy"
    np.save(npy, np.zeros((21, 21)))
    code, _, err = invoke(
        capsys, "export-phase", npy, "--f", "4mm", "--aperture", "8um", "--pitch", "395nm", "-o", tmp_path / "x.zmx"
    )
    assert code == 2 and "--output" in err and "2-D" in err and not (tmp_path / "x.zmx").exists()


def test_grid_phase_dat_holds_the_closed_form_phase_and_its_slopes(capsys, tmp_path):
    from metalens_cli.io.phase_files import read_grid_dat

    out_file = tmp_path / "lens.dat"
    code, out, _ = invoke(capsys, "export-phase", *SMALL, "-o", out_file, "--json")
    assert code == 0 and json.loads(out)["format"] == "dat"
    phase, step, inside = read_grid_dat(out_file)
    m = phase.shape[0]
    assert m == 2 * math.floor(100e-6 / 395e-9 + 1e-9) + 1 and step == pytest.approx(395e-9, rel=1e-12)
    c = (np.arange(m) - m // 2) * 395e-9
    y, x = np.meshgrid(c, c, indexing="ij")
    r = np.hypot(x, y)
    closed = -(2 * math.pi / 532e-9) * (np.sqrt(r**2 + 4e-3**2) - 4e-3)
    np.testing.assert_array_equal(inside, r <= 100e-6)
    # the radial profile is interpolated linearly between its samples: ≤ |φ''|·pitch²/8 ≈ 2.3e-4 rad
    np.testing.assert_allclose(phase[inside], closed[inside], atol=3e-4)
    assert np.all(phase[~inside] == 0)
    lines = out_file.read_text().splitlines()
    first = np.array(lines[1].split(), dtype=float)  # the corner (−x, +y): outside the pupil
    assert lines[0].split()[:5] == [str(m), str(m), repr(395e-9 * 1e3), repr(395e-9 * 1e3), "0"] and first[4] == 1
    # the slopes (rad/mm) on the +x axis, row m//2, against dφ/dx = −2πx/(λ√(x² + f²))
    row = np.array([line.split() for line in lines[1 + (m - 1 - m // 2) * m : 1 + (m - m // 2) * m]], dtype=float)
    xs = c[5:-5]
    slope = -2 * math.pi * xs / (532e-9 * np.sqrt(xs**2 + 4e-3**2)) * 1e-3
    np.testing.assert_allclose(row[5:-5, 1], slope, rtol=2e-3, atol=0.2)  # central differences of a quadratic


def test_grid_phase_dat_of_a_2d_map_and_its_refusals(capsys, tmp_path):
    from metalens_cli.io.phase_files import read_grid_dat
    from metalens_cli.optics.lens import hyperbolic

    theta = hyperbolic(532e-9, 4e-3, 40e-6, 395e-9, radial=False).theta.numpy()
    npy = tmp_path / "map.npy"
    np.save(npy, theta)
    dat = tmp_path / "map.dat"
    code, _, _ = invoke(capsys, "export-phase", npy, "--f", "4mm", "--aperture", "40um", "--pitch", "395nm", "-o", dat)
    phase, _, inside = read_grid_dat(dat)
    assert code == 0
    np.testing.assert_allclose(phase[inside], 2 * theta[inside], rtol=1e-11)  # the map's values to 12 digits
    code, out, err = invoke(capsys, "export-phase", *PAPER, "-o", tmp_path / "big.dat")
    assert code == 2 and "--output" in err and "6369 × 6369" in err and not (tmp_path / "big.dat").exists()
    code, out, err = invoke(capsys, "export-phase", *SMALL, "--order", "4", "-o", tmp_path / "o.dat")
    assert code == 2 and "--order" in err
