"""Tolerance analysis: the expected-value path against closed forms, the nanofin solver and the
drawn 2-D maps; budgets against the inverted closed forms; photographs of an error-free lens
score as the design; the command's JSON, exit codes and refusals."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.imaging import tolerance as tol
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.presets import load_preset
from metalens_cli.optics import fabrication as fab
from metalens_cli.optics.fin import Fin
from metalens_cli.optics.lens import hyperbolic

TINY = Path(__file__).parents[1] / "design" / "tiny.toml"
SMALL = ["--f", "300um", "--aperture", "80um", "--pixel-pitch", "0.5um"]


def small_design():
    return resolve_design("hyperbolic:532nm", f_m=300e-6, aperture_m=80e-6)


SETTINGS = tol.ToleranceSettings(pixel_pitch_m=0.5e-6, band_samples=1)


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path / "cache"))


def test_width_bias_gives_the_nanofin_solvers_efficiency_at_that_width(cache):
    from metalens_cli.io.materials import parse_material
    from metalens_cli.optics.nanofin import fin_response

    nanofin = dataclasses.replace(load_preset(TINY).nanofin, harmonics=9)
    waves = np.array([457e-9, 530e-9, 628e-9])
    from metalens_cli.io.fin_variations import fabricated_fin_light

    light = fabricated_fin_light(nanofin, waves, fab.FabricationErrors(width_bias_m=10e-9))
    n_fin = parse_material(nanofin.material, "m").index(waves)
    n_sub = parse_material(nanofin.substrate, "s").index(waves)
    wider = fin_response(Fin(395e-9, 700e-9, 315e-9, 125e-9), n_fin, n_sub, waves, 9)
    design = fin_response(Fin(395e-9, 700e-9, 305e-9, 125e-9), n_fin, n_sub, waves, 9)
    np.testing.assert_allclose(light.coherent, wider.conversion, rtol=1e-9)  # one fin: all coherent
    np.testing.assert_allclose(light.unconverted, wider.co_polarized, rtol=1e-9)
    np.testing.assert_allclose(light.design_conversion, design.conversion, rtol=1e-9)
    np.testing.assert_allclose(light.design_unconverted, design.co_polarized, rtol=1e-9)
    assert np.all(light.scattered == 0)
    assert light.solves == 2
    again = fabricated_fin_light(nanofin, waves, fab.FabricationErrors(width_bias_m=10e-9))
    assert again.solves == 0 and np.array_equal(again.coherent, light.coherent)  # from the cache
    spread = fabricated_fin_light(nanofin, waves, fab.FabricationErrors(width_sigma_m=8e-9))
    # Jensen: |E a|² ≤ E|a|²; a spread scatters some of the converted light
    assert np.all(spread.scattered > 0) and np.all(spread.coherent < spread.coherent + spread.scattered)


def test_light_is_conserved_and_the_zero_error_lens_is_the_design():
    design = dataclasses.replace(small_design(), efficiency=None)
    waves = SETTINGS.wavelengths()
    errors = fab.FabricationErrors(rotation_sigma_rad=0.1, missing=0.02, theta_levels=8)
    light = tol.fabricated_light(design, errors, waves)
    np.testing.assert_allclose(light.coherent + light.scattered + light.unconverted, 1.0, rtol=1e-12)
    nominal = tol.fabricated_light(design, fab.FabricationErrors(), waves)
    assert np.all(nominal.coherent == 1) and np.all(nominal.scattered == 0) and np.all(nominal.unconverted == 0)


def test_rotation_budget_inverts_the_marechal_form():
    result = tol.analyse(
        small_design(),
        fab.FabricationErrors(rotation_sigma_rad=0.1, theta_levels=8),
        SETTINGS,
        budget=tol.parse_budget("strehl -10%"),
    )
    rotation = result.cases[0]
    assert rotation["source"] == "rotation-sigma"
    # the expected PSF's peak falls by κ = exp(−(2σ)²), plus the flat veil's share (< 1e-4 here)
    np.testing.assert_allclose(rotation["relative"]["strehl"], math.exp(-0.04), rtol=1e-4)
    np.testing.assert_allclose(rotation["relative"]["core_far"], math.exp(-0.04), rtol=1e-3)
    assert [c["source"] for c in result.cases] == ["rotation-sigma", "theta-levels", "combined"]
    budgets = {b["source"]: b for b in result.budgets}
    # Strehl 0.9 at σ = √(−ln 0.9)/2 = 0.1623 rad (9.3°); θ levels: sinc²(π/5) = 0.875, sinc²(π/6) = 0.912
    assert budgets["rotation_sigma_rad"]["limits"][0]["largest"] == pytest.approx(
        math.sqrt(-math.log(0.9)) / 2, rel=2e-3
    )
    assert budgets["theta_levels"]["levels"] == 6
    assert all(c["within_budget"] for c in result.cases)


def test_monte_carlo_of_drawn_maps_agrees_with_the_expectation():
    errors = fab.FabricationErrors(rotation_sigma_rad=0.15)
    settings = tol.ToleranceSettings(bands=((532e-9, 10e-9),), band_samples=1, pixel_pitch_m=0.5e-6)
    mc = tol.monte_carlo(small_design(), errors, settings, 3, 0, budget=tol.parse_budget("strehl -5%"))
    strehl = mc["relative"]["strehl"][0]
    assert strehl["ci"][0] <= strehl["mean"] <= strehl["ci"][1]
    assert strehl["mean"] == pytest.approx(math.exp(-((2 * 0.15) ** 2)), abs=3e-3)  # 0.914: below the budget
    assert mc["yield"]["fraction"] == 0 and mc["yield"]["ci"][0] == 0 < mc["yield"]["ci"][1] < 1


def test_photographs_of_an_error_free_lens_score_as_the_design():
    preset = load_preset(TINY)
    lens = hyperbolic(532e-9, 1e-3, 0.2e-3, 395e-9)
    path = Path(__file__).parent / "_tolerance_theta.npy"
    try:
        np.save(path, lens.theta.numpy())
        design = resolve_design(str(path), preset)
    finally:
        path.unlink()
    same = tol.fabricated_design(design, fab.FabricationErrors(), "free")
    waves = np.linspace(400e-9, 700e-9, 301)
    np.testing.assert_allclose(tol.design_efficiency(same, waves), tol.design_efficiency(design, waves), rtol=1e-12)
    evaluation = tol.photo_settings(design, 1, [2000.0], SETTINGS)
    cases = [("free", fab.FabricationErrors()), ("rotation", fab.FabricationErrors(rotation_sigma_rad=0.3))]
    changes, _ = tol.photo_scores(design, cases, evaluation, ["dirt"], [0])
    free = [c for c in changes if c["source"] == "free"]
    assert free and all(c["change"] == pytest.approx(0.0, abs=1e-9) for c in free)
    rotated = [c for c in changes if c["source"] == "rotation" and c["metric"] == "psnr_db"]
    assert rotated and all(c["change"] < 0 for c in rotated)  # 30 % less focused light, more shot noise


def invoke(capsys, *args):
    code = run([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_command_json_and_csv(capsys, tmp_path):
    csv, plot = tmp_path / "t.csv", tmp_path / "t.png"
    code, out, _ = invoke(
        capsys,
        "tolerance",
        "hyperbolic:532nm",
        *SMALL,
        "--rotation-sigma",
        "3deg",
        "--missing",
        "0.5%",
        "--band-samples",
        "1",
        "--budget",
        "core-far -5%",
        "--csv",
        csv,
        "--plot",
        plot,
        "--json",
    )
    assert code == 0
    report = json.loads(out)
    assert {c["source"] for c in report["cases"]} == {"rotation-sigma", "missing", "combined"}
    combined = report["cases"][-1]["relative"]["strehl"]
    assert combined == pytest.approx([math.exp(-((2 * math.radians(3)) ** 2)) * 0.995**2] * 3, rel=1e-4)
    assert len(csv.read_text().splitlines()) == 1 + 4 * 3  # the design and three cases, three bands
    assert plot.stat().st_size > 0 and report["plot"] == str(plot)


@pytest.mark.parametrize(
    "args, option",
    [
        (["--theta-levels", "1"], "--theta-levels"),
        (["--missing", "150%"], "--missing"),
        (["--rotation-sigma", "-2deg"], "--rotation-sigma"),
        (["--width-bias", "10"], "--width-bias"),
        (["--rotation-sigma", "2deg", "--budget", "sharpness -10%"], "--budget"),
        (["--rotation-sigma", "2deg", "--budget", "strehl -150%"], "--budget"),
        (["--width-bias", "10nm"], "--preset"),
        ([], "--rotation-sigma"),
    ],
)
def test_hostile_inputs_exit_2_naming_the_option(capsys, args, option):
    code, out, err = invoke(capsys, "tolerance", "hyperbolic:532nm", *SMALL, *args)
    assert code == 2 and out == ""
    assert option in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


PRESET = """name = "tol"
[lens]
focal_length = "300um"
aperture = "80um"
design = "hyperbolic"
design_wavelength = "532nm"
[nanofin]
pitch = "395nm"
height = "700nm"
width = "305nm"
length = "125nm"
efficiency_wavelengths = ["457nm", "530nm", "628nm"]
efficiency = [0.784, 0.729, 0.669]
[sensor]
pixel_pitch = "0.5um"
pixels = 32
[scene]
z_near = "10mm:12mm"
z_far = "1m:20m"
[optimize]
steps = 1
learning_rate = 0.1
t_max = 1
[tolerance]
rotation_sigma = "2deg"
missing = 0.001
stitch_sigma = "STITCH"
budget = "strehl -10%"
"""


def test_a_presets_tolerance_table_sets_what_options_do_not(capsys, tmp_path):
    preset = tmp_path / "tol.toml"
    preset.write_text(PRESET.replace("STITCH", "20nm"), encoding="utf-8")
    code, out, _ = invoke(capsys, "tolerance", preset, "--band-samples", "1", "--missing", "0.2%", "--json")
    report = json.loads(out)
    assert code == 0 and [c["errors"] for c in report["cases"][:3]] == [
        {"rotation_sigma_rad": pytest.approx(math.radians(2))},
        {"missing": 0.002},  # the option wins over the table
        {"stitch_sigma_m": 20e-9},
    ]
    assert {b["source"] for b in report["budgets"]} == {"rotation_sigma_rad", "missing", "stitch_sigma_m"}
    from metalens_cli.io.presets import to_toml

    again = tmp_path / "again.toml"
    again.write_text(to_toml(load_preset(preset)), encoding="utf-8")
    assert load_preset(again).tolerance == load_preset(preset).tolerance
    preset.write_text(PRESET.replace("STITCH", "-3nm"), encoding="utf-8")
    code, out, err = invoke(capsys, "tolerance", preset)
    assert code == 2 and "tolerance.stitch_sigma" in err
