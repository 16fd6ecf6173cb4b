"""`metalens nanofin efficiency` end to end: the JSON interface, the convergence report, errors."""

import json
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run

PRESETS = Path(__file__).parents[2] / "presets"


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_interface_and_a_square_fin(capsys, tmp_path):
    code, out, err = invoke(
        capsys,
        "nanofin",
        "efficiency",
        "--wavelengths",
        "457nm,530nm",
        "--harmonics",
        "7",
        "--json",
        "--plot",
        tmp_path / "nf.png",
    )
    assert code == 0, err
    r = json.loads(out)
    assert r["wavelengths_m"] == [457e-9, 530e-9] and r["harmonics"] == 7
    for key in ("conversion_efficiency", "co_polarized", "transmittance"):
        assert len(r[key]) == 2 and all(0 <= v <= 1 for v in r[key])
    assert all(e + c <= t + 1e-12 for e, c, t in zip(r["conversion_efficiency"], r["co_polarized"], r["transmittance"]))
    assert r["material"]["name"] == "sinx" and (tmp_path / "nf.png").stat().st_size > 0
    code, out, _ = invoke(
        capsys,
        "nanofin",
        "efficiency",
        "--width",
        "150nm",
        "--length",
        "150nm",
        "--wavelengths",
        "530nm",
        "--harmonics",
        "9",
        "--json",
    )
    assert code == 0 and json.loads(out)["conversion_efficiency"][0] < 1e-5  # a square fin converts nothing


def test_auto_harmonics_report_their_convergence(capsys):
    code, out, err = invoke(
        capsys,
        "nanofin",
        "efficiency",
        "--wavelengths",
        "530nm",
        "--material",
        "2.0",
        "--tolerance",
        "0.01",
        "--max-harmonics",
        "11",
        "--json",
    )
    assert code == 0, err
    r = json.loads(out)
    table = r["convergence"]
    assert table[0]["harmonics"] == 5 and r["harmonics"] in [t["harmonics"] for t in table]
    chosen = next(k for k, t in enumerate(table) if t["harmonics"] == r["harmonics"])
    assert chosen == len(table) - 1 and abs(table[chosen]["conversion"] - table[chosen - 1]["conversion"]) < 0.01


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--width", "400nm"], "--width: 400 nm is larger than the 395 nm period"),
        (["--length", "0nm"], "--length"),
        (["--harmonics", "4"], "an odd number"),
        (["--material", "unobtainium"], "--material: 'unobtainium' is not a material"),
        (["--material", "2.0-0.1j"], "--material"),
        (
            ["--material", "2.0", "--substrate", "tio2", "--wavelengths", "300nm"],
            "--substrate: 300 nm is outside the range of tio2",
        ),
        (["--wavelengths", "1m"], "not an optical wavelength"),
        (["--harmonics", "41", "--max-memory", "1MiB"], "--max-memory"),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, args, message):
    code, out, err = invoke(capsys, "nanofin", "efficiency", *args)
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err, err


def test_sweep_writes_its_map_and_recommends_a_fin(capsys, tmp_path):
    out = tmp_path / "sweep"
    code, stdout, err = invoke(
        capsys,
        "nanofin",
        "sweep",
        "--width",
        "250nm,300nm",
        "--length",
        "100nm,150nm",
        "--harmonics",
        "3",
        "--max-harmonics",
        "11",
        "--band",
        "530nm:20nm",
        "-o",
        out,
        "--json",
    )
    assert code == 0, err
    r = json.loads(stdout)
    assert sorted(p.name for p in out.iterdir()) == [
        "nanofin.toml",
        "sweep.csv",
        "sweep.json",
        "sweep.npz",
        "sweep.png",
    ]
    assert (out / "sweep.csv").read_text().count("\n") == 5
    c = r["recommended"]
    assert c["width_m"] in (250e-9, 300e-9) and c["length_m"] in (100e-9, 150e-9)
    f = c["converged"]
    assert (
        f["harmonics"] >= 9 and 0 < f["eta_per_band"][0] < 1 and f["fins"] == 1 and f["worst_neighbour"] == f["score"]
    )
    assert not r["cached"] and len(r["wavelengths_m"][0]) == 8
    assert any("lies on the grid's edge" in w for w in r["warnings"])  # a 2 × 2 grid is all edge
    code, again, err = invoke(
        capsys,
        "nanofin",
        "sweep",
        "--width",
        "250nm,300nm",
        "--length",
        "100nm,150nm",
        "--harmonics",
        "3",
        "--max-harmonics",
        "11",
        "--band",
        "530nm:20nm",
        "-o",
        tmp_path / "again",
        "--json",
    )
    again = json.loads(again)
    assert code == 0 and again["cached"] and again["converged_cached"]  # the map and the refinement come from the cache
    assert again["recommended"] == c
    code, _, err = invoke(capsys, "nanofin", "sweep", "--width", "400nm", "--length", "100nm", "-o", tmp_path / "x")
    assert code == 2 and "--width: 400 nm is larger than the 395 nm period" in err


def test_the_recommended_fin_goes_into_the_preset(capsys, tmp_path):
    """--preset: its [nanofin] and filter bands are the sweep's defaults, and OUTPUT/preset.toml is
    that preset with the recommended fin (η by RCWA at the converged N), which export-gds then
    draws without being told; OUTPUT/nanofin.toml is the section alone."""
    from metalens_cli.io.presets import load_preset

    source = PRESETS / "quick-split-spectrum.toml"
    code, out, err = invoke(
        capsys,
        "nanofin",
        "sweep",
        "--preset",
        source,
        "--width",
        "250nm,300nm",
        "--length",
        "100nm,150nm",
        "--harmonics",
        "3",
        "--max-harmonics",
        "9",
        "-o",
        tmp_path / "sweep",
        "--json",
    )
    assert code == 0, err
    r = json.loads(out)
    original, chosen = load_preset(source), load_preset(tmp_path / "sweep" / "preset.toml")
    assert (
        np.allclose(r["bands_m"], list(zip(original.filter.centers_m, original.filter.widths_m)), rtol=1e-9)
        and r["period_m"] == 395e-9
    )
    fin = chosen.nanofin
    assert (fin.width_m, fin.length_m) == (r["recommended"]["width_m"], r["recommended"]["length_m"])
    assert (
        fin.efficiency == "rcwa"
        and fin.harmonics == r["recommended"]["converged"]["harmonics"]
        and fin.material == original.nanofin.material
    )
    assert chosen.lens == original.lens and chosen.sensor == original.sensor and chosen.filter == original.filter
    section = (tmp_path / "sweep" / "nanofin.toml").read_text()
    assert section.count("[nanofin]") == 1 and 'efficiency = "rcwa"' in section
    code, out, err = invoke(
        capsys,
        "export-gds",
        "--design",
        "hyperbolic:532nm",
        "--aperture",
        "20um",
        "--preset",
        tmp_path / "sweep" / "preset.toml",
        "-o",
        tmp_path / "lens.gds",
        "--json",
    )
    report = json.loads(out)
    assert code == 0 and report["warnings"] == [] and report["efficiency"]["fin"]["width_m"] == fin.width_m


def test_one_fin_for_optics_and_layout(capsys, tmp_path):
    """A preset with efficiency = "rcwa": bands check, psf-scan and export-gds all say that they
    used RCWA η of the preset's fin (computed once: the later commands find it cached), psf-scan's
    channel mix changes with it, and export-gds draws that fin (and warns when told another)."""
    text = (PRESETS / "quick-split-spectrum.toml").read_text()
    text = text.replace(
        'efficiency_wavelengths = ["457nm", "530nm", "628nm"]   # RCWA conversion efficiency\n'
        "efficiency = [0.784, 0.729, 0.669]",
        'material = "sinx"\nefficiency = "rcwa"\nharmonics = 3',
    )
    assert 'efficiency = "rcwa"' in text
    (tmp_path / "rcwa.toml").write_text(text)
    preset = tmp_path / "rcwa.toml"
    code, out, err = invoke(capsys, "bands", "check", "--preset", preset, "--json")
    assert code == 0, err
    first = json.loads(out)["efficiency"]
    assert (
        first["source"] == "rcwa" and first["harmonics"] == 3 and len(first["band_mean"]) == 3 and not first["cached"]
    )
    scan = [
        "psf-scan",
        "--design",
        "hyperbolic:532nm",
        "--aperture",
        "60um",
        "--pixels",
        "16",
        "--wavelengths",
        "450:640:10nm",
        "--depths",
        "inf",
        "--json",
    ]
    code, out, err = invoke(capsys, *scan, "--preset", preset, "-o", tmp_path / "rcwa.exr")
    assert code == 0, err
    used = json.loads(out)["efficiency"]
    assert used["cached"] and used["conversion"] == first["conversion"]
    code, out, err = invoke(
        capsys, *scan, "--preset", PRESETS / "quick-split-spectrum.toml", "-o", tmp_path / "table.exr"
    )
    assert code == 0 and json.loads(out)["efficiency"]["source"] == "table"
    from metalens_cli.io.exr import read_exr_cube

    rcwa_rgb, table_rgb = (read_exr_cube(tmp_path / name).rgb for name in ("rcwa.exr", "table.exr"))
    assert (
        abs(rcwa_rgb - table_rgb).max() > 5e-3 * table_rgb.max()
    )  # another η weighs each channel's wavelengths differently
    gds = ["export-gds", "--design", "hyperbolic:532nm", "--aperture", "20um", "--preset", preset, "--json"]
    code, out, err = invoke(capsys, *gds, "-o", tmp_path / "lens.gds")
    report = json.loads(out)
    assert code == 0 and report["efficiency"]["source"] == "rcwa" and report["warnings"] == []
    code, out, err = invoke(capsys, *gds, "--width", "290nm", "-o", tmp_path / "other.gds")
    assert code == 0 and "is not the preset's (305 × 125 nm" in json.loads(out)["warnings"][0]


TINY_SWEEP = [
    "nanofin",
    "sweep",
    "--width",
    "250nm,300nm",
    "--length",
    "100nm,150nm",
    "--band",
    "530nm:20nm",
    "--samples-per-band",
    "1",
]


@pytest.mark.parametrize("args", [["--harmonics", "1"], ["--max-harmonics", "9"]])
def test_the_least_harmonics_in_range_work(capsys, tmp_path, args):
    """N = 1 (one order: E_y's odd subspace is empty) and the least --max-harmonics, 9 (auto
    compares N = 9 with 7 and 5; unconverged there, a warning), in both commands."""
    code, out, err = invoke(capsys, "nanofin", "efficiency", "--wavelengths", "530nm", *args, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert 0 <= r["conversion_efficiency"][0] <= 1 and abs(r["transmittance"][0] + r["reflectance"][0] - 1) < 1e-9
    code, out, err = invoke(capsys, *TINY_SWEEP, *args, "--max-harmonics", "9", "-o", tmp_path / "sweep", "--json")
    assert code == 0, err
    assert (
        json.loads(out)["recommended"]["converged"]["harmonics"] == 9
        and (tmp_path / "sweep" / "nanofin.toml").is_file()
    )


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (
            ["--max-harmonics", "5"],
            "--max-harmonics': '5' (expected an odd number of Fourier harmonics per axis from 9 to 41)",
        ),
        (["--max-harmonics", "3"], "from 9 to 41"),
        (["--max-harmonics", "10"], "from 9 to 41"),
        (["--harmonics", "2"], "--harmonics': '2' (expected an odd number of Fourier harmonics per axis from 1 to 41)"),
        (["--band", "540nm:20nm"], "--band: pass bands overlap"),
        (["--band", "600nm:0.5nm"], "--band: a band is narrower than"),
        (["--band", "1000nm:1990nm"], "--band': 5 nm is not an optical wavelength"),  # its lower edge
    ],
)
def test_sweep_refuses_before_any_work(capsys, tmp_path, args, words):
    """Values a preset or the convergence rule refuses are refused up front, nothing written."""
    code, out, err = invoke(capsys, *TINY_SWEEP, *args, "-o", tmp_path / "sweep")
    assert code == 2 and out == "" and err.count("\n") == 1 and words in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_huge_fabrication_tolerance_is_estimated_as_the_grid(capsys, tmp_path, monkeypatch):
    """The neighbourhood is cut at the grid's edges: ±1 m holds the 4 fins of a 2 × 2 grid, and the
    estimate (was 3e8 days) stays within 10× of the run."""
    from metalens_cli.cli import nanofin

    estimates = []
    announce = nanofin.announce
    monkeypatch.setattr(
        nanofin, "announce", lambda estimate, *a, **k: (estimates.append(estimate), announce(estimate, *a, **k))
    )
    code, out, err = invoke(
        capsys,
        *TINY_SWEEP,
        "--harmonics",
        "3",
        "--max-harmonics",
        "9",
        "--fabrication-tolerance",
        "1m",
        "-o",
        tmp_path / "sweep",
        "--json",
    )
    assert code == 0, err
    r = json.loads(out)
    assert r["recommended"]["converged"]["fins"] == 4
    fine = r["recommended"]["converged"]
    measured = r["seconds"] + fine["seconds"] + sum(t["seconds"] for t in fine["convergence"])
    assert estimates[0].seconds_max < 10 * measured + 1, (estimates[0].seconds_max, measured)


def test_an_output_folder_holding_files_needs_overwrite(capsys, tmp_path):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, _, err = invoke(capsys, *TINY_SWEEP, "--harmonics", "3", "--max-harmonics", "9", "-o", out)
    assert (
        code == 2
        and "--output: folder" in err
        and "'notes.txt'" in err
        and [p.name for p in out.iterdir()] == ["notes.txt"]
    )
    code, _, err = invoke(
        capsys, *TINY_SWEEP, "--harmonics", "3", "--max-harmonics", "9", "-o", out, "--overwrite", "--quiet"
    )
    assert code == 0, err
    assert (out / "notes.txt").read_text() == "mine" and (out / "sweep.npz").is_file()
