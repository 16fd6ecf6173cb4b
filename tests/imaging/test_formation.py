"""Image formation on a canvas: convolution against scipy, the cases whose answer needs no code
(grey wall, opaque cover, translation, energy), the two forms, gradients and noise."""

import numpy as np
import pytest
import scipy.signal
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.formation import add_noise, canvas_margin, convolve, form_image, psf_transform
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


@pytest.mark.parametrize("n, extra", [(9, 0), (8, 0), (31, 0), (9, 5)])
def test_convolution_matches_direct_sum(n, extra):
    """The sensor crop equals scipy's full convolution at offset margin + N//2 (margin ≥ N//2;
    a larger margin is trimmed first)."""
    margin = n // 2 + extra
    canvas, psf = rng.random((3, 20 + 2 * margin, 23 + 2 * margin)), rng.random((3, n, n))
    psf /= psf.sum(axis=(-2, -1), keepdims=True)
    ours = convolve(t(canvas), t(psf), margin).numpy()
    k = margin + n // 2
    direct = np.stack(
        [scipy.signal.convolve2d(canvas[c], psf[c], mode="full")[k : k + 20, k : k + 23] for c in range(3)]
    )
    np.testing.assert_allclose(ours, direct, atol=1e-12)  # float64 FFT round-off only


def test_canvas_narrower_than_the_psf_is_refused():
    with pytest.raises(InputError, match="canvas margin"):
        convolve(torch.ones(1, 20, 20), torch.ones(1, 11, 11), 4)


def _random_psfs(n_near=21, n_far=9):
    near, far = rng.random((3, n_near, n_near)) ** 4, rng.random((3, n_far, n_far)) ** 4
    return t(near * [[[0.3]], [[0.7]], [[1.1]]]), t(far)  # any scale: form_image divides by the sum


@pytest.mark.parametrize("formation", ["physical", "paper"])
@pytest.mark.parametrize("coverage", [0.0, 0.3, 1.0])
def test_uniform_wall_behind_uniform_cover(formation, coverage):
    """Grey wall g behind a uniform cover of coverage m and colour c: α = m and I = m·c + (1 − m)·g
    at every pixel, whatever the PSFs' shapes or scales (both forms agree for uniform m)."""
    near, far = _random_psfs()
    margin = canvas_margin(21, 9)
    shape = (3, 16 + 2 * margin, 12 + 2 * margin)
    grey, colour = torch.full(shape, 0.25, dtype=torch.float64), torch.full(shape, 0.05, dtype=torch.float64)
    mask = torch.full((1, *shape[1:]), coverage, dtype=torch.float64)
    capture = form_image(grey, colour, mask, near, far, margin, formation=formation)
    np.testing.assert_allclose(capture.alpha.numpy(), coverage, atol=1e-12)
    np.testing.assert_allclose(capture.unobstructed.numpy(), 0.25, rtol=1e-12)
    np.testing.assert_allclose(capture.obstructed.numpy(), coverage * 0.05 + (1 - coverage) * 0.25, rtol=1e-12)


def test_opaque_cover_shows_only_the_blurred_obstruction():
    near, far = _random_psfs()
    margin = canvas_margin(21, 9)
    shape = (3, 16 + 2 * margin, 16 + 2 * margin)
    scene, colour = t(rng.random(shape)), t(rng.random(shape))
    capture = form_image(scene, colour, torch.ones(1, *shape[1:], dtype=torch.float64), near, far, margin)
    np.testing.assert_allclose(capture.alpha.numpy(), 1.0, atol=1e-12)
    np.testing.assert_allclose(
        capture.obstructed.numpy(),
        convolve(colour, near / near.sum((-2, -1), keepdim=True), margin).numpy(),
        atol=1e-12,
    )


def test_delta_psfs_composite_the_scene_and_obstruction():
    clean, obs = rng.random((3, 24, 24)), rng.random((3, 24, 24))
    mask = rng.random((1, 24, 24))
    delta = np.zeros((3, 7, 7))
    delta[:, 3, 3] = 2.0
    for formation in ("physical", "paper"):
        capture = form_image(t(clean), t(obs), t(mask), t(delta), t(delta), 4, formation=formation)
        crop = np.s_[..., 4:-4, 4:-4]
        np.testing.assert_allclose(capture.unobstructed.numpy(), clean[crop], atol=1e-12)
        np.testing.assert_allclose(capture.obstructed.numpy(), (mask * obs + (1 - mask) * clean)[crop], atol=1e-12)


def test_translation_of_scene_and_obstruction_translates_the_capture():
    near, far = _random_psfs()
    margin, k = canvas_margin(21, 9), 5
    shape = (3, 30 + 2 * margin, 30 + 2 * margin)
    scene, colour, mask = t(rng.random(shape)), t(rng.random(shape)), t(rng.random((1, *shape[1:])))
    shifted = [torch.roll(x, shifts=(k, k), dims=(-2, -1)) for x in (scene, colour, mask)]
    a = form_image(scene, colour, mask, near, far, margin).obstructed
    b = form_image(*shifted, near, far, margin).obstructed
    np.testing.assert_allclose(b[..., k:, k:].numpy(), a[..., :-k, :-k].numpy(), atol=1e-12)


def test_energy_of_a_small_obstruction_is_conserved():
    """An emitting patch on a black scene: the capture carries exactly the patch's light when its
    blur stays on the sensor (unit-sum PSF)."""
    near, far = _random_psfs()
    margin = canvas_margin(21, 9)
    shape = (3, 60 + 2 * margin, 60 + 2 * margin)
    mask = torch.zeros(1, *shape[1:], dtype=torch.float64)
    mask[..., margin + 25 : margin + 35, margin + 25 : margin + 35] = 0.6
    colour = torch.full(shape, 0.8, dtype=torch.float64)
    capture = form_image(torch.zeros(shape, dtype=torch.float64), colour, mask, near, far, margin)
    np.testing.assert_allclose(capture.obstructed.sum((-2, -1)).numpy(), 0.6 * 0.8 * 100, rtol=1e-12)


def test_paper_form_dims_partial_coverage():
    """Wires covering a fraction φ of the glass under a blur much wider than their period: the
    physical obstruction light is φ·c, the paper's literal α ⊙ (P ∗ I_obs) is φ²·c."""
    n = 40  # a whole number of wire periods: every window covers exactly φ = 1/4
    near = torch.ones(3, n, n, dtype=torch.float64)
    margin = n // 2
    size = 40 + 2 * margin
    wires = torch.zeros(1, size, size, dtype=torch.float64)
    wires[..., ::4, :] = 1.0  # φ = 1/4, period 4 ≪ 40
    colour = 0.5 * wires.expand(3, -1, -1)
    for formation, expected in (("physical", 0.25 * 0.5), ("paper", 0.25**2 * 0.5)):
        light = form_image(
            torch.zeros(3, size, size, dtype=torch.float64), colour, wires, near, near, margin, formation=formation
        ).obstruction_light
        np.testing.assert_allclose(light.numpy(), expected, rtol=1e-12)


def test_transforms_reuse_gradients_and_gain_clamp():
    margin = 4
    clean, obs = torch.rand(1, 3, 24, 24), torch.rand(1, 3, 24, 24)
    mask = (torch.rand(1, 1, 24, 24) > 0.5).float()
    psf = torch.rand(3, 9, 9, requires_grad=True)
    far = torch.rand(3, 9, 9)
    direct = form_image(clean, obs, mask, psf, far, margin)
    cached = form_image(clean, obs, mask, psf_transform(psf, (16, 16)), psf_transform(far, (16, 16)), margin)
    torch.testing.assert_close(direct.obstructed, cached.obstructed)
    cached.obstructed.mean().backward()
    assert psf.grad is not None and torch.isfinite(psf.grad).all() and psf.grad.abs().sum() > 0
    clamped = form_image(clean, obs, mask, psf.detach(), far, margin, alpha_gain=10.0)
    assert clamped.alpha.max() <= 1.0 and clamped.alpha.mean() > direct.alpha.mean()
    with pytest.raises(InputError, match="alpha_gain"):
        form_image(clean, obs, mask, psf.detach(), far, margin, alpha_gain=0.0)
    with pytest.raises(InputError, match="formation"):
        form_image(clean, obs, mask, psf.detach(), far, margin, formation="literal")


def test_noise_seeded_and_scaled():
    image = torch.full((3, 64, 64), 0.25, dtype=torch.float64)
    a, b = (
        add_noise(image, photons=1000, read_noise=0.01, generator=3),
        add_noise(image, photons=1000, read_noise=0.01, generator=3),
    )
    assert torch.equal(a, b)
    # variance 0.25/1000 + 1e-4 = 3.5e-4; 12288 samples → relative standard error of the variance ≈ 1.3 %
    assert float((a - image).var()) == pytest.approx(3.5e-4, rel=0.06)
