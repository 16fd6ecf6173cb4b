"""Parameterisations of θ and the training losses, against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose

from metalens_cli.design.losses import bright_loss, l1_loss, sharp_loss, ssim_loss, training_loss
from metalens_cli.design.parameterization import initial_parameterization, random_radial_theta
from metalens_cli.errors import InputError
from metalens_cli.io.presets import LossConfig
from metalens_cli.optics.lens import hyperbolic

F, D, P, LAM = 1e-3, 0.2e-3, 395e-9, 532e-9


def test_radial_hyperbolic_init_is_the_hyperbolic_lens():
    model = initial_parameterization("radial", "hyperbolic", LAM, F, D, P)
    np.testing.assert_array_equal(model.lens().theta.detach().numpy(), hyperbolic(LAM, F, D, P).theta.numpy())


def test_2d_full_grid_init_is_the_hyperbolic_map():
    model = initial_parameterization("2d", "hyperbolic", LAM, F, D, P)
    np.testing.assert_allclose(
        model.lens().theta.detach().numpy(), hyperbolic(LAM, F, D, P, radial=False).theta.numpy(), rtol=0, atol=1e-12
    )


def test_coarse_design_grid_upsamples_with_aligned_centre_and_corners():
    model = initial_parameterization("2d", "hyperbolic", LAM, F, D, P, design_grid=51)
    full = model.full_theta().detach().numpy()
    coarse = model.theta.detach().numpy()
    m = full.shape[0]
    assert m == hyperbolic(LAM, F, D, P, radial=False).grid_size
    for (i, j), (a, b) in [((m // 2, m // 2), (25, 25)), ((0, 0), (0, 0)), ((m - 1, 0), (50, 0))]:
        assert full[i, j] == pytest.approx(coarse[a, b], abs=1e-12)
    # bilinear interpolation of a smooth map: close to the exact hyperbolic map (coarse cell ≈ 10 sites)
    exact = hyperbolic(LAM, F, D, P, radial=False).theta.numpy()
    assert np.max(np.abs(full - exact)) < 0.2
    full.sum()  # gradient path
    model.full_theta().sum().backward()
    assert model.theta.grad.shape == (51, 51) and torch.all(model.theta.grad > 0)


def test_design_grid_must_be_odd_and_not_finer_than_the_sites():
    with pytest.raises(InputError, match="optimize.design_grid"):
        initial_parameterization("2d", "hyperbolic", LAM, F, D, P, design_grid=50)


def test_random_init_is_seeded_and_as_steep_as_asked():
    r = np.arange(400) * P
    a, b = random_radial_theta(r, D, 3e5, 1), random_radial_theta(r, D, 3e5, 1)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, random_radial_theta(r, D, 3e5, 2))
    inside = r <= D / 2
    slope = np.abs(np.diff(2 * a[inside])) / P / (2 * math.pi)  # local frequency, cycles/m
    # finite differences on the sampled rings: the steepest point can fall beyond the last ring inside the pupil
    assert slope.max() == pytest.approx(3e5, rel=0.03)


def _delta_psf(n=15, channels=3, fraction=1.0):
    psf = torch.zeros(channels, n, n, dtype=torch.float64)
    psf[:, n // 2, n // 2] = fraction
    return psf


def test_bright_and_sharp_losses_closed_forms():
    # every channel keeps all its light in the centre pixel: L_bright = 3/3 − 1 = 0, L_sharp = 1/3 − 1
    assert float(bright_loss(_delta_psf())) == pytest.approx(0.0, abs=1e-15)
    assert float(sharp_loss(_delta_psf())) == pytest.approx(1 / 3 - 1)
    # half the light lost: L_bright = 3/1.5 − 1 = 1
    assert float(bright_loss(_delta_psf(fraction=0.5))) == pytest.approx(1.0)
    # light just outside the 5 × 5 window counts for bright, not for sharp
    psf = torch.zeros(3, 15, 15, dtype=torch.float64)
    psf[:, 7, 10] = 1.0
    psf[:, 7, 9] = 0.5
    assert float(sharp_loss(psf, 5)) == pytest.approx(1 / 1.5 - 1)
    assert float(sharp_loss(psf, 7)) == pytest.approx(1 / 4.5 - 1)


def test_per_channel_sharp_loss_weighs_the_weakest_channel():
    # E = (1, 0.5, 0.25): total 1/1.75 − 1; per channel mean(1, 2, 4) − 1 = 4/3
    psf = _delta_psf() * torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)[:, None, None]
    assert float(sharp_loss(psf)) == pytest.approx(1 / 1.75 - 1)
    assert float(sharp_loss(psf, mode="per_channel")) == pytest.approx(4 / 3)
    assert float(sharp_loss(_delta_psf(), mode="per_channel")) == pytest.approx(0.0, abs=1e-15)
    energy = torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64, requires_grad=True)
    sharp_loss(_delta_psf() * energy[:, None, None], mode="per_channel").backward()
    assert_allclose(energy.grad.numpy(), -1 / (3 * np.array([1.0, 0.5, 0.25]) ** 2))  # d(1/E)/dE = −1/E², /3 channels
    with pytest.raises(InputError, match="loss.sharp_mode"):
        sharp_loss(psf, mode="max")


def test_per_wavelength_sharp_loss_prefers_a_flat_spectrum():
    """−mean log E_λ: for one mean core energy a flat spectrum scores lower than a peaked one
    (Jensen), its gradient is −1/(W·E_λ); without cores it refuses with the preset key."""
    flat, peaked = (
        torch.full((4,), 0.04, dtype=torch.float64),
        torch.tensor([0.13, 0.01, 0.01, 0.01], dtype=torch.float64),
    )
    assert float(sharp_loss(_delta_psf(), mode="log_wavelength", cores=flat)) == pytest.approx(-math.log(0.04))
    assert float(sharp_loss(_delta_psf(), mode="log_wavelength", cores=flat)) < float(
        sharp_loss(_delta_psf(), mode="log_wavelength", cores=peaked)
    )
    energy = peaked.clone().requires_grad_(True)
    sharp_loss(_delta_psf(), mode="log_wavelength", cores=energy).backward()
    assert_allclose(energy.grad.numpy(), -1 / (4 * peaked.numpy()))
    with pytest.raises(InputError, match="loss.sharp_mode"):
        sharp_loss(_delta_psf(), mode="log_wavelength")


def test_harmonic_sharp_loss_weighs_the_weakest_wavelength_most():
    """log mean 1/E_λ: −log E on a flat spectrum (as −mean log E_λ), above the geometric form on
    a peaked one (harmonic ≤ geometric mean), and its gradient (1/E_λ²)/Σ(1/E_μ) by hand."""
    flat, uneven = (
        torch.full((4,), 0.04, dtype=torch.float64),
        torch.tensor([0.1, 0.05, 0.02, 0.01], dtype=torch.float64),
    )
    assert float(sharp_loss(_delta_psf(), mode="harmonic_wavelength", cores=flat)) == pytest.approx(-math.log(0.04))
    assert float(sharp_loss(_delta_psf(), mode="harmonic_wavelength", cores=uneven)) == pytest.approx(
        math.log(np.mean(1 / uneven.numpy()))
    )
    assert float(sharp_loss(_delta_psf(), mode="harmonic_wavelength", cores=uneven)) > float(
        sharp_loss(_delta_psf(), mode="log_wavelength", cores=uneven)
    )
    energy = uneven.clone().requires_grad_(True)
    sharp_loss(_delta_psf(), mode="harmonic_wavelength", cores=energy).backward()
    inverse = 1 / uneven.numpy()
    assert_allclose(energy.grad.numpy(), -(inverse**2) / inverse.sum())
    assert np.argmax(np.abs(energy.grad.numpy())) == 3  # the weakest wavelength is pushed hardest
    with pytest.raises(InputError, match="loss.sharp_mode"):
        sharp_loss(_delta_psf(), mode="harmonic_wavelength")


def test_image_losses_vanish_for_identical_images_and_grow_with_noise():
    gen = torch.Generator().manual_seed(0)
    clean = torch.rand(2, 3, 32, 32, generator=gen, dtype=torch.float64)
    noisy = clean + 0.1 * torch.randn(clean.shape, generator=gen, dtype=torch.float64)
    assert torch.all(l1_loss(clean, clean) == 0) and torch.allclose(
        ssim_loss(clean, clean), torch.zeros(2, dtype=torch.float64), atol=1e-12
    )
    assert torch.all(l1_loss(noisy, clean) > 0.07) and torch.all(ssim_loss(noisy, clean) > 0.05)
    # E|N(0, σ)| = σ·√(2/π): L1 of Gaussian noise, 3 % tolerance for 6144 samples
    assert float(l1_loss(noisy, clean).mean()) == pytest.approx(0.1 * math.sqrt(2 / math.pi), rel=0.03)


def test_training_loss_weights_and_shares():
    gen = torch.Generator().manual_seed(1)
    clean = torch.rand(1, 3, 24, 24, generator=gen, dtype=torch.float64)
    capture = 0.9 * clean
    psf = _delta_psf(fraction=0.8)
    weights = LossConfig(l1=2.0, ssim=0.5, bright=3.0, sharp=0.0)
    total, parts = training_loss(capture, clean, psf, weights)
    expected = 2.0 * parts["l1"] + 0.5 * parts["ssim"] + 3.0 * parts["bright"]
    assert float(total) == pytest.approx(float(expected)) and float(parts["total"]) == pytest.approx(float(expected))
    half, _ = training_loss(capture, clean, psf, weights, image_share=0.5, psf_share=0.25)
    assert float(half) == pytest.approx(
        float(0.5 * (2.0 * parts["l1"] + 0.5 * parts["ssim"]) + 0.25 * 3.0 * parts["bright"])
    )


def test_spline_basis_starts_at_the_hyperbolic_lens_and_moves_smoothly():
    """The spline deviation starts at 0 (θ is the hyperbolic profile, exactly) and one
    coefficient's step changes θ smoothly: its second difference over the rings is O(h²) of the
    step, not a kink like a linear sample's (which puts the whole step into one ring's slope)."""
    from metalens_cli.design.parameterization import spline_basis

    model = initial_parameterization("radial", "hyperbolic", LAM, F, D, P, design_grid=16, basis="spline")
    np.testing.assert_array_equal(model.lens().theta.detach().numpy(), hyperbolic(LAM, F, D, P).theta.numpy())
    basis = spline_basis(model.base.numel(), 16)
    assert_allclose(basis.sum(axis=1), 1.0, atol=1e-12)  # partition of unity: a uniform shift of θ is exact
    with torch.no_grad():
        model.theta[8] += 0.1
    step = (model.full_theta() - model.base).detach().numpy()
    assert step.max() == pytest.approx(0.1 * basis[:, 8].max())
    kink = np.abs(np.diff(step, 2)).max()
    samples = initial_parameterization("radial", "hyperbolic", LAM, F, D, P, design_grid=16)
    with torch.no_grad():
        samples.theta[8] += 0.1
    linear_kink = np.abs(
        np.diff((samples.full_theta() - torch.from_numpy(hyperbolic(LAM, F, D, P).theta.numpy())).detach().numpy(), 2)
    ).max()
    assert kink < linear_kink / 10


def test_spline_basis_is_refused_where_it_does_not_apply():
    with pytest.raises(InputError, match="optimize.theta_basis"):
        initial_parameterization("2d", "hyperbolic", LAM, F, D, P, design_grid=51, basis="spline")
    with pytest.raises(InputError, match="optimize.design_grid"):
        initial_parameterization("radial", "hyperbolic", LAM, F, D, P, design_grid=3, basis="spline")


def test_log_sharp_loss_is_the_mean_log_and_zero_when_all_light_is_in_the_core():
    psf = torch.zeros(3, 9, 9, dtype=torch.float64)
    psf[:, 4, 4] = torch.tensor([0.5, 0.25, 0.125])
    assert float(sharp_loss(psf, 5, "log")) == pytest.approx(-(math.log(0.5) + math.log(0.25) + math.log(0.125)) / 3)
    psf[:, 4, 4] = 1.0
    assert float(sharp_loss(psf, 5, "log")) == pytest.approx(0.0, abs=1e-15)
