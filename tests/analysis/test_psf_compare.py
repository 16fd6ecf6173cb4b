"""psf compare against cases with known answers: a cube with itself, a shifted copy, a Gaussian
sampled at two pitches, wavelengths between and outside the simulated ones."""

import math
import re

import numpy as np
import pytest
from synthetic import gaussian_spot

from metalens_cli.analysis.psf_compare import compare_cubes
from metalens_cli.errors import InputError
from metalens_cli.io.exr import PsfCube

PITCH = 2e-6


def cube(psfs, wavelengths_nm, pitch=PITCH, depths=(math.inf,)):
    psf = np.asarray(psfs, dtype=np.float32).reshape(len(depths), len(wavelengths_nm), *np.shape(psfs)[-2:])
    return PsfCube(psf, None, np.array(wavelengths_nm) * 1e-9, np.array(depths, dtype=float), {"pixel_pitch_m": pitch})


def spot(n, sigma, offset=(0.0, 0.0)):
    return gaussian_spot(n, n, (n // 2 + offset[0], n // 2 + offset[1]), sigma)


def test_a_cube_against_itself_has_peak_ratio_one_and_no_error():
    c = cube([spot(41, 1.5), spot(41, 2.5)], [530, 630])
    result = compare_cubes(c, c)
    for pair in result.pairs:
        assert pair["peak_ratio"] == pytest.approx(1, abs=1e-12) and pair["relative_l2"] < 1e-12
        assert pair["simulated"] == "exact" and pair["shift_px"] == [0.0, 0.0]
        assert pair["mtf50_lpmm"]["measured"] == pair["mtf50_lpmm"]["simulated"]
        ee = pair["encircled_energy"]
        assert ee["measured"] == pytest.approx(ee["simulated"]) and ee["measured"] == sorted(ee["measured"])


def test_a_shifted_copy_is_registered_back():
    measured = cube([spot(41, 2.0, (0.4, -1.3))], [530])
    result = compare_cubes(measured, cube([spot(41, 2.0)], [530]))
    pair = result.pairs[0]
    assert np.allclose(pair["shift_px"], (0.4, -1.3), atol=0.05)
    assert pair["relative_l2"] < 0.02 and pair["peak_ratio"] == pytest.approx(1, abs=0.02)


def test_a_broader_measured_spot_has_a_lower_peak_and_mtf50():
    pair = compare_cubes(cube([spot(41, 3.0)], [530]), cube([spot(41, 1.5)], [530])).pairs[0]
    assert pair["peak_ratio"] < 0.3 and pair["mtf50_lpmm"]["measured"] < 0.6 * pair["mtf50_lpmm"]["simulated"]
    assert pair["fwhm_m"]["measured"] == pytest.approx(2 * pair["fwhm_m"]["simulated"], rel=0.05)  # FWHM ∝ σ


def test_a_simulation_at_half_the_pitch_is_resampled_onto_the_measured_grid():
    """The same Gaussian (σ = 3 µm) sampled at 2 µm and at 1 µm pixels."""
    measured = cube([spot(31, 1.5)], [530])
    simulated = cube([spot(81, 3.0)], [530], pitch=PITCH / 2)
    result = compare_cubes(measured, simulated)
    assert result.resampled and result.pixels == 31
    pair = result.pairs[0]
    assert pair["relative_l2"] < 0.02 and pair["peak_ratio"] == pytest.approx(1, abs=0.02)


def test_wavelengths_between_are_interpolated_and_outside_refused():
    simulated = cube([spot(31, 1.0), spot(31, 3.0)], [520, 540])
    measured = cube([spot(31, 2.0), spot(31, 2.0), spot(31, 2.0)], [510, 530, 540])
    result = compare_cubes(measured, simulated)
    how = {round(p["wavelength_m"] * 1e9): p["simulated"] for p in result.pairs}
    assert how == {530: "interpolated from 520 and 540 nm", 540: "exact"}
    assert [round(r["wavelength_m"] * 1e9) for r in result.refused] == [510]
    strict = compare_cubes(measured, simulated, interpolate=False)
    assert [round(p["wavelength_m"] * 1e9) for p in strict.pairs] == [540]


def test_no_common_depth_is_refused():
    with pytest.raises(InputError, match="no simulated PSF at this depth"):
        compare_cubes(cube([spot(21, 1.0)], [530], depths=(0.045,)), cube([spot(21, 1.0)], [530]))


def test_each_psfs_own_figures_do_not_depend_on_the_other():
    """FWHM and encircled energy of the measured PSF are the same against a centred and against
    an off-centre simulation. FWHM of a Gaussian integrated over pixels: 2.3548 √(σ² + 1/12)
    pixels (the box adds its variance)."""
    measured = cube([spot(41, 2.0)], [530])
    centred = compare_cubes(measured, cube([spot(41, 2.0)], [530])).pairs[0]
    shifted = compare_cubes(measured, cube([spot(41, 2.0, (3.3, -2.7))], [530])).pairs[0]
    assert centred["fwhm_m"]["measured"] == shifted["fwhm_m"]["measured"]
    assert centred["encircled_energy"]["measured"] == shifted["encircled_energy"]["measured"]
    assert shifted["fwhm_m"]["simulated"] == pytest.approx(centred["fwhm_m"]["simulated"], rel=0.004)
    assert centred["fwhm_m"]["measured"] == pytest.approx(2.3548 * math.sqrt(2.0**2 + 1 / 12) * PITCH, rel=0.004)


@pytest.mark.parametrize(
    ("measured_pitch", "simulated_pitch", "words"),
    [
        (
            1e-12,
            1.85e-6,
            "MEASURED: its 31 pixels of 0.001 nm span 0.031 nm, less than half its shortest wavelength (530 nm)",
        ),
        (
            2e-6,
            1e-12,
            "SIMULATED: its 31 pixels of 0.001 nm span 0.031 nm, less than half its shortest wavelength (530 nm)",
        ),
        (0.1e-6, 1.85e-6, "MEASURED: its window (31 pixels of 100 nm) spans under 3 simulated pixels of 1.85 µm"),
    ],
    ids=["1 pm measured", "1 pm simulated", "a window within one simulated pixel"],
)
def test_pitches_no_psf_can_have_are_refused(measured_pitch, simulated_pitch, words):
    """A 1 pm pitch (the MTF50 would read 1e8 lp/mm) and a measured window inside 1.1 simulated
    pixels: nothing to compare, whatever the resampling would make of it."""
    with pytest.raises(InputError, match=re.escape(words)):
        compare_cubes(
            cube([spot(31, 2.0)], [530], pitch=measured_pitch), cube([spot(31, 2.0)], [530], pitch=simulated_pitch)
        )


def test_a_simulation_much_coarser_than_the_measurement_is_warned_about():
    """The same Gaussian (σ = 4 µm) measured at 1 µm, simulated at 4 µm: compared (resampled),
    with one line saying the simulation is interpolated; at 2 µm, within 2×, nothing is said."""
    measured = cube([spot(41, 4.0)], [530], pitch=1e-6)
    coarse = compare_cubes(measured, cube([spot(21, 1.0)], [530], pitch=4e-6))
    assert coarse.resampled and len(coarse.warnings) == 1 and "are 4× the measured (1 µm)" in coarse.warnings[0]
    assert compare_cubes(measured, cube([spot(31, 2.0)], [530], pitch=2e-6)).warnings == []


@pytest.mark.parametrize(
    ("measured", "simulated", "words"),
    [
        (
            cube([spot(41, 2.0)], [530]),
            cube([spot(41, 2.0)[19:22, 19:22]], [530]),
            "SIMULATED: its window (3 × 3 pixels of 2 µm, 6 µm across) covers 3 × 3 measured pixels of 2 µm: too small "
            "to compare PSFs (expected a simulated window at least 8 measured pixels (16 µm) wide",
        ),
        (
            cube([spot(41, 2.0)], [530]),
            cube([spot(161, 50.0)], [530], pitch=PITCH / 50),
            "SIMULATED: its window (161 × 161 pixels of 40 nm, 6.44 µm across) covers 3 × 3 measured pixels",
        ),
        (
            cube([spot(5, 0.7)], [530]),
            cube([spot(41, 2.0)], [530]),
            "MEASURED: the common window is 5 × 5 pixels of 2 µm, its own window: too small to compare PSFs "
            "(expected a measured window of at least 8 × 8 pixels)",
        ),
    ],
    ids=["3x3 crop", "1/50 pitch", "5x5 measured"],
)
def test_a_common_window_too_small_to_compare_psfs_is_refused(measured, simulated, words):
    """A 3 × 3 common window gave peak ratios of 1.0 and encircled energies of 1.000 for any PSFs."""
    with pytest.raises(InputError, match=re.escape(words)):
        compare_cubes(measured, simulated)


def test_encircled_energy_beyond_the_window_is_not_reported_and_light_outside_it_is_refused():
    """A 9 × 9 crop of the simulation: the default radii 10 and 20 µm leave the 18 µm window
    (None, one warning); a blur disc of σ = 15 pixels, 5 % of it in the window, is not compared."""
    measured = cube([spot(61, 1.5), spot(61, 15.0)], [530, 630])
    simulated = cube([spot(61, 1.5)[26:35, 26:35], spot(61, 15.0)[26:35, 26:35]], [530, 630])
    result = compare_cubes(measured, simulated)
    assert result.pixels == 9 and [round(p["wavelength_m"] * 1e9) for p in result.pairs] == [530]
    ee = result.pairs[0]["encircled_energy"]
    assert ee["measured"][1:] == [None, None] and ee["simulated"][1:] == [None, None] and 0.5 < ee["measured"][0] <= 1
    assert [round(r["wavelength_m"] * 1e9) for r in result.refused] == [630]
    assert "the compared window (9 × 9 pixels of 2 µm) holds" in result.refused[0]["reason"]
    assert any(
        "encircled energy at 10 µm and 20 µm is not reported" in w and "18 µm across" in w for w in result.warnings
    )
    assert all(r is not None for r in compare_cubes(measured, measured).pairs[0]["encircled_energy"]["measured"])


# ---------------------------------------------------------------------------- field cubes


def field_cube(psfs, angles, centres, pitch=PITCH, azimuth=0.0):
    """A field cube of one depth (inf) and one wavelength (530 nm): ``psfs`` (F, N, N), window
    centres [column, row] in its own pixels."""
    psf = np.asarray(psfs, dtype=np.float32)[:, None, None]
    metadata = {
        "pixel_pitch_m": pitch,
        "field_angles_rad": list(angles),
        "field_azimuth_rad": azimuth,
        "chief_ray_m": [[c * pitch, r * pitch] for c, r in centres],
        "window_centre_px": [list(c) for c in centres],
    }
    return PsfCube(psf[0], None, np.array([530e-9]), np.array([math.inf]), metadata, psf, None)


def test_field_cubes_are_compared_field_by_field():
    measured = field_cube([spot(41, 1.5), spot(41, 2.0), spot(41, 2.5)], [0.0, 0.05, 0.1], [(0, 0), (100, 0), (200, 0)])
    simulated = field_cube([spot(41, 2.5), spot(41, 1.5)], [0.1, 0.0], [(200, 0), (0, 0)])  # other order, no 0.05
    result = compare_cubes(measured, simulated)
    assert [(f["field"], f["simulated_field"]) for f in result.fields] == [(0, 1), (1, None), (2, 0)]
    assert [p["field"] for p in result.pairs] == [0, 2] and result.pairs[1]["field_angle_deg"] == pytest.approx(
        math.degrees(0.1)
    )
    for pair in result.pairs:  # each with its own partner: identical PSFs
        assert pair["peak_ratio"] == pytest.approx(1, abs=1e-12) and pair["relative_l2"] < 1e-12
        assert pair["sensor_shift_px"] == [0.0, 0.0]
    assert result.refused == [
        {
            "field": 1,
            "field_angle_deg": pytest.approx(math.degrees(0.05)),
            "depth_m": None,
            "wavelength_m": 530e-9,
            "reason": "no simulated field at this field angle",
        }
    ]
    assert [s["field"] for s in result.scans] == [0, 2] and result.warnings == []


@pytest.mark.parametrize(("sim_pitch", "sim_centre"), [(PITCH, 103), (PITCH / 2, 206)])
def test_window_centres_are_taken_into_account(sim_pitch, sim_centre):
    """The measured window is centred on sensor column 100, the simulated on column 103 (206 half
    pixels): a measured spot 3 columns right of its window's centre lies where the simulated spot
    does on the sensor. The registration finds the windows' shift (0, 3); on the sensor: (0, 0)."""
    n_sim = 41 if sim_pitch == PITCH else 81
    measured = field_cube([spot(41, 1.5), spot(41, 2.0, (0.0, 3.0))], [0.0, 0.1], [(0, 0), (100, 0)])
    simulated = field_cube(
        [spot(n_sim, 1.5 * PITCH / sim_pitch), spot(n_sim, 2.0 * PITCH / sim_pitch)],
        [0.0, 0.1 + 5e-7],  # within 1e-6 rad
        [(0, 0), (sim_centre, 0)],
        pitch=sim_pitch,
    )
    result = compare_cubes(measured, simulated)
    assert result.fields[1]["window_offset_px"] == pytest.approx([0.0, 3.0])
    pair = result.pairs[1]
    assert np.allclose(pair["shift_px"], (0.0, 3.0), atol=0.05)
    assert np.allclose(pair["sensor_shift_px"], (0.0, 0.0), atol=0.05)
    assert pair["relative_l2"] < 0.03


def test_a_field_cube_against_an_on_axis_cube_compares_field_0_with_a_warning():
    on_axis = cube([spot(41, 1.5)], [530])
    fields = field_cube([spot(41, 1.5), spot(41, 3.0)], [0.0, 0.1], [(0, 0), (100, 0)])
    for measured, simulated, which in ((on_axis, fields, "simulated"), (fields, on_axis, "measured")):
        result = compare_cubes(measured, simulated)
        assert result.fields == [] and len(result.pairs) == 1 and "field" not in result.pairs[0]
        assert result.pairs[0]["relative_l2"] < 1e-12  # field 0, not field 1
        assert result.warnings == [
            f"the {which} cube holds 2 fields and the {'measured' if which == 'simulated' else 'simulated'} cube is "
            f"on axis: only the {which} cube's field 0 (at 0°) is compared"
        ]
    plain = compare_cubes(on_axis, on_axis)
    assert plain.fields == [] and set(plain.pairs[0]) == {
        "depth_m",
        "wavelength_m",
        "simulated",
        "shift_px",
        "peak_ratio",
        "fwhm_m",
        "encircled_energy",
        "relative_l2",
        "mtf50_lpmm",
    }


def test_field_cubes_at_other_azimuths_or_angles_are_refused():
    measured = field_cube([spot(41, 1.5)], [0.1], [(100, 0)])
    with pytest.raises(InputError, match="azimuth 90°, the measured cube's at 0°"):
        compare_cubes(measured, field_cube([spot(41, 1.5)], [0.1], [(0, 100)], azimuth=math.pi / 2))
    compare_cubes(measured, field_cube([spot(41, 1.5)], [0.1], [(100, 0)], azimuth=2 * math.pi))  # the same azimuth
    with pytest.raises(InputError, match=re.escape("none of its field angles (11.46°) is one of the measured cube's")):
        compare_cubes(measured, field_cube([spot(41, 1.5)], [0.2], [(200, 0)]))
