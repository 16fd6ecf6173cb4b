"""Design specs resolve to the same lenses however they are named."""

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from metalens_cli.errors import InputError
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.presets import load_preset

PRESETS = Path(__file__).parents[2] / "presets"


def test_hyperbolic_spec_with_options():
    d = resolve_design("hyperbolic:532nm", f_m=4e-3, aperture_m=0.2e-3)
    assert d.kind == "hyperbolic" and d.lambda_d_m == 532e-9 and d.lens.radial
    assert d.lens.pitch_m == 395e-9 and d.focal_length_m == 4e-3


def test_preset_spec_equals_hyperbolic_spec():
    from_preset = resolve_design(str(PRESETS / "hyperbolic-532.toml"))
    from_spec = resolve_design("hyperbolic:532nm", preset=load_preset(PRESETS / "hyperbolic-532.toml"))
    assert_allclose(from_preset.lens.theta.numpy(), from_spec.lens.theta.numpy(), rtol=0, atol=0)
    assert from_preset.preset.name == "hyperbolic-532"


def test_npy_and_run_directory(tmp_path):
    hyper = resolve_design("hyperbolic:532nm", f_m=4e-3, aperture_m=0.2e-3, pitch_m=395e-9)
    theta = hyper.lens.theta.numpy()
    np.save(tmp_path / "theta.npy", theta)
    d = resolve_design(str(tmp_path / "theta.npy"), f_m=4e-3, aperture_m=0.2e-3, pitch_m=395e-9)
    assert d.kind == "npy" and np.array_equal(d.lens.theta.numpy(), theta)
    text = (PRESETS / "split-spectrum.toml").read_text().replace('aperture = "2.516mm"', 'aperture = "0.2mm"')
    (tmp_path / "preset.toml").write_text(text)
    run = resolve_design(str(tmp_path))
    assert run.kind == "run" and run.preset.name == "split-spectrum" and run.lens.aperture_m == 0.2e-3
    assert np.array_equal(run.lens.theta.numpy(), theta)


@pytest.mark.parametrize(
    "spec, kwargs, option",
    [
        ("hyperbolic:532", {"f_m": 4e-3, "aperture_m": 1e-3}, "--design"),
        ("hyperbolic:532nm", {"aperture_m": 1e-3}, "--f"),
        ("nonexistent.npy", {}, "--design"),
        (str(PRESETS / "split-spectrum.toml"), {}, "--design"),  # learned: no θ in a preset
    ],
)
def test_bad_specs(spec, kwargs, option):
    with pytest.raises(InputError) as info:
        resolve_design(spec, **kwargs)
    assert info.value.field == option


def test_npy_shape_contradicting_pitch(tmp_path):
    np.save(tmp_path / "short.npy", np.zeros(10))
    with pytest.raises(InputError, match="samples"):
        resolve_design(str(tmp_path / "short.npy"), f_m=4e-3, aperture_m=1e-3, pitch_m=395e-9)
