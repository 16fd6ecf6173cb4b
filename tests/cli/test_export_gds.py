"""export-gds end to end on a small lens: JSON report, --verify through KLayout, exit codes."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run

pytest.importorskip("klayout")

PRESETS = Path(__file__).parents[2] / "presets"
SMALL = [
    "--design",
    "hyperbolic:532nm",
    "--f",
    "4mm",
    "--aperture",
    "30um",
    "--pitch",
    "395nm",
    "--width",
    "305nm",
    "--length",
    "125nm",
]
KEYS = {"atoms", "file", "bytes", "format", "max_phase_error_rad", "seconds", "efficiency", "warnings"}


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    "name, angles", [("lens.gds", "exact"), ("lens.oas", "exact"), ("lens.gds", "32"), ("lens.oas", "32")]
)
def test_json_report_and_verify(capsys, tmp_path, name, angles):
    out_file = tmp_path / name
    code, out, _ = invoke(capsys, "export-gds", *SMALL, "-o", out_file, "--angles", angles, "--verify", "--json")
    report = json.loads(out)
    assert code == 0 and set(report) == KEYS | {"verify"}
    assert report["format"] == name[-3:] and report["bytes"] == out_file.stat().st_size > 0
    k = np.arange(-40, 41)
    lattice = int(np.sum(np.hypot(*np.meshgrid(k, k)) * 395e-9 <= 15e-6))  # brute-force sites within D/2
    assert report["atoms"] == report["verify"]["found_atoms"] == lattice
    assert report["verify"]["ok"] and report["verify"]["samples"] == 1000
    bound = 0 if angles == "exact" else math.pi / 32
    assert report["max_phase_error_rad"] <= bound
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary left


def test_preset_geometry_and_text_output(capsys, tmp_path):
    code, out, _ = invoke(
        capsys,
        "export-gds",
        "--design",
        PRESETS / "hyperbolic-532.toml",
        "--aperture",
        "20um",
        "-o",
        tmp_path / "x.gds",
        "--quiet",
    )
    assert (
        code == 0 and "2,017" in out and "hyperbolic_532" in out
    )  # the preset's 305 × 125 nm fins pass the overlap check


def test_verify_mismatch_exits_1(capsys, tmp_path, monkeypatch):
    import metalens_cli.io.layout_verify as verify

    real = verify.site_theta
    monkeypatch.setattr(verify, "site_theta", lambda lens, i, j: real(lens, i, j) + 0.1)  # the file no longer matches
    code, out, _ = invoke(capsys, "export-gds", *SMALL, "-o", tmp_path / "x.gds", "--verify", "--json")
    result = json.loads(out)["verify"]
    assert code == 1 and not result["ok"]
    assert result["worst"]["rotation_rad"] == pytest.approx(0.1, abs=0.005)  # the shift, within dbu rounding


@pytest.mark.parametrize(
    "args, option",
    [
        (["--design", "hyperbolic:532nm", "--f", "4mm", "--aperture", "30um", "-o", "x.gds"], "--width"),
        ([*SMALL, "--layer", "1/a", "-o", "x.gds"], "--layer"),
        ([*SMALL, "--angles", "1", "-o", "x.gds"], "--angles"),
        ([*SMALL, "--angles", "fine", "-o", "x.gds"], "--angles"),
        ([*SMALL, "-o", "x.dxf"], "--output"),
        ([*SMALL, "--width", "390nm", "-o", "x.gds"], "--width"),
        ([*SMALL, "--dbu", "100nm", "-o", "x.gds"], "--dbu"),
    ],
)
def test_bad_input(capsys, tmp_path, monkeypatch, args, option):
    monkeypatch.chdir(tmp_path)
    code, out, err = invoke(capsys, "export-gds", *args)
    assert code == 2 and option in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_map_contradicting_pitch_exits_2(capsys, tmp_path):
    npy = tmp_path / "theta.npy"
    np.save(npy, np.zeros((77, 77)))  # the grid of a 30 µm pupil at 395 nm
    code, _, err = invoke(
        capsys,
        "export-gds",
        "--design",
        npy,
        "--f",
        "4mm",
        "--aperture",
        "30um",
        "--pitch",
        "790nm",
        "--width",
        "305nm",
        "--length",
        "125nm",
        "-o",
        tmp_path / "x.gds",
    )
    assert code == 2 and "contradicts" in err and not (tmp_path / "x.gds").exists()
