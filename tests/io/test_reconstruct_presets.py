"""Reconstruction presets: the shipped ones load, round-trip through TOML, and bad keys are named."""

from __future__ import annotations

from pathlib import Path

import pytest

from metalens_cli.errors import InputError
from metalens_cli.io.reconstruct_presets import (
    load_reconstruct_preset,
    reconstruct_preset_from_dict,
    reconstruct_to_toml,
)

PRESETS = Path(__file__).parents[2] / "presets"


@pytest.mark.parametrize("name", ["quick-reconstruct", "reconstruct"])
def test_shipped_presets_load_and_round_trip(name, tmp_path):
    preset = load_reconstruct_preset(PRESETS / f"{name}.toml")
    copy = tmp_path / "copy.toml"
    copy.write_text(reconstruct_to_toml(preset))
    again = load_reconstruct_preset(copy)
    assert again.network == preset.network and again.train == preset.train and again.data == preset.data


@pytest.mark.parametrize(
    "document, field",
    [
        ({"train": {"steps": 1, "crop": 512}, "data": {"pool_pixels": 256}}, "train.crop"),
        ({"train": {"steps": 1}, "data": {"pool_pixels": 600}}, "data.pool_pixels"),  # beyond the 512² sensor
        ({"train": {"steps": 1}, "data": {"sensor_pixels": 8}}, "data.sensor_pixels"),
        ({"train": {"steps": 1}, "network": {"spectral_bins": 1}}, "network.spectral_bins"),
        ({"train": {"steps": 1, "lr": 1}}, "train.lr"),
        ({"train": {"steps": -1}}, "train.steps"),
        ({"train": {"steps": 1}, "data": {"obstructions": ["mud"]}}, "data.obstructions"),
        ({"train": {"steps": 1}, "data": {"wavelengths": "500nm"}}, "data.wavelengths"),
        ({"network": {"width": 16}}, "train"),
        ({"train": {"steps": 1}, "optimize": {}}, "optimize"),
        ({"name": "../evil", "train": {"steps": 1}}, "name"),  # the camera presets' rule: it names runs/NAME
        ({"name": ".hidden", "train": {"steps": 1}}, "name"),
    ],
)
def test_bad_presets_name_the_key(document, field):
    with pytest.raises(InputError) as error:
        reconstruct_preset_from_dict(document)
    assert error.value.field == field
