"""One camera for every design: equal light before the filter, η in the budget, zero-order light
against its closed form, one nanofin model per table."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from metalens_cli.imaging.camera import Camera, channel_budget, efficiency_sources, electrons
from metalens_cli.imaging.evaluation import expose
from metalens_cli.imaging.formation import zero_order_light
from metalens_cli.io.designs import resolve_design
from metalens_cli.io.presets import load_preset
from metalens_cli.optics.spectra import camera_response, wavelength_grid
from metalens_cli.optics.zero_order import zero_order_psf, zero_order_radius_m

PAPER = dict(f_m=4e-3, aperture_m=2.516e-3, pitch_m=None)


def _design(preset: str | None, spec: str = "hyperbolic:532nm"):
    return resolve_design(spec, load_preset(preset) if preset else None, **(PAPER if preset is None else {}))


def test_a_filter_of_throughput_t_gets_t_times_the_photons_on_a_grey_wall():
    """Noise variance of a grey wall g exposed at L electrons: g/(L·t_c) + (σ_r/(L·t_c))².
    The split preset's filter passes t_c of the light an unfiltered design with the same fin
    gets; t_c computed independently here from the filter's band model and the camera."""
    split, bare = _design("presets/quick-split-spectrum.toml"), _design("presets/hyperbolic-532.toml")
    t_split, t_bare = channel_budget(split).throughput, channel_budget(bare).throughput
    # independently: ∫CRF·T·η dλ / ∫CRF·η dλ with T the preset's bands and η its table (the same fin in both)
    grid = wavelength_grid()
    crf = camera_response(grid) * np.interp(grid, [457e-9, 530e-9, 628e-9], [0.784, 0.729, 0.669])
    f = load_preset("presets/quick-split-spectrum.toml").filter
    band = np.zeros_like(grid)
    for c, w in zip(f.centers_m, f.widths_m):
        band = np.maximum(band, f.peak_transmission * (np.abs(grid - c) < w / 2))
    ratio = (crf * band).sum(axis=1) / crf.sum(axis=1)
    # a hard-edged band against the smooth 2 nm edges: within a few per cent of the throughput
    np.testing.assert_allclose(t_split / t_bare, ratio, rtol=0.06)
    camera = Camera(light=2000.0, read_electrons=0.0)
    g = 0.3
    wall = np.full((3, 128, 128), g, dtype=np.float32)
    variances = []
    for budget in (t_split, t_bare):
        counts = electrons(dataclasses.replace(channel_budget(bare), throughput=budget), camera)
        noisy = expose(wall, counts, camera.read_electrons, generator=7)
        variances.append(noisy.reshape(3, -1).var(axis=1))
    np.testing.assert_allclose(variances[0], g / (2000.0 * t_split), rtol=0.05)
    np.testing.assert_allclose(variances[1] / variances[0], t_split / t_bare, rtol=0.07)


def test_eta_costs_light_and_an_ideal_fin_none():
    """η of the paper's fin (0.67-0.78) is in the budget: t_c of the unfiltered preset equals
    the CRF-weighted mean of η, and a design with η = 1 collects all the light (t_c = 1)."""
    bare = _design("presets/hyperbolic-532.toml")
    ideal = _design(None)
    np.testing.assert_allclose(channel_budget(ideal).throughput, 1.0)
    assert channel_budget(ideal).zero_order.max() == 0.0  # η = 1 leaves nothing unconverted
    t = channel_budget(bare).throughput
    assert np.all((t > 0.66) & (t < 0.79))


def test_zero_order_psf_is_the_shadow_of_the_aperture():
    """A far point's unconverted light fills a disc of the aperture's size; a near one's a disc
    a(1 + d/z): its area in pixels matches π R² to the pixel integration."""
    pitch = 1.85e-6
    for depth, radius_m in ((math.inf, 1.258e-3), (0.045, 1.258e-3 * (1 + 4 / 45))):
        assert zero_order_radius_m(2.516e-3, 4e-3, depth) == pytest.approx(radius_m)
        psf = zero_order_psf(2.516e-3, 4e-3, depth, pitch)
        assert psf.sum() == pytest.approx(1.0)
        inside = psf > 0.5 * psf.max()
        r_px = radius_m / pitch
        assert inside.sum() == pytest.approx(math.pi * r_px**2, rel=2e-3)
        n = psf.shape[0] // 2
        assert psf[n, n] == pytest.approx(1 / (math.pi * r_px**2), rel=2e-3)  # uniform: 1/area inside


def _zero_order_case(mask_value: float, scene):
    """The zero-order light of ``scene`` (3, H+2M, W+2M) behind a uniform mask, small discs."""
    near = torch.as_tensor(zero_order_psf(60e-6, 4e-3, 0.045, 1.85e-6)).unsqueeze(0)
    far = torch.as_tensor(zero_order_psf(60e-6, 4e-3, math.inf, 1.85e-6)).unsqueeze(0)
    margin = near.shape[-1] // 2 + 2
    shape = (3, 8 + 2 * margin, 8 + 2 * margin)
    clean = scene(shape, margin)
    obstruction = torch.full(shape, 0.0, dtype=torch.float64)
    mask = torch.full((1, *shape[1:]), mask_value, dtype=torch.float64)
    psf_near = torch.zeros(3, 5, 5, dtype=torch.float64)
    psf_near[:, 2, 2] = 1
    return zero_order_light(clean, obstruction, mask, psf_near, near, far, margin), far, margin


def test_zero_order_light_of_a_grey_wall_a_point_and_an_opaque_cover():
    """Closed forms: a grey wall gives the same grey (unit-sum disc); a point gives the disc
    itself, centred on it; an opaque dark cover hides the scene's zero-order light too."""

    def grey(shape, margin):
        return torch.full(shape, 0.25, dtype=torch.float64)

    (obstructed, unobstructed), far, margin = _zero_order_case(0.0, grey)
    torch.testing.assert_close(unobstructed, torch.full_like(unobstructed, 0.25))
    torch.testing.assert_close(obstructed, unobstructed)

    def point(shape, margin):
        x = torch.zeros(shape, dtype=torch.float64)
        x[:, margin + 4, margin + 4] = 1.0
        return x

    (_, unobstructed), far, margin = _zero_order_case(0.0, point)
    n = far.shape[-1] // 2
    expected = far[0, n - 4 : n + 4, n - 4 : n + 4]  # the disc around the point, seen on the 8 × 8 sensor
    torch.testing.assert_close(unobstructed[0], expected)
    (obstructed, _), _, _ = _zero_order_case(1.0, grey)
    assert obstructed.abs().max() < 1e-12


def test_mixed_efficiency_sources_warn_and_a_bare_design_takes_the_tables_fin():
    preset = load_preset("presets/hyperbolic-532.toml")
    other = dataclasses.replace(
        preset, nanofin=dataclasses.replace(preset.nanofin, efficiency=[0.5, 0.5, 0.5]), name="half"
    )
    a = resolve_design("hyperbolic:532nm", preset)
    b = resolve_design("hyperbolic:532nm", other)
    shared, warnings, notes = efficiency_sources([a, dataclasses.replace(b, spec="half")])
    assert len(warnings) == 1 and "half" in warnings[0] and "0.284" in warnings[0], warnings
    bare = _design(None)
    shared, warnings, notes = efficiency_sources([bare, a])
    assert warnings == [] and "hyperbolic:532nm" in notes[0]
    np.testing.assert_allclose(
        channel_budget(dataclasses.replace(bare, efficiency=shared)).throughput, channel_budget(a).throughput
    )


def test_through_the_whole_camera_a_grey_wall_stays_grey_and_an_opaque_cover_hides_the_scene():
    """simulate_captures with the zero-order light attached (leak 1: no analyzer, ζ_c ≈ 0.3-0.45):
    a grey wall g images as the uniform g·(1 + ζ_c) (focused and unconverted light both sum to
    one), and a fully opaque dark cover leaves nothing of the scene, focused or unconverted."""
    from metalens_cli.imaging.images import CleanImage
    from metalens_cli.imaging.obstructions import Obstruction
    from metalens_cli.imaging.pipeline import attach_zero_order, capture_psfs, simulate_captures

    design = resolve_design(
        "hyperbolic:532nm", load_preset("presets/hyperbolic-532.toml"), f_m=None, aperture_m=0.3e-3, pitch_m=None
    )
    psfs = capture_psfs(design, 0.045, 1.0, [450e-9, 530e-9, 610e-9, 690e-9], 1.85e-6, 16)
    attach_zero_order(psfs, design, 1.85e-6, 1.0)
    zeta = psfs.zero_order.scale.flatten().numpy()
    assert np.all((zeta > 0.2) & (zeta < 0.6)), zeta
    margin = psfs.margin
    side = 16 + 2 * margin
    wall = CleanImage("wall", np.full((3, side, side), 0.3, dtype=np.float32), margin)
    opaque = Obstruction(
        "cover", np.zeros((3, side, side), np.float32), np.ones((1, side, side), np.float32), 0.045, {}
    )
    key = ("cover", 0, 0, psfs.z_near_m, design.focal_length_m)
    (capture,) = simulate_captures([wall], "cover", psfs, design.focal_length_m, 1.85e-6, 0, obstructions={key: opaque})
    expected = 0.3 * (1 + zeta)[:, None, None] * np.ones((3, 16, 16))
    np.testing.assert_allclose(capture.unobstructed, expected, rtol=1e-4)
    np.testing.assert_allclose(capture.obstructed, 0.0, atol=1e-6)
