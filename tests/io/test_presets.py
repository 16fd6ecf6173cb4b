"""Preset loading and validation."""

import dataclasses
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metalens_cli.errors import InputError
from metalens_cli.io.presets import load_preset, preset_from_dict, to_dict, to_toml

PRESETS = Path(__file__).parents[2] / "presets"


def test_paper_preset_values():
    p = load_preset(PRESETS / "split-spectrum.toml")
    assert (p.lens.focal_length_m, p.lens.aperture_m) == (4e-3, 2.516e-3)
    assert (p.nanofin.pitch_m, p.nanofin.height_m, p.nanofin.width_m, p.nanofin.length_m) == (
        395e-9,
        700e-9,
        305e-9,
        125e-9,
    )
    assert p.nanofin.efficiency == (0.784, 0.729, 0.669)
    assert p.filter.centers_m == (457e-9, 530e-9, 628e-9) and p.filter.widths_m == (22e-9, 20e-9, 28e-9)
    assert (p.sensor.pixel_pitch_m, p.sensor.pixels) == (1.85e-6, 512)
    assert p.scene.z_near_m == (0.04, 0.05) and p.scene.z_far_m == (1.0, 20.0)
    assert (p.optimize.learning_rate, p.optimize.t_max, p.optimize.optimizer) == (0.1, 5000, "adamw")


def test_every_shipped_preset_loads():
    for path in PRESETS.glob("*.toml"):
        if "[train]" in path.read_text():
            continue  # a reconstruction preset (tests/io/test_reconstruct_presets.py)
        assert to_dict(load_preset(path))["name"] == path.stem


def _paper_dict():
    return tomllib.loads((PRESETS / "split-spectrum.toml").read_text())


@pytest.mark.parametrize(
    "mutate, path, why",
    [
        (lambda d: d["lens"].update(focal_lenght="4mm"), "lens.focal_lenght", "unknown key"),
        (lambda d: d["lens"].pop("aperture"), "lens.aperture", "missing"),
        (lambda d: d["lens"].update(focal_length="4"), "lens.focal_length", "no unit"),
        (lambda d: d["sensor"].update(pixels=0), "sensor.pixels", "out of range"),
        (lambda d: d["nanofin"].update(efficiency=[0.7, 1.2, 0.6]), "nanofin.efficiency", "out of range"),
        (lambda d: d["nanofin"].update(efficiency=[0.7, 0.6]), "nanofin.efficiency", "one value per"),
        (lambda d: d["optimize"].update(learning_rate="fast"), "optimize.learning_rate", "expected a number"),
        (lambda d: d.pop("scene"), "scene", "missing section"),
        (lambda d: d.update(extra=1), "extra", "unknown"),
        (lambda d: d["lens"].update(design="magic"), "lens.design", "not allowed"),
        (lambda d: d["optimize"].update(field_angles="3"), "optimize.field_angles", "not an angle"),
        (lambda d: d["optimize"].update(field_angles=["0deg", "70deg"]), "optimize.field_angles", "past 60°"),
        (lambda d: d["optimize"].update(field_angles=[]), "optimize.field_angles", "at least one angle"),
        (lambda d: d["optimize"].update(radial_margin=0.01), "optimize.radial_margin", "out of range"),
    ],
)
def test_validation_names_the_key_path(mutate, path, why):
    data = _paper_dict()
    mutate(data)
    with pytest.raises(InputError) as info:
        preset_from_dict(data)
    assert info.value.field == path and why in str(info.value)


def test_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("[lens\n")
    with pytest.raises(InputError, match="broken.toml is not valid TOML"):
        load_preset(bad)
    with pytest.raises(InputError, match="no such file"):
        load_preset(tmp_path / "missing.toml")


def test_obstruction_section_optional_and_validated():
    data = _paper_dict()
    assert preset_from_dict(data).obstruction.dirt_coverage == (0.15, 0.35)
    data.pop("obstruction")
    assert preset_from_dict(data).obstruction.fence_pitch_m == 3e-3  # defaults when absent
    data["obstruction"] = {"dirt_coverage": [0.5, 0.2]}
    with pytest.raises(InputError) as info:
        preset_from_dict(data)
    assert info.value.field == "obstruction.dirt_coverage"


def test_filter_and_efficiency_from_csv_relative_to_preset(tmp_path):
    import numpy as np

    from metalens_cli.analysis.bands import bands_from_transmission, read_filter_csv
    from metalens_cli.io.preset_spectra import preset_sensitivity

    nm = np.arange(380, 781)
    inside = ((nm >= 446) & (nm <= 468)) | ((nm >= 520) & (nm <= 540)) | ((nm >= 614) & (nm <= 642))
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "filter.csv").write_text(
        "wavelength_nm,T\n" + "\n".join(f"{w},{90 if i else 0}" for w, i in zip(nm, inside))
    )
    (tmp_path / "data" / "eta.csv").write_text("\n".join(f"{w},0.7" for w in nm))
    text = (PRESETS / "split-spectrum.toml").read_text()
    text = text.replace(
        'centers = ["457nm", "530nm", "628nm"]\nwidths = ["22nm", "20nm", "28nm"]    # FWHM', 'csv = "data/filter.csv"'
    )
    text = text.replace(
        "efficiency = [0.784, 0.729, 0.669]", 'efficiency = [0.784, 0.729, 0.669]\nefficiency_csv = "data/eta.csv"'
    )
    (tmp_path / "csv.toml").write_text(text)
    preset = load_preset(tmp_path / "csv.toml")
    assert preset.filter.csv == str((tmp_path / "data" / "filter.csv").resolve())
    bands = bands_from_transmission(*read_filter_csv(preset.filter.csv))
    # 0 → 0.9 between 445 and 446 nm crosses 0.5 at 445 + 0.5/0.9 nm
    assert [round(b.lo_m * 1e9, 3) for b in bands] == [445.556, 519.556, 613.556]
    s = preset_sensitivity(preset)
    outside = (s.wavelengths_m > 480e-9) & (s.wavelengths_m < 505e-9)
    assert np.all(s.values[:, outside] == 0)  # the CSV filter blocks between bands


def test_missing_csv_named(tmp_path):
    text = (
        (PRESETS / "split-spectrum.toml")
        .read_text()
        .replace(
            'centers = ["457nm", "530nm", "628nm"]\nwidths = ["22nm", "20nm", "28nm"]    # FWHM', 'csv = "nope.csv"'
        )
    )
    (tmp_path / "p.toml").write_text(text)
    with pytest.raises(InputError, match="filter.csv: no such file"):
        load_preset(tmp_path / "p.toml")


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(description=st.text(), name=st.from_regex(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,20}", fullmatch=True))
def test_run_directory_toml_round_trips_any_text(tmp_path_factory, description, name):
    """The writer of run directories' preset.toml: any description (newlines, quotes, control
    characters, astral planes) and any legal name read back equal, as does every value."""
    preset = dataclasses.replace(load_preset(PRESETS / "split-spectrum.toml"), description=description, name=name)
    text = to_toml(preset)
    assert tomllib.loads(text)["description"] == description
    path = tmp_path_factory.mktemp("round") / "preset.toml"
    path.write_text(text, encoding="utf-8")
    again = load_preset(path)
    assert to_dict(dataclasses.replace(again, source=None)) == to_dict(dataclasses.replace(preset, source=None))


def test_preset_name_must_not_leave_runs():
    for name in ("../../x", "/abs", ".hidden", "a b", ""):
        data = _paper_dict()
        data["name"] = name
        with pytest.raises(InputError, match="not a plain name"):
            preset_from_dict(data)


def test_field_angles_read_as_a_list_or_a_range_and_round_trip(tmp_path):
    """``[optimize] field_angles``: on axis by default; an array of angles or the CLI's list and
    range form, in radians; written back by to_toml to the same angles."""
    import math

    data = _paper_dict()
    assert preset_from_dict(data).optimize.field_angles_rad == (0.0,)
    data["optimize"]["field_angles"] = ["0deg", "6.75deg", "0.05rad"]
    listed = preset_from_dict(data)
    assert listed.optimize.field_angles_rad == (0.0, math.radians(6.75), 0.05)
    data["optimize"]["field_angles"] = "0:6:3deg"
    assert preset_from_dict(data).optimize.field_angles_rad == pytest.approx(tuple(map(math.radians, (0, 3, 6))))
    path = tmp_path / "again.toml"
    path.write_text(to_toml(listed))
    assert load_preset(path).optimize.field_angles_rad == listed.optimize.field_angles_rad
