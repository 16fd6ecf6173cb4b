"""Geometric blur and PSF windows against the thin-lens closed form and a direct PSF sum."""

import math

import numpy as np
import pytest

from metalens_cli.optics.blur import geometric_blur_radius, psf_window, window_pixels, window_radius_m
from metalens_cli.optics.lens import from_array, hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

PITCH = 395e-9


def _thin_lens_blur(lam, z, f=4e-3, aperture=0.2e-3, lambda_d=532e-9, d=4e-3):
    """Paraxial blur radius D·|v − d|/(2v) with v = 1/(1/f_λ − 1/z), f_λ = f·λd/λ."""
    f_lam = f * lambda_d / lam
    v = 1 / (1 / f_lam - (0 if math.isinf(z) else 1 / z))
    return aperture * abs(v - d) / (2 * v)


@pytest.mark.parametrize("lam, z", [(450e-9, 0.045), (630e-9, math.inf), (700e-9, 0.04), (420e-9, 1.0)])
def test_blur_radius_matches_thin_lens_at_low_na(lam, z):
    lens = hyperbolic(532e-9, 4e-3, 0.2e-3, PITCH)  # NA 0.025: paraxial optics holds to ~0.1 %
    ours = geometric_blur_radius(lens, lam, z, 4e-3)
    # the ray from the last interval midpoint, (K − ½)·p, stands for the rim at D/2: ≤ p/a ≈ 0.4 %
    assert ours == pytest.approx(_thin_lens_blur(lam, z), rel=5e-3)


def test_two_dimensional_map_traces_like_its_radial_profile():
    radial, grid = (hyperbolic(532e-9, 1e-3, 0.1e-3, PITCH, radial=r) for r in (True, False))
    for lam, z in ((457e-9, 0.012), (628e-9, math.inf)):
        # the 2-D map's central differences and its rim sites differ from the radial midpoints by ~p
        assert geometric_blur_radius(grid, lam, z, 1e-3) == pytest.approx(
            geometric_blur_radius(radial, lam, z, 1e-3), rel=0.02
        )


def test_window_pixels_inscribes_the_radius():
    assert window_pixels(0.5e-6, 1e-6) == 1 and window_pixels(0.51e-6, 1e-6) == 3 and window_pixels(10e-6, 1e-6) == 21


def test_windows_hold_99_percent_of_the_paper_lens_light():
    """The paper's lens (NA 0.3) at the extremes of the visible and both depths: a window sized by
    ``psf_window`` holds ≥ 99 % of the power through the aperture (the issue's target)."""
    lens = hyperbolic(532e-9, 4e-3, 2.516e-3, PITCH)
    for lam in (400e-9, 700e-9):
        for z in (0.04, math.inf):
            n = psf_window(lens, [lam], [z], 4e-3, 1.85e-6)
            kept = float(compute_psf(lens, PsfGrid([lam], [z], n, 1.85e-6)).psf.sum())
            assert 0.99 <= kept <= 1.0005, (lam, z, n, kept)
            assert n <= 2 * (window_radius_m(lens, [lam], [z], 4e-3) / 1.85e-6) + 3  # no larger than its light


def test_kept_fraction_matches_a_direct_sum_of_a_larger_window():
    """The pipeline's kept report equals the share of a 1.6× larger window's light inside the
    chosen window (the Hankel plans differ between window sizes: 1e-4)."""
    from metalens_cli.imaging.channel_psfs import channel_psfs
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.optics.window import crop_window

    design = resolve_design("hyperbolic:532nm", None, f_m=4e-3, aperture_m=2.516e-3, pitch_m=None)
    waves = list(np.arange(420e-9, 681e-9, 40e-9))
    psfs = channel_psfs(design, 0.045, 2.0, waves, 1.85e-6)
    big = channel_psfs(design, 0.045, 2.0, waves, 1.85e-6, window=int(1.6 * psfs.near.shape[-1]) | 1)
    direct = crop_window(big.near, psfs.near.shape[-1]).sum((-2, -1))
    np.testing.assert_allclose(psfs.kept_near, direct.numpy(), atol=1e-4)
    assert min(psfs.kept_near + psfs.kept_far) >= 0.99 and psfs.warnings() == []
    assert max(big.kept_near) <= 1.0005  # energy: no window gets more than went through the aperture


def test_a_learned_profile_is_traced_from_its_own_phase():
    """A profile steeper than the hyperbolic one sends rim rays further: the window grows with it."""
    base = hyperbolic(532e-9, 4e-3, 0.5e-3, PITCH)
    theta = base.theta.numpy()
    r = np.arange(theta.size) * PITCH
    steeper = from_array(theta * 1.2, PITCH, 0.5e-3, 4e-3)  # f/1.2: more converging
    # ray optics: extra slope 0.2·(r/f) at the rim → lands 0.2·a·(d/f) further across
    extra = geometric_blur_radius(steeper, 532e-9, math.inf, 4e-3) - geometric_blur_radius(base, 532e-9, math.inf, 4e-3)
    assert extra == pytest.approx(0.2 * r[r <= 0.25e-3][-1], rel=0.02)


def test_extreme_wavelengths_and_depths_bound_every_ray():
    """window_radius_m traces only the ends of each range; tracing every (λ, z) gives the same."""
    from metalens_cli.optics.blur import DIFFRACTION_MARGIN, numerical_aperture

    lens = hyperbolic(532e-9, 4e-3, 1e-3, PITCH)
    lams, zs = list(np.linspace(420e-9, 680e-9, 14)), [0.04, 0.043, 0.05, 1.0, math.inf]
    na = numerical_aperture(lens, 4e-3)
    brute = max(geometric_blur_radius(lens, lam, z, 4e-3) + DIFFRACTION_MARGIN * lam / na for lam in lams for z in zs)
    assert window_radius_m(lens, lams, zs, 4e-3) == pytest.approx(brute, rel=1e-12)
