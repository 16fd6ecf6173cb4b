"""psf-scan end to end on a small lens: EXR contract, JSON report, plots, errors."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.io.exr import read_exr_cube

PRESETS = Path(__file__).parents[2] / "presets"
SMALL = [
    "--design",
    "hyperbolic:532nm",
    "--f",
    "4mm",
    "--aperture",
    "0.3mm",
    "--pixels",
    "33",
    "--pixel-pitch",
    "1.85um",
]


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_scan_writes_contract_and_json(capsys, tmp_path):
    out_file, plot = tmp_path / "psf.exr", tmp_path / "scan.png"
    code, out, _ = invoke(
        capsys,
        "psf-scan",
        *SMALL,
        "--wavelengths",
        "500:560:20nm",
        "--depths",
        "45mm,inf",
        "-o",
        out_file,
        "--json",
        "--plot",
        plot,
    )
    assert code == 0 and plot.exists()
    report = json.loads(out)
    assert report["depths_m"] == [0.045, None] and len(report["psfs"]) == 8
    assert set(report["psfs"][0]) == {
        "depth_m",
        "wavelength_m",
        "peak",
        "energy_in_window",
        "energy_center_5x5",
        "fwhm_m",
    }
    assert report["timing_s"]["total"] > 0 and report["propagator"] == "radial"
    cube = read_exr_cube(out_file)
    assert cube.psf.shape == (2, 4, 33, 33) and math.isinf(cube.depths_m[1])
    assert cube.rgb is None  # no preset: no spectra
    # Energy: a NA-0.04 lens puts nearly all power inside 33 × 1.85 µm (Airy radius 8 µm).
    assert np.all(cube.psf.sum(axis=(-2, -1)) > 0.9)
    # The in-focus far PSF (532 nm is not on the grid; 540 nm is 1.5 % off) peaks on the axis pixel.
    assert np.unravel_index(np.argmax(cube.psf[1, 2]), (33, 33)) == (16, 16)


def test_scan_with_preset_writes_rgb(capsys, tmp_path):
    out_file = tmp_path / "psf.exr"
    code, out, _ = invoke(
        capsys,
        "psf-scan",
        *SMALL,
        "--preset",
        PRESETS / "split-spectrum.toml",
        "--wavelengths",
        "430:645:5nm",
        "--depths",
        "inf",
        "-o",
        out_file,
        "--json",
        "--quiet",
    )
    assert code == 0
    cube = read_exr_cube(out_file)
    assert cube.rgb.shape == (1, 3, 33, 33)
    # Each channel PSF is a convex mix of the monochromatic ones: its energy lies within theirs.
    energies = cube.psf.sum(axis=(-2, -1))[0]
    for channel in cube.rgb.sum(axis=(-2, -1))[0]:
        assert energies.min() - 1e-6 <= channel <= energies.max() + 1e-6
    report = json.loads(out)
    assert report["spectra"]["channels"] == ["R", "G", "B"]
    # The channel summary (filter × camera response): each channel's centre 5 × 5 energy is the
    # quadrature-weighted mean of the wavelengths' own (the 5 × 5 sum is linear), recomputed here
    # from the per-wavelength report; the split-spectrum filter keeps each channel to its pass band.
    from metalens_cli.io.preset_spectra import preset_sensitivity
    from metalens_cli.io.presets import load_preset
    from metalens_cli.optics.spectra import quadrature_weights

    weights = quadrature_weights(
        preset_sensitivity(load_preset(PRESETS / "split-spectrum.toml")), np.array(report["wavelengths_m"])
    ).weights
    per_wavelength = np.array([p["energy_center_5x5"] for p in report["psfs"]])
    channels = {m["channel"]: m for m in report["channel_psfs"]}
    assert list(channels) == ["R", "G", "B"] and all(m["depth_m"] is None for m in channels.values())
    for c, name in enumerate("RGB"):
        assert channels[name]["energy_center_5x5"] == pytest.approx(float(weights[c] @ per_wavelength), rel=1e-5)


def test_check_accuracy_reports(capsys, tmp_path):
    code, out, _ = invoke(
        capsys,
        "psf-scan",
        *SMALL,
        "--wavelengths",
        "532nm",
        "--depths",
        "inf",
        "-o",
        tmp_path / "p.exr",
        "--check-accuracy",
        "--json",
    )
    accuracy = json.loads(out)["accuracy"]
    assert code == 0
    assert accuracy["doubled_sampling_rel_l2"] < 1e-3 and accuracy["rs_rel_l2"] < 1e-3


@pytest.mark.parametrize(
    "args, option",
    [
        (["--design", "hyperbolic:532nm", "--aperture", "1mm", "-o", "x.exr"], "--f"),
        ([*SMALL, "--device", "cuda:7", "-o", "x.exr"], "--device"),
        ([*SMALL, "--wavelengths", "500", "-o", "x.exr"], "--wavelengths"),
    ],
)
def test_bad_input(capsys, tmp_path, monkeypatch, args, option):
    monkeypatch.chdir(tmp_path)
    code, out, err = invoke(capsys, "psf-scan", *args)
    assert code == 2 and option in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_a_scan_estimated_at_days_is_refused_before_it_starts(capsys, tmp_path):
    """Direct Rayleigh-Sommerfeld integration of the paper's lens over 512² pixels takes hours a
    PSF: refused by the default --max-time (a day) and by a stricter one, with the estimate.
    --max-memory is set so that the time check is what refuses, whatever memory the host has free
    (the 512² scan needs ~15 GiB)."""
    lens = [
        "--max-memory",
        "64GiB",
        "--design",
        "hyperbolic:532nm",
        "--f",
        "4mm",
        "--aperture",
        "2.516mm",
        "--propagator",
        "rs",
        "--pixels",
        "512",
        "--depths",
        "inf",
        "-o",
        tmp_path / "rs.exr",
    ]
    code, out, err = invoke(capsys, "psf-scan", *lens, "--wavelengths", "430:645:5nm")
    assert code == 2 and out == ""
    assert "--pixels: psf-scan of 44 PSFs" in err and "days, over the --max-time limit (24.0 h)" in err
    code, _, err = invoke(capsys, "psf-scan", *lens, "--wavelengths", "532nm", "--max-time", "30min")
    assert code == 2 and "over the --max-time limit (30 min)" in err
    assert list(tmp_path.iterdir()) == []


def test_an_undersampled_lens_names_pitch_and_offers_force_only_where_it_exists(capsys, tmp_path):
    """The sampling guard is bad input about the lens: it names --pitch and what would fix it;
    psf-scan, which has --force, says so; simulate, which has not, does not."""
    lens = ["--f", "1mm", "--aperture", "10mm", "--pixels", "32"]
    code, _, err = invoke(
        capsys,
        "psf-scan",
        "--design",
        "hyperbolic:532nm",
        *lens,
        "--wavelengths",
        "532nm",
        "--depths",
        "45mm",
        "-o",
        tmp_path / "x.exr",
    )
    assert code == 2 and err.startswith("metalens: error: --pitch: the field leaving the lens reaches ")
    assert err.rstrip().endswith("or a more distant source; or --force to compute anyway)") and err.count("\n") == 1
    code, _, err = invoke(
        capsys, "simulate", "hyperbolic:532nm", *lens, "--images", "charts", "--limit", "1", "-o", tmp_path / "s"
    )
    assert code == 2 and err.startswith("metalens: error: --pitch: ") and "force" not in err
    assert list(tmp_path.iterdir()) == []
