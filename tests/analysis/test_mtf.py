"""PSF-based MTF against closed forms: sampled Gaussians, the simulator's Airy PSF, the pixel aperture."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from metalens_cli.analysis.mtf import (
    cube_mtf,
    diffraction_limited_mtf,
    diffraction_mtf,
    mtf50,
    mtf_at,
    pixel_aperture_mtf,
    psf_mtf,
    radial_grid,
)
from metalens_cli.errors import InputError
from metalens_cli.io.exr import PsfCube

PITCH = 1.85e-6


def gaussian(n: int, sigma_px: float, scale: float = 1.0) -> np.ndarray:
    """A Gaussian sampled at pixel centres, axis at (n//2, n//2), float32 like a cube."""
    y, x = np.mgrid[:n, :n] - n // 2
    return (scale * np.exp(-(x**2 + y**2) / (2 * sigma_px**2))).astype(np.float32)


@pytest.mark.parametrize("n", [256, 255])
def test_sampled_gaussian_matches_closed_form(n):
    # The DFT of a sampled Gaussian is exp(−2π²σ²ν²) (ν in cycles/pixel) plus aliases folded at
    # 1 cycle/pixel: ≤ 2·exp(−2π²σ²/4) = 3e-5 for σ = 1.5 px. The ring average then differs
    # from the curve at k·Δν by half its curvature times the ring's radial variance, largest at
    # ring 1 (8 lattice points): measured 1.6e-4. Hence atol 3e-4.
    sigma = 1.5
    grid = radial_grid(n, PITCH)
    nu = np.arange(n // 2 + 1) / n
    assert_allclose(psf_mtf(gaussian(n, sigma, 1e3), grid), np.exp(-2 * np.pi**2 * sigma**2 * nu**2), atol=3e-4)


def test_mtf_ignores_position_and_scale():
    # A circular shift changes only the OTF's phase; the scale cancels in the DC normalisation
    # (float32 rounding of the values: 1e-6).
    grid = radial_grid(64, PITCH)
    psf = gaussian(64, 2.0)
    moved = np.roll(psf, (5, -3), axis=(0, 1)) * 7
    assert_allclose(psf_mtf(moved, grid), psf_mtf(psf, grid), atol=1e-6)


def test_frequency_axis_in_lpmm():
    # Rings at k/(N·p): 0 … Nyquist 1/(2p) = 270.27 lp/mm for even N, Δν/2 short of it for odd N.
    even, odd = radial_grid(256, PITCH), radial_grid(255, PITCH)
    assert_allclose(even.frequencies_lpmm, np.arange(129) / (256 * 1.85e-3), rtol=1e-12)
    assert_allclose([even.frequencies_lpmm[-1], even.nyquist_lpmm], [1e3 / 3.7, 1e3 / 3.7], rtol=1e-12)
    assert_allclose(odd.frequencies_lpmm[-1], 127 / (255 * 1.85e-3), rtol=1e-12)


def test_mtf50_of_a_gaussian():
    # exp(−2π²σ²ν²) = 1/2 at ν = √(ln 2 / (2π²σ²)) cycles/px; linear interpolation between rings
    # 1.06 lp/mm apart on a curve of curvature ~1e-4 per (lp/mm)² errs < 1e-4 relative, the
    # binning 3e-4 in MTF (slope 0.013 per lp/mm): rtol 2e-3.
    sigma = 2.0
    grid = radial_grid(512, PITCH)
    expected = math.sqrt(math.log(2) / (2 * math.pi**2 * sigma**2)) / PITCH * 1e-3
    assert_allclose(mtf50(grid.frequencies_lpmm, psf_mtf(gaussian(512, sigma), grid)), expected, rtol=2e-3)


def test_mtf50_and_interpolation_edge_cases():
    freqs = np.array([0.0, 10.0, 20.0, 30.0])
    curves = np.array([[1.0, 0.8, 0.4, 0.1], [1.0, 0.9, 0.8, 0.7]])
    assert_allclose(mtf50(freqs, curves), [17.5, np.nan])  # 0.8 → 0.4 crosses 0.5 at 3/4 of the step
    assert_allclose(mtf_at(freqs, curves, [5.0, 30.0]), [[0.9, 0.1], [0.95, 0.7]])
    with pytest.raises(InputError, match="outside the frequency axis"):
        mtf_at(freqs, curves, [31.0])


def test_pixel_mtf_is_the_ring_average_of_the_square_pixel():
    # Independent angular average of |sinc(ν p cos φ)·sinc(ν p sin φ)| on the circle |ν| = k·Δν
    # (2000 angles). The rings average lattice points instead, whose angles are uneven; the
    # pixel MTF varies with angle (0.64 on the axes, 0.66 on the diagonal at Nyquist), so they
    # differ most near Nyquist, and at the last ring, which holds only its inner half:
    # measured 2e-5 up to ring 30, 8e-4 at ring 64. Hence atol 1e-3.
    grid = radial_grid(128, PITCH)
    nu = np.arange(65) / 128
    phi = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    circle = np.abs(np.sinc(nu[:, None] * np.cos(phi)) * np.sinc(nu[:, None] * np.sin(phi))).mean(axis=1)
    assert_allclose(pixel_aperture_mtf(grid), circle, atol=1e-3)
    assert pixel_aperture_mtf(grid)[-1] > 2 / np.pi  # ≥ sinc(1/2) inside Nyquist: safe to divide


def test_diffraction_mtf_closed_form():
    # Values of (2/π)(arccos s − s√(1 − s²)) at s = 0, 1/2, 1 and beyond the cutoff.
    na, lam = 0.3, 500e-9
    cutoff = 2 * na / lam
    s = np.array([0.0, 0.5, 1.0, 1.5])
    expected = [1.0, 2 / np.pi * (np.pi / 3 - 0.5 * math.sqrt(0.75)), 0.0, 0.0]
    assert_allclose(diffraction_mtf(s * cutoff, na, lam), expected, atol=1e-12)


def test_simulated_airy_psf_against_diffraction_limit():
    # The hyperbolic lens at its design wavelength, source at infinity, is aberration-free: its
    # sensor PSF is the pixel-integrated Airy pattern of NA = a/√(a² + f²) = 0.07, cutoff
    # 263 lp/mm, below Nyquist 270 lp/mm and below 1/p − cutoff (no aliasing). The only
    # departure is the window: it holds a power fraction 1 − ε; writing the full OTF as
    # (windowed part + tail part) with |tail| ≤ ε bounds the change of the normalised OTF by
    # 2ε/(1 − ε) (0.012 for 129 px). Plus 1e-3 for the ring averaging and the simulator's own
    # accuracy (~1e-3). The pixel aperture changes the curve by 0.037, well beyond that.
    torch = pytest.importorskip("torch")
    from metalens_cli.imaging.psf_scan import run_scan
    from metalens_cli.io.designs import resolve_design

    n, lam, f, na = 129, 532e-9, 4e-3, 0.07
    aperture = 2 * f * na / math.sqrt(1 - na**2)
    design = resolve_design("hyperbolic:532nm", f_m=f, aperture_m=aperture)
    psf = np.asarray(run_scan(design, [lam], [math.inf], n, PITCH, dtype=torch.float32).psf)[0, 0]
    eps = 1 - float(psf.sum())
    atol = 2 * eps / (1 - eps) + 1e-3
    grid = radial_grid(n, PITCH)
    analytic = diffraction_mtf(grid.frequencies_lpmm * 1e3, na, lam)
    assert_allclose(psf_mtf(psf, grid, remove_pixel_mtf=True), analytic, atol=atol)
    with_pixel = diffraction_limited_mtf(grid, na, [lam], include_pixel=True)[0]
    assert_allclose(psf_mtf(psf, grid), with_pixel, atol=atol)
    assert np.abs(psf_mtf(psf, grid) - analytic).max() > 2 * atol  # the pixel aperture is really there


def test_cube_mtf_shapes_references_and_records():
    sigmas = np.array([[1.0, 1.5, 2.0], [2.5, 3.0, 3.5]])
    psf = np.stack([np.stack([gaussian(64, s) for s in row]) for row in sigmas])
    cube = PsfCube(
        psf,
        psf[:, :3],
        np.array([450e-9, 530e-9, 630e-9]),
        np.array([0.045, math.inf]),
        {"pixel_pitch_m": PITCH, "na": 0.3},
    )
    result = cube_mtf(cube, at_lpmm=[50.0, 100.0])
    assert result.mtf.shape == (2, 3, 33) and result.rgb_mtf.shape == (2, 3, 33)
    assert result.diffraction.shape == (3, 33) and result.na == 0.3
    expected = np.sqrt(np.log(2) / (2 * np.pi**2 * sigmas**2)) / PITCH * 1e-3
    assert_allclose(result.mtf50_lpmm, expected, rtol=2e-2)  # 64-px rings are 8.4 lp/mm apart
    records = result.curves()
    assert len(records) == 12 and set(records[0]) == {"depth_m", "wavelength_m", "mtf", "mtf50_lpmm", "mtf_at"}
    assert records[-1]["channel"] == "B" and math.isinf(records[-1]["depth_m"])
    assert cube_mtf(cube, na=0.1).na == 0.1 and "mtf_at" not in cube_mtf(cube).curves()[0]
    removed = cube_mtf(cube, remove_pixel_mtf=True)
    assert np.all(removed.mtf[..., 1:] > result.mtf[..., 1:])  # dividing by the pixel MTF (< 1) raises the curves


def test_cube_without_na_has_no_reference_and_empty_psf_is_refused():
    psf = np.stack([np.stack([gaussian(16, 1.0), np.zeros((16, 16), np.float32)])])
    cube = PsfCube(psf, None, np.array([500e-9, 600e-9]), np.array([1.0]), {"pixel_pitch_m": PITCH})
    with pytest.raises(InputError, match=r"index \(0, 1\) has no power"):
        cube_mtf(cube)
    assert (
        cube_mtf(PsfCube(psf[:, :1], None, np.array([500e-9]), np.array([1.0]), {"pixel_pitch_m": PITCH})).diffraction
        is None
    )
