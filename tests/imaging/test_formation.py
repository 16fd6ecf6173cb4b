"""Image formation: the α = 0 limit, delta PSFs, energy, linear vs circular boundaries, gradients."""

import numpy as np
import pytest
import scipy.signal
import torch

from metalens_cli.imaging.formation import add_noise, circular_convolve, convolve, form_image, psf_spectrum
from metalens_cli.optics.propagate import fft_size

rng = np.random.default_rng(0)


def t(a):
    return torch.as_tensor(a, dtype=torch.float64)


def test_fft_size_is_smooth_and_minimal():
    for n in (1, 7, 97, 768, 769, 1023):
        m = fft_size(n)
        assert m >= n
        k = m
        for p in (2, 3, 5, 7):
            while k % p == 0:
                k //= p
        assert k == 1
    assert fft_size(769) == 784 and fft_size(1023) == 1024


@pytest.mark.parametrize("n", [9, 8, 31])
def test_linear_convolution_matches_direct(n):
    image, psf = rng.random((3, 20, 23)), rng.random((3, n, n))
    ours = convolve(t(image), t(psf)).numpy()
    c = n // 2  # axis pixel of the PSF: 'same' output = full[c : c + H]
    direct = np.stack([scipy.signal.convolve2d(image[k], psf[k], mode="full")[c : c + 20, c : c + 23] for k in range(3)])
    np.testing.assert_allclose(ours, direct, atol=1e-12)  # float64 FFT round-off only


def test_alpha_zero_reproduces_far_convolution_exactly():
    clean, obs, psf_near, psf_far = rng.random((2, 3, 24, 24)), rng.random((2, 3, 24, 24)), rng.random((3, 11, 11)), rng.random((3, 11, 11))
    capture = form_image(t(clean), t(obs), torch.zeros(2, 1, 24, 24, dtype=torch.float64), t(psf_near), t(psf_far))
    assert torch.equal(capture.alpha, torch.zeros_like(capture.alpha))
    # α = 0 exactly (zero mask): I = 1·(P_far ∗ I_clean) + 0, identical to the far convolution in the same batch.
    assert torch.equal(capture.image, capture.unobstructed)
    np.testing.assert_allclose(capture.image.numpy(), convolve(t(clean), t(psf_far)).numpy(), atol=1e-13)


def test_delta_psf_reproduces_scene_and_composites():
    clean, obs = rng.random((3, 16, 16)), rng.random((3, 16, 16))
    mask = (rng.random((1, 16, 16)) > 0.5).astype(float)
    delta = np.zeros((3, 7, 7))
    delta[:, 3, 3] = 1
    capture = form_image(t(clean), t(obs * mask), t(mask), t(delta), t(delta))
    np.testing.assert_allclose(capture.unobstructed.numpy(), clean, atol=1e-12)
    np.testing.assert_allclose(capture.image.numpy(), mask * obs + (1 - mask) * clean, atol=1e-12)


def test_energy_kept_and_uniform_scene_brightness():
    psf = rng.random((3, 9, 9))
    psf /= psf.sum(axis=(-2, -1), keepdims=True) / np.array([1.0, 0.9, 0.5])[:, None, None]
    image = rng.random((3, 40, 40))
    image[:, :6], image[:, -6:], image[:, :, :6], image[:, :, -6:] = 0, 0, 0, 0  # content away from the borders
    out = convolve(t(image), t(psf)).numpy()
    np.testing.assert_allclose(out.sum(axis=(-2, -1)), image.sum(axis=(-2, -1)) * [1.0, 0.9, 0.5], rtol=1e-12)
    uniform = convolve(torch.ones(3, 30, 30, dtype=torch.float64), t(psf)).numpy()
    np.testing.assert_allclose(uniform[:, 10:20, 10:20], np.broadcast_to([[[1.0]], [[0.9]], [[0.5]]], (3, 10, 10)), rtol=1e-12)


def test_linear_differs_from_circular_only_near_the_borders():
    image = np.zeros((1, 32, 32))
    image[0, 0, 0] = 1.0  # a point in the corner
    psf = np.ones((1, 5, 5)) / 25
    linear = convolve(t(image), t(psf)).numpy()[0]
    circular = circular_convolve(t(image), t(psf)).numpy()[0]
    assert linear[-1, -1] == pytest.approx(0, abs=1e-15)  # no wrap-around
    assert circular[-1, -1] == pytest.approx(1 / 25)  # wrapped to the opposite corner
    np.testing.assert_allclose(linear[:3, :3], circular[:3, :3], atol=1e-15)
    assert linear.sum() == pytest.approx(9 / 25) and circular.sum() == pytest.approx(1.0)


def test_spectrum_reuse_gradients_and_gain_clamp():
    clean, obs = torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 16)
    mask = (torch.rand(1, 1, 16, 16) > 0.5).float()
    psf = torch.rand(3, 9, 9, requires_grad=True)
    far = torch.rand(3, 9, 9) / 81
    direct = form_image(clean, obs, mask, psf / 81, far)
    cached = form_image(clean, obs, mask, psf_spectrum(psf / 81, (16, 16)), psf_spectrum(far, (16, 16)))
    torch.testing.assert_close(direct.image, cached.image)
    cached.image.mean().backward()
    assert psf.grad is not None and torch.isfinite(psf.grad).all() and psf.grad.abs().sum() > 0
    clamped = form_image(clean, obs, mask, psf.detach() / 81, far, alpha_gain=10.0)
    assert clamped.alpha.max() <= 1.0 and clamped.alpha.mean() > direct.alpha.mean()


def test_noise_seeded_and_scaled():
    image = torch.full((3, 64, 64), 0.25, dtype=torch.float64)
    a, b = add_noise(image, photons=1000, read_noise=0.01, generator=3), add_noise(image, photons=1000, read_noise=0.01, generator=3)
    assert torch.equal(a, b)
    # variance 0.25/1000 + 1e-4 = 3.5e-4; 12288 samples → relative standard error of the variance ≈ 1.3 %
    assert float((a - image).var()) == pytest.approx(3.5e-4, rel=0.06)
