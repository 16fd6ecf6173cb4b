"""Channel PSFs in windows from their light (optics.channel_psf), against compute_psf."""

import math

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.optics.channel_psf import ENCIRCLED_ENERGY, channel_psf_stack
from metalens_cli.optics.lens import hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid
from metalens_cli.optics.sensor import build_radial_sensor
from metalens_cli.optics.spectra import mix_channels
from metalens_cli.optics.window import crop_window

# A small lens (D = 0.3 mm, f = 1 mm, NA ≈ 0.15) keeps the radial plan small; its near depth
# (20 mm) defocuses every wavelength, its far depth is sharp near the design wavelength.
LENS = dict(lambda_d_m=532e-9, focal_length_m=1e-3, aperture_m=0.3e-3, pitch_m=395e-9)
WAVES = [450e-9, 460e-9, 470e-9, 520e-9, 532e-9, 545e-9, 610e-9, 625e-9, 640e-9]
WEIGHTS = np.kron(np.eye(3), np.full((1, 3), 1 / 3))[::-1].copy()  # R from the longest three
DEPTHS = [0.02, math.inf]
PITCH = 4e-6  # coarse pixels: the 99.9 % discs of an NA 0.15 lens span ~100 of them


@pytest.fixture(scope="module")
def lens():
    return hyperbolic(LENS["lambda_d_m"], LENS["focal_length_m"], LENS["aperture_m"], LENS["pitch_m"])


@pytest.fixture(scope="module")
def stack(lens):
    return channel_psf_stack(lens, WAVES, DEPTHS, WEIGHTS, 301, PITCH, dtype=torch.float64)


def test_mixing_before_the_pixel_operator_equals_mixing_after(lens, stack):
    """Both are linear: the channel PSF of the mixed intensity equals the mix of the pixel PSFs
    of the same plan (float64: agreement to round-off, 1e-6 asked)."""
    reference = compute_psf(lens, PsfGrid(WAVES, DEPTHS, 301, PITCH), dtype=torch.float64)  # the same plan (capacity)
    for i in range(len(DEPTHS)):
        mixed_after = crop_window(mix_channels(reference.psf[i], WEIGHTS), stack.psfs[i].shape[-1])
        error = float((stack.psfs[i] - mixed_after).norm() / mixed_after.norm())
        assert error < 1e-6


def test_each_wavelengths_core_is_the_centre_of_its_own_pixel_psf(lens):
    """``core_window`` k: each wavelength's energy in its central k × k pixels equals the sum over
    those pixels of its monochromatic PSF from compute_psf (the same plan; float64, 1e-9), and
    asking for it changes nothing else."""
    cored = channel_psf_stack(lens, WAVES, DEPTHS, WEIGHTS, 301, PITCH, dtype=torch.float64, core_window=5)
    reference = compute_psf(lens, PsfGrid(WAVES, DEPTHS, 301, PITCH), dtype=torch.float64)
    plain = channel_psf_stack(lens, WAVES, DEPTHS, WEIGHTS, 301, PITCH, dtype=torch.float64)
    assert plain.cores is None
    for i in range(len(DEPTHS)):
        expected = crop_window(reference.psf[i], 5).sum(dim=(-2, -1))
        torch.testing.assert_close(cored.cores[i], expected, rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(cored.psfs[i], plain.psfs[i], rtol=0, atol=0)
    assert int(cored.cores[1][:6].argmax()) == 4  # at ∞ the design wavelength (532 nm) beats its neighbours
    with pytest.raises(InputError, match="core_window"):
        channel_psf_stack(lens, WAVES, DEPTHS, WEIGHTS, 301, PITCH, core_window=4)


def test_window_holds_the_light_of_a_psf_twice_as_large(lens, stack):
    """The rule's window holds ≥ 99.9 % of what a direct sum over a window of twice the side
    (and over the whole sensor plane, Parseval) finds; and no more than it needs: the next
    smaller disc holds less than 99.9 % of the sensor plane's light for some channel."""
    for i in range(len(DEPTHS)):
        n = stack.psfs[i].shape[-1]
        large = mix_channels(
            compute_psf(lens, PsfGrid(WAVES, [DEPTHS[i]], 2 * n + 1, PITCH), dtype=torch.float64).psf[0], WEIGHTS
        )
        total = large.sum(dim=(-2, -1)).numpy()
        assert np.all(stack.kept[i] >= ENCIRCLED_ENERGY * total)
        assert np.all(stack.held[i] >= ENCIRCLED_ENERGY - 2e-4)  # pixel integral vs disc: interpolation error
        assert np.all(total <= stack.on_sensor[i] * (1 + 1e-4))  # Parseval bounds every window's sum
        # the rule is the disc inscribed in the window: a square inside the next smaller disc falls short
        inner = crop_window(large, 2 * math.floor((n // 2 - 0.5) / math.sqrt(2)) + 1).sum(dim=(-2, -1)).numpy()
        assert np.any(inner < ENCIRCLED_ENERGY * stack.on_sensor[i])
    assert not stack.outgrown.any()


def test_windows_follow_the_light(lens, stack):
    """A defocused depth needs a larger window than the sharp one; each channel's own window is
    reported and the depth's window is their largest."""
    near, far = stack.windows
    assert stack.psfs[0].shape[-1] == max(near) and stack.psfs[1].shape[-1] == max(far)
    assert max(near) > min(far)
    assert all(n % 2 == 1 for w in stack.windows for n in w)


def test_light_past_the_capacity_is_reported(lens):
    """A capacity smaller than the light: the window is the capacity and the channel is outgrown."""
    small = channel_psf_stack(lens, WAVES, DEPTHS, WEIGHTS, 21, PITCH, plan_pixels=201, dtype=torch.float64)
    assert small.outgrown[0].all() and small.psfs[0].shape[-1] == 21
    assert np.all(small.held[0] < ENCIRCLED_ENERGY)


def test_radial_sensor_window_is_the_smaller_operator():
    """A window cut from a larger pixel operator equals the operator built for that window."""
    big = build_radial_sensor(0.1e-6, 61, PITCH)
    samples = torch.rand(big.n_radii, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    for n in (1, 2, 17, 30, 61):
        own, cut = build_radial_sensor(0.1e-6, n, PITCH), big.window(n)
        assert cut.n_radii == own.n_radii
        torch.testing.assert_close(cut.apply(samples[: cut.n_radii]), own.apply(samples[: own.n_radii]), rtol=0, atol=0)


def test_two_d_lens_uses_square_energy(lens):
    """A 2-D lens (the ASM path): the window holds ≥ 99.9 % of the capacity's light."""
    grid_lens = hyperbolic(
        LENS["lambda_d_m"], LENS["focal_length_m"], LENS["aperture_m"], LENS["pitch_m"], radial=False
    )
    stack = channel_psf_stack(grid_lens, WAVES[3:6], [math.inf], WEIGHTS[:, 3:6] * 0 + np.eye(3), 61, PITCH)
    full = mix_channels(compute_psf(grid_lens, PsfGrid(WAVES[3:6], [math.inf], 61, PITCH)).psf[0], np.eye(3)).sum(
        dim=(-2, -1)
    )
    assert np.all(stack.kept[0] >= ENCIRCLED_ENERGY * full.numpy() * (1 - 1e-6))


def test_a_narrower_radial_margin_stays_within_its_error_budget(lens, stack):
    """``radial_margin`` 0.1 (``[optimize] radial_margin``: half the default's sin-angle kept past
    the steepest ray) shrinks the Hankel plan; each channel PSF stays within 5e-4 (relative L2,
    over its window) of the mix of compute_psf's at doubled sampling (margins and densities × 2),
    as the default's does within 2e-4. The light it drops is edge diffraction at wide angles, which
    the window rule no longer counts: on this NA 0.15 lens with 4-µm pixels the windows shrink by a
    quarter and keep about 1e-3 of the aperture's power less (asked: < 1.5e-3); on the paper's lens
    in training, 2-12 px of 600-900 and 3e-5 (docs/benchmarks.md)."""
    narrow = channel_psf_stack(lens, WAVES, DEPTHS, WEIGHTS, 301, PITCH, dtype=torch.float64, radial_margin=0.1)
    assert narrow.grid["hankel_samples"] < 0.85 * stack.grid["hankel_samples"]
    fine = compute_psf(lens, PsfGrid(WAVES, DEPTHS, 301, PITCH), dtype=torch.float64, oversample=2.0)
    for i in range(len(DEPTHS)):
        for psfs, budget in ((narrow.psfs, 5e-4), (stack.psfs, 2e-4)):
            reference = crop_window(mix_channels(fine.psf[i], WEIGHTS), psfs[i].shape[-1])
            error = (psfs[i] - reference).flatten(1).norm(dim=1) / reference.flatten(1).norm(dim=1)
            assert float(error.max()) < budget, (i, error)
    dropped = stack.kept - narrow.kept
    assert np.all(dropped >= 0) and np.all(dropped < 1.5e-3)
