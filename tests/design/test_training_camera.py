"""Training under the verdict's camera (design.training_camera), the loss on the metric's images
(loss.space = "metric"), L_bright over the whole sensor, and what steers θ (design.validation)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from metalens_cli.design.losses import training_loss
from metalens_cli.design.training_camera import expose, training_camera, zero_order_veil
from metalens_cli.design.validation import snr_summary
from metalens_cli.errors import InputError
from metalens_cli.io.presets import load_preset, preset_from_dict, sensor_field_angles, to_toml

TINY = Path(__file__).with_name("tiny.toml")
QUICK = Path(__file__).parents[2] / "presets" / "quick-split-spectrum.toml"


@pytest.fixture(scope="module")
def tiny():
    return load_preset(TINY)


def _with(preset, section: str, **changes):
    return dataclasses.replace(preset, **{section: dataclasses.replace(getattr(preset, section), **changes)})


# ----------------------------------------------------------------------------------------- the gradient's SNR


def test_gradient_snr_is_unbiased_on_gaussian_draws():
    """D = 8 draws of P gradients g = μ + σ·ε with known μ/σ: the mean over repetitions of the
    estimated mean SNR² is the true one (within 3 %, about 6 standard errors), where the plug-in
    m²/s² overstates it by (μ²/σ² + 1/D)·(D − 1)/(D − 3) (here 1.6-1.9 ×); and pure noise gives 0."""
    gen = torch.Generator().manual_seed(1)
    p, d, repeats = 2000, 8, 300
    mu = torch.linspace(-1.5, 1.5, p, dtype=torch.float64)
    sigma = torch.linspace(0.5, 2.0, p, dtype=torch.float64)
    truth = float((mu**2 / sigma**2).mean())
    estimates, plug_in, noise = [], [], []
    for _ in range(repeats):
        draws = mu + sigma * torch.randn(d, p, generator=gen, dtype=torch.float64)
        estimates.append(snr_summary(draws)["mean_snr2"])
        plug_in.append(float((draws.mean(0) ** 2 / draws.var(0)).mean()))
        noise.append(snr_summary(sigma * torch.randn(d, p, generator=gen, dtype=torch.float64))["mean_snr2"])
    assert np.mean(estimates) == pytest.approx(truth, rel=0.03)
    assert np.mean(plug_in) > 1.5 * truth
    assert abs(np.mean(noise)) < 0.01
    with pytest.raises(ValueError, match="more than 3 draws"):
        snr_summary(torch.zeros(3, 5))


# --------------------------------------------------------------------------------------- the metric as the loss


def test_the_metric_loss_of_a_capture_is_what_evaluate_scores():
    """loss.space = "metric": 1 − SSIM is 1 − evaluate's SSIM of the capture (imaging.pipeline.
    score: float64 match, colour-science sRGB in float32), and L1 is the mean absolute difference
    of the same images computed here with numpy (least-squares gain and bias, IEC sRGB formula)."""
    from metalens_cli.imaging.pipeline import score

    gen = torch.Generator().manual_seed(3)
    clean = torch.rand(1, 3, 48, 48, generator=gen, dtype=torch.float64)
    capture = 0.7 * torch.nn.functional.avg_pool2d(clean, 5, stride=1, padding=2) + 0.05
    capture = capture + 0.02 * torch.randn(capture.shape, generator=gen, dtype=torch.float64)
    psf = torch.full((3, 5, 5), 1 / 25, dtype=torch.float64)
    weights = dataclasses.replace(load_preset(TINY).loss, space="metric")
    _, parts = training_loss(capture, clean, psf, weights)
    scored = score(capture[0].numpy(), clean[0].numpy())
    assert float(parts["ssim"]) == pytest.approx(1 - scored["ssim"], abs=2e-6)

    x, y = capture[0].numpy().ravel(), clean[0].numpy().ravel()
    gain, bias = np.polyfit(x, y, 1)

    def srgb(v):
        v = np.clip(v, 0, 1)
        return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)

    assert float(parts["l1"]) == pytest.approx(np.abs(srgb(gain * x + bias) - srgb(y)).mean(), rel=1e-9)
    linear = dataclasses.replace(weights, space="linear")
    assert float(training_loss(capture, clean, psf, linear)[1]["l1"]) == pytest.approx(np.abs(x - y).mean())


def test_bright_counts_the_light_on_the_whole_sensor(tiny):
    """sensor.full_pixels: L_bright sees the far PSF on the whole sensor, not the step's crop; a
    PSF whose light lies outside the crop and inside the sensor then costs nothing."""
    from metalens_cli.design.step import sensor_psf

    psf = torch.zeros(3, 101, 101)
    psf[:, 50, 50], psf[:, 50, 90] = 0.5, 0.5  # half the light 40 px off axis: outside a 32-px crop
    whole = _with(tiny, "sensor", full_pixels=96)
    assert sensor_psf(psf, tiny).sum() == pytest.approx(1.5)
    assert sensor_psf(psf, whole).sum() == pytest.approx(3.0)
    with pytest.raises(InputError, match="sensor.full_pixels"):
        preset_from_dict({**_toml(tiny), "sensor": {**_toml(tiny)["sensor"], "full_pixels": 16}})


def _toml(preset) -> dict:
    import tomllib

    return tomllib.loads(to_toml(preset))


# --------------------------------------------------------------------------------------------- the camera


def test_a_filter_of_throughput_t_sees_t_times_the_light(tiny):
    """[optimize] light: each channel collects light × t_c, t_c = ∫CRF·T·η/∫CRF, as evaluate's
    camera counts it (imaging.camera.channel_budget of the same design); without the filter it
    collects light × s_c (η alone), so the filtered run sees t_c/s_c of the unfiltered one's
    photons; a learned filter's share g_c gives light·s_c·g_c; and the noise has that variance."""
    from metalens_cli.imaging.camera import channel_budget
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.preset_spectra import channel_throughput

    lit = _with(tiny, "optimize", light=2000.0)
    bare = dataclasses.replace(lit, filter=None)
    camera, open_camera = training_camera(lit), training_camera(bare)
    design = dataclasses.replace(resolve_design("hyperbolic:532nm", f_m=1e-3, aperture_m=0.2e-3), preset=lit)
    t = channel_budget(design).throughput
    assert np.allclose(camera.electrons, 2000 * t, rtol=1e-12)
    assert np.allclose(open_camera.electrons, camera.per_share, rtol=1e-12)
    assert np.all(camera.electrons < 0.5 * open_camera.electrons)  # a tri-band filter passes well under half
    g = torch.as_tensor(channel_throughput(lit))  # the preset filter's share, as a band draw reports it
    assert np.allclose(camera.full_scale(g).numpy(), camera.electrons, rtol=2e-3)  # 0.5-nm against 1-nm grids
    grey = torch.full((4, 3, 64, 64), 0.4, dtype=torch.float64)
    noisy = expose(grey, dataclasses.replace(camera, read_electrons=0.0), None, seed=5)
    variance = (noisy - grey).var(dim=(0, 2, 3)).numpy()
    assert np.allclose(variance, 0.4 / camera.electrons, rtol=0.06)


def test_light_and_photons_are_one_camera_or_the_other(tiny):
    """light (the verdict's camera) and photons/read_noise (the older count) together are refused,
    naming the key; light takes names; "sensor:K" field angles sample the whole sensor by area."""
    table = _toml(tiny)
    both = {**table, "optimize": {**table["optimize"], "light": "indoor", "photons": 100.0}}
    with pytest.raises(InputError, match="optimize.light"):
        preset_from_dict(both)
    named = preset_from_dict({**table, "optimize": {**table["optimize"], "light": "daylight"}})
    assert named.optimize.light == 20000.0 and training_camera(named).read_electrons == 2.5
    with pytest.raises(InputError, match="optimize.light"):
        preset_from_dict({**table, "optimize": {**table["optimize"], "light": "bright"}})
    over = {**table, "sensor": {**table["sensor"], "full_pixels": 512}, "optimize": {**table["optimize"]}}
    over["optimize"]["field_angles"] = "sensor:4"
    angles = preset_from_dict(over).optimize.field_angles_rad
    assert angles == pytest.approx(sensor_field_angles(512, 1.85e-6, 1e-3, 4))
    # a uniform point on the square: its height's quartiles, by Monte Carlo
    rng = np.random.default_rng(0)
    heights = np.hypot(*rng.uniform(-1, 1, (2, 400_000))) * 256 * 1.85e-6
    expected = np.arctan(np.quantile(heights, [0.125, 0.375, 0.625, 0.875]) / 1e-3)
    assert np.allclose(angles, expected, rtol=2e-3)
    with pytest.raises(InputError, match="optimize.field_angles"):
        preset_from_dict({**over, "optimize": {**over["optimize"], "field_angles": "sensor:0"}})


def test_the_zero_order_veil_of_a_grey_wall_is_its_share_of_the_wall():
    """A grey wall with no obstruction gains ζ_c of itself; an opaque cover in front of it gains
    ζ_c of the cover's own light instead (the wall hidden)."""
    grey = torch.full((1, 3, 40, 40), 0.3, dtype=torch.float64)
    zeta = np.array([0.01, 0.02, 0.03])
    none = torch.zeros_like(grey)
    veil = zero_order_veil(grey, none, none, zeta)
    assert torch.allclose(veil.reshape(3), torch.as_tensor(0.3 * zeta))
    cover = zero_order_veil(grey, torch.full_like(grey, 0.1), torch.ones_like(grey), zeta)
    assert torch.allclose(cover.reshape(3), torch.as_tensor(0.1 * zeta))


# --------------------------------------------------------------------------------------- learning from images


def test_an_image_only_fine_tune_removes_a_defocus(tiny):
    """A toy problem whose optimum is known: the tiny lens defocused (θ_hyperbolic + c·r², the
    focus moved by ~15 µm at f = 1 mm) and trained on the image terms alone (w_sharp = w_bright
    = 0, the metric's images) for 12 steps: the quadratic part of θ − θ_hyperbolic shrinks. (At a
    learning rate of 0.5 rad the per-ring Adam steps roughen θ past the pitch's sampling limit by
    step 11 on some scene draws; 0.3 rad keeps it smooth.)"""
    from metalens_cli.design import distributed
    from metalens_cli.design.model import build_model
    from metalens_cli.design.step import one_step
    from metalens_cli.design.training import _session
    from metalens_cli.runtime import Stopwatch

    preset = _with(_with(tiny, "loss", bright=0.0, sharp=0.0, space="metric"), "optimize", learning_rate=0.3)
    start = build_model(preset).full_theta().detach().numpy()
    r = np.arange(start.size) * preset.nanofin.pitch_m
    a = preset.lens.aperture_m / 2
    defocus = 6.0 * (r / a) ** 2  # rad of θ (12 rad of phase at the rim)

    def quadratic(theta):
        return float(np.polyfit((r / a) ** 2, theta - start, 1)[0])

    with distributed.session(torch.device("cpu")) as ctx:
        session = _session(preset, ctx)
        model = session.model
        with torch.no_grad():
            model.theta += torch.as_tensor(np.interp(np.linspace(0, r[-1], model.theta.numel()), r, defocus))
        before = quadratic(model.full_theta().detach().numpy())
        for step in range(12):
            one_step(session, preset, step, ctx, Stopwatch())
        after = quadratic(model.full_theta().detach().numpy())
    assert before == pytest.approx(6.0, rel=0.02)
    assert abs(after) < 0.8 * abs(before), (before, after)
    assert math.isfinite(after)


# ------------------------------------------------------------------------------ starting from a learned θ


def _hyperbolic_rings(preset) -> np.ndarray:
    from metalens_cli.design.parameterization import radial_radii
    from metalens_cli.optics.lens import hyperbolic_phase

    r = radial_radii(preset.nanofin.pitch_m, preset.lens.aperture_m)
    return hyperbolic_phase(r, preset.lens.design_wavelength_m, preset.lens.focal_length_m) / 2, r


def test_init_from_starts_the_run_at_that_theta_and_the_run_keeps_its_copy(tiny, tmp_path):
    """optimize.init_from = a θ .npy: the model starts at that θ exactly (per-ring samples and the
    spline's base alike); a 0-step run writes it back as its θ, keeps a copy beside its preset
    (named relative), and stays a design spec after the source is deleted."""
    from metalens_cli.design.model import build_model
    from metalens_cli.design.training import train
    from metalens_cli.io.designs import resolve_design

    hyperbolic, r = _hyperbolic_rings(tiny)
    source = hyperbolic + 3.0 * (r / r[-1]) ** 2  # a defocused lens, not what init = hyperbolic gives
    np.save(tmp_path / "source.npy", source)
    (tmp_path / "start.toml").write_text(to_toml(_with(tiny, "optimize", init_from="source.npy")))
    preset = load_preset(tmp_path / "start.toml")
    assert preset.optimize.init_from == str(tmp_path / "source.npy")
    np.testing.assert_array_equal(build_model(preset).full_theta().detach().numpy(), source)
    spline = build_model(_with(preset, "optimize", theta_basis="spline", design_grid=8))
    np.testing.assert_array_equal(spline.full_theta().detach().numpy(), source)

    train(preset, tmp_path / "run", steps=0)
    (tmp_path / "source.npy").unlink()
    assert 'init_from = "start_theta.npy"' in (tmp_path / "run" / "preset.toml").read_text()
    np.testing.assert_array_equal(np.load(tmp_path / "run" / "start_theta.npy"), source)
    np.testing.assert_allclose(np.load(tmp_path / "run" / "theta.npy"), source, rtol=0, atol=1e-12)
    design = resolve_design(str(tmp_path / "run"))
    assert design.preset.optimize.init_from == str(tmp_path / "run" / "start_theta.npy")


def test_init_from_refuses_what_is_not_this_lens_radial_theta(tiny, tmp_path):
    """A 2-D map, a folder without theta.npy, a θ of another ring count, init = random beside it:
    each an InputError naming optimize.init_from."""
    from metalens_cli.design.model import build_model

    hyperbolic, _ = _hyperbolic_rings(tiny)
    np.save(tmp_path / "map.npy", np.zeros((5, 5)))
    np.save(tmp_path / "short.npy", hyperbolic[:-3])
    np.save(tmp_path / "good.npy", hyperbolic)
    (tmp_path / "empty").mkdir()
    for value in ("map.npy", "empty", "missing.npy"):
        (tmp_path / "p.toml").write_text(to_toml(tiny).replace("[optimize]", f'[optimize]\ninit_from = "{value}"'))
        with pytest.raises(InputError) as caught:
            load_preset(tmp_path / "p.toml")
        assert "optimize.init_from" in caught.value.field
    with pytest.raises(InputError, match="rings") as caught:
        build_model(_with(tiny, "optimize", init_from=str(tmp_path / "short.npy")))
    assert caught.value.field == "optimize.init_from"
    with pytest.raises(InputError) as caught:
        build_model(_with(tiny, "optimize", init_from=str(tmp_path / "good.npy"), init="random"))
    assert caught.value.field == "optimize.init_from"
