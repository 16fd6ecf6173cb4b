"""Preset loading and validation."""

import tomllib
from pathlib import Path

import pytest

from metalens_cli.errors import InputError
from metalens_cli.io.presets import load_preset, preset_from_dict, to_dict

PRESETS = Path(__file__).parents[2] / "presets"


def test_paper_preset_values():
    p = load_preset(PRESETS / "split-spectrum.toml")
    assert (p.lens.focal_length_m, p.lens.aperture_m) == (4e-3, 2.516e-3)
    assert (p.nanofin.pitch_m, p.nanofin.height_m, p.nanofin.width_m, p.nanofin.length_m) == (395e-9, 700e-9, 305e-9, 125e-9)
    assert p.nanofin.efficiency == (0.784, 0.729, 0.669)
    assert p.filter.centers_m == (457e-9, 530e-9, 628e-9) and p.filter.widths_m == (22e-9, 20e-9, 28e-9)
    assert (p.sensor.pixel_pitch_m, p.sensor.pixels) == (1.85e-6, 512)
    assert p.scene.z_near_m == (0.04, 0.05) and p.scene.z_far_m == (1.0, 20.0)
    assert (p.optimize.learning_rate, p.optimize.t_max, p.optimize.optimizer) == (0.1, 5000, "adamw")


def test_every_shipped_preset_loads():
    for path in PRESETS.glob("*.toml"):
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
    with pytest.raises(InputError, match="cannot read"):
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
