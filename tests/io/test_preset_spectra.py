"""A preset's η(λ) and S^c (io.preset_spectra): RCWA η computed once and cached, the spline
between its samples against RCWA at the wavelengths between, and S^c = CRF·T·η."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.errors import InputError
from metalens_cli.io import cache, preset_spectra
from metalens_cli.io.presets import load_preset, preset_from_dict
from metalens_cli.optics.fin import Fin
from metalens_cli.optics.materials import FUSED_SILICA, SINX
from metalens_cli.optics.nanofin import fin_response

PRESETS = Path(__file__).parents[2] / "presets"
HARMONICS = 5  # η's dependence on λ, not its convergence, is under test: the cheapest truncation
NARROW = (500e-9, 540e-9)  # where the cache, not the sampling, is under test


def preset_with(**nanofin):
    data = tomllib.loads((PRESETS / "quick-split-spectrum.toml").read_text())
    table = {k: v for k, v in data["nanofin"].items() if not k.startswith("efficiency")}
    data["nanofin"] = {**table, "efficiency": "rcwa", "harmonics": HARMONICS, **nanofin}
    return preset_from_dict(data)


@pytest.fixture
def empty_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_rcwa_efficiency_is_computed_once_then_read_from_the_cache(empty_cache, monkeypatch):
    preset = preset_with()
    first = preset_spectra.preset_efficiency(preset.nanofin, NARROW)
    assert first.report["source"] == "rcwa" and not first.report["cached"]
    assert Path(first.report["cache_entry"]).parent.parent == empty_cache
    w = first.wavelengths_m
    direct = fin_response(Fin(395e-9, 700e-9, 305e-9, 125e-9), SINX.index(w), FUSED_SILICA.index(w), w, HARMONICS)
    np.testing.assert_allclose(first.values, direct.conversion, rtol=1e-12)

    def no_rcwa(*args, **kwargs):
        raise AssertionError("RCWA ran although the cache holds the answer")

    monkeypatch.setattr("metalens_cli.optics.nanofin.fin_response", no_rcwa)
    second = preset_spectra.preset_efficiency(preset.nanofin, NARROW)
    assert second.report["cached"] and np.array_equal(second.values, first.values)
    with pytest.raises(AssertionError, match="RCWA ran"):  # another fin is another entry
        preset_spectra.preset_efficiency(preset_with(height="650nm").nanofin, NARROW)


def test_the_interpolation_is_within_1e_3_of_rcwa_away_from_rayleigh_anomalies():
    """η of a 700 nm fin oscillates over ~100 nm of λ and has features below 1 nm wide; RCWA on a
    grid that shares no wavelength with the samples must agree with the interpolation within
    1e-3, except within 1 nm of the features the report lists as unresolved, and those must
    include the Rayleigh anomaly λ = n_sub·p (where the first orders start to propagate in the
    substrate and η has a kink)."""
    efficiency = preset_spectra.preset_efficiency(preset_with().nanofin, (540e-9, 620e-9))
    assert 20 < efficiency.wavelengths_m.size < 100
    probe = np.arange(541.3e-9, 620e-9, 1.7e-9)
    direct = fin_response(
        Fin(395e-9, 700e-9, 305e-9, 125e-9), SINX.index(probe), FUSED_SILICA.index(probe), probe, HARMONICS
    )
    rayleigh = FUSED_SILICA.index(np.array([576e-9]))[0].real * 395e-9
    unresolved = np.array(efficiency.report["unresolved_m"])
    assert np.abs(unresolved - rayleigh).min() < 1e-9
    away = np.all([np.abs(probe - u) > 1e-9 for u in unresolved], axis=0)
    assert away.sum() > 0.85 * probe.size  # two features, each about 2 nm wide
    assert np.abs(efficiency.at(probe) - direct.conversion)[away].max() < 1e-3
    assert efficiency.at([300e-9])[0] == pytest.approx(efficiency.values[0])  # flat beyond the range


def test_sensitivity_is_camera_times_filter_times_eta():
    rcwa = preset_with()
    ideal = preset_with(efficiency=[1.0], efficiency_wavelengths=["530nm"])
    grid = np.linspace(420e-9, 680e-9, 27)
    with_eta, without = (preset_spectra.preset_sensitivity(p, grid).values for p in (rcwa, ideal))
    eta = preset_spectra.preset_efficiency(rcwa.nanofin, rcwa.sensor.wavelength_range_m).at(grid)
    assert 0.2 < eta.min() and eta.max() < 0.95
    np.testing.assert_allclose(with_eta, without * eta, rtol=1e-12, atol=0)


def test_the_report_says_which_efficiency_was_used():
    table = preset_spectra.efficiency_report(load_preset(PRESETS / "split-spectrum.toml"), [(446e-9, 468e-9)])
    assert table["source"] == "table" and table["conversion"] == pytest.approx([0.784, 0.729, 0.669])
    assert 0.78 < table["band_mean"][0] < 0.785
    rcwa = preset_spectra.efficiency_report(preset_with())
    assert rcwa["source"] == "rcwa" and rcwa["harmonics"] == HARMONICS and rcwa["material"] == "sinx"
    assert rcwa["at_m"] == [457e-9, 530e-9, 628e-9] and all(0.3 < v < 0.9 for v in rcwa["conversion"])


def test_an_unwritable_cache_costs_only_the_recomputation_and_says_so(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("METALENS_CACHE", str(blocker))
    with pytest.warns(cache.CacheWarning, match=f"cache folder '{blocker}' cannot be used"):
        efficiency = preset_spectra.preset_efficiency(preset_with().nanofin, NARROW)
    assert efficiency.report["cache_entry"] is None and efficiency.values.shape == efficiency.wavelengths_m.shape
    assert cache.load("nanofin", "0" * 24) is None


@pytest.mark.parametrize(
    "change, field",
    [
        ({"efficiency_wavelengths": ["530nm"]}, "nanofin.efficiency_wavelengths"),  # a table's wavelengths with rcwa
        ({"efficiency": "exact"}, "nanofin.efficiency"),
        ({"harmonics": 20}, "nanofin.harmonics"),
        ({"material": "unobtainium"}, "nanofin.material"),
        ({"substrate": "2.0-0.1j"}, "nanofin.substrate"),
        ({"width": "400nm"}, "nanofin.width"),
    ],
)
def test_bad_nanofin_sections_name_the_key(change, field):
    with pytest.raises(InputError) as caught:
        preset_with(**change)
    assert caught.value.field == field


def test_a_material_file_is_read_relative_to_the_preset(tmp_path):
    (tmp_path / "film.csv").write_text("wavelength_nm,n\n380,2.05\n800,1.98\n")
    text = (
        (PRESETS / "quick-split-spectrum.toml")
        .read_text()
        .replace('length = "125nm"', 'length = "125nm"\nmaterial = "film.csv"')
    )
    (tmp_path / "p.toml").write_text(text)
    preset = load_preset(tmp_path / "p.toml")
    assert preset.nanofin.material == str(tmp_path / "film.csv")
    (tmp_path / "film.csv").unlink()
    with pytest.raises(InputError, match="nanofin.material"):
        load_preset(tmp_path / "p.toml")
