"""PSF-based MTF against closed forms: sampled Gaussians, the simulator's Airy PSF, the pixel aperture."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from metalens_cli.analysis.mtf import (
    cube_mtf,
    diffraction_limited_mtf,
    diffraction_mtf,
    line_mtf,
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
    from metalens_cli.optics.sampling import PsfGrid

    n, lam, f, na = 129, 532e-9, 4e-3, 0.07
    aperture = 2 * f * na / math.sqrt(1 - na**2)
    design = resolve_design("hyperbolic:532nm", f_m=f, aperture_m=aperture)
    psf = np.asarray(run_scan(design, PsfGrid([lam], [math.inf], n, PITCH), dtype=torch.float32).psf)[0, 0]
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


# ---------------------------------------------------------------------------- over the field


def elliptic(n: int, sigma_x: float, sigma_y: float) -> np.ndarray:
    """exp(−x²/2σx² − y²/2σy²) at pixel centres (x = column, y = row, from pixel n//2), float32."""
    y, x = np.mgrid[:n, :n] - n // 2
    return np.exp(-(x**2) / (2 * sigma_x**2) - y**2 / (2 * sigma_y**2)).astype(np.float32)


def gaussian_mtf(n: int, sigma_px: float) -> np.ndarray:
    """exp(−2π²σ²ν²) at ν = k/n cycles/pixel, k = 0 … n//2."""
    return np.exp(-2 * np.pi**2 * sigma_px**2 * (np.arange(n // 2 + 1) / n) ** 2)


# The DFT of a sampled Gaussian is its continuous transform plus aliases from the lattice
# points 1 cycle/pixel away, at most exp(−π²σ²/2) = 1.5e-5 each for σ = 1.5 px within Nyquist
# (a few of them), and float32 rounding 1e-6; the 64-px window cuts nothing (σ ≤ 2.5 px).
# Hence atol 1e-4 against the closed forms.
CLOSED_FORM_ATOL = 1e-4


def test_tangential_and_sagittal_mtf_of_a_separable_gaussian():
    # exp(−x²/2σx² − y²/2σy²): the MTF along the unit vector u is exp(−2π²ν²(σx²ux² + σy²uy²)).
    # ψ = 0: tangential along x (σx), sagittal along y (σy); ψ = 90°: the other way round, and
    # the PSF turned by 90° (σx and σy swapped) gives back ψ = 0's curves.
    n, sx, sy = 64, 1.5, 2.5
    psf, grid = elliptic(n, sx, sy), radial_grid(n, PITCH)
    for psi, tangential, sagittal in ((0.0, sx, sy), (math.pi / 2, sy, sx)):
        assert_allclose(line_mtf(psf, grid, psi), gaussian_mtf(n, tangential), atol=CLOSED_FORM_ATOL)
        assert_allclose(line_mtf(psf, grid, psi + math.pi / 2), gaussian_mtf(n, sagittal), atol=CLOSED_FORM_ATOL)
    turned = elliptic(n, sy, sx)
    assert_allclose(line_mtf(turned, grid, math.pi / 2), gaussian_mtf(n, sx), atol=CLOSED_FORM_ATOL)
    assert_allclose(line_mtf(turned, grid, math.pi), gaussian_mtf(n, sy), atol=CLOSED_FORM_ATOL)


@pytest.mark.parametrize("psi_deg", [30.0, -70.0, 135.0])
def test_line_mtf_off_the_pixel_axes_is_the_exact_dft(psi_deg):
    # Off the axes no line spread function of rows or columns gives the curve: the direct DFT
    # along ν(cos ψ, sin ψ) does, σ² = σx²cos²ψ + σy²sin²ψ (same bounds as above).
    n, sx, sy, psi = 64, 1.5, 2.5, math.radians(psi_deg)
    grid = radial_grid(n, PITCH)
    expected = math.sqrt(sx**2 * math.cos(psi) ** 2 + sy**2 * math.sin(psi) ** 2)
    assert_allclose(line_mtf(elliptic(n, sx, sy), grid, psi), gaussian_mtf(n, expected), atol=CLOSED_FORM_ATOL)
    scaled = line_mtf(np.stack([elliptic(n, sx, sy), 9 * elliptic(n, sy, sx)]).astype(np.float64), grid, psi)
    swapped = math.sqrt(sy**2 * math.cos(psi) ** 2 + sx**2 * math.sin(psi) ** 2)
    assert scaled.dtype == np.float64 and scaled.shape == (2, 33)
    assert_allclose(scaled[1], gaussian_mtf(n, swapped), atol=CLOSED_FORM_ATOL)  # batch, scale, float64


def test_a_rotationally_symmetric_psf_has_equal_tangential_sagittal_and_radial_curves():
    # Two concentric Gaussians (σ 1.5 and 3 px, weights 1 and 0.5: not separable). Sampled
    # Gaussians sum to 2πσ² (aliases aside), so the MTF is (A1·e1 + A2·e2)/(A1 + A2),
    # Ak = wk·2πσk². Tangential and sagittal: the closed form within 1e-4 (as above), hence each
    # other within 2e-4, at any azimuth. The radial average differs from the closed form by its
    # ring binning (module docstring): measured 1.9e-3 at N = 128 for this steep curve: 2.5e-3.
    n = 128
    y, x = np.mgrid[:n, :n] - n // 2
    psf = (np.exp(-(x**2 + y**2) / (2 * 1.5**2)) + 0.5 * np.exp(-(x**2 + y**2) / (2 * 3.0**2))).astype(np.float32)
    a1, a2 = 2 * np.pi * 1.5**2, 0.5 * 2 * np.pi * 3.0**2
    closed = (a1 * gaussian_mtf(n, 1.5) + a2 * gaussian_mtf(n, 3.0)) / (a1 + a2)
    grid = radial_grid(n, PITCH)
    radial = psf_mtf(psf, grid)
    assert_allclose(radial, closed, atol=2.5e-3)
    for psi in (0.0, math.radians(35.0)):
        tangential, sagittal = line_mtf(psf, grid, psi), line_mtf(psf, grid, psi + math.pi / 2)
        assert_allclose(tangential, closed, atol=CLOSED_FORM_ATOL)
        assert_allclose(sagittal, closed, atol=CLOSED_FORM_ATOL)
        assert_allclose(tangential, sagittal, atol=2 * CLOSED_FORM_ATOL)
        assert_allclose(tangential, radial, atol=2.5e-3 + CLOSED_FORM_ATOL)


def test_line_mtf_pixel_aperture():
    # A Gaussian (σ = 1.5 px) integrated over square pixels (erf differences) has the OTF
    # exp(−2π²σ²ν²)·sinc(νx)·sinc(νy) (ν in cycles/pixel) plus aliases (bounded as above): with
    # remove_pixel_mtf the pixel factor is divided out, sample by sample.
    from scipy.special import erf

    n, sigma, psi = 64, 1.5, math.radians(30.0)
    c = np.arange(n) - n // 2
    side = 0.5 * (erf((c + 0.5) / (math.sqrt(2) * sigma)) - erf((c - 0.5) / (math.sqrt(2) * sigma)))
    psf = np.outer(side, side).astype(np.float32)
    nu = np.arange(n // 2 + 1) / n
    pixel = np.abs(np.sinc(nu * math.cos(psi)) * np.sinc(nu * math.sin(psi)))
    grid = radial_grid(n, PITCH)
    assert_allclose(line_mtf(psf, grid, psi), gaussian_mtf(n, sigma) * pixel, atol=CLOSED_FORM_ATOL)
    assert_allclose(line_mtf(psf, grid, psi, remove_pixel_mtf=True), gaussian_mtf(n, sigma), atol=CLOSED_FORM_ATOL)


def field_cube(sigmas_xy, rgb=True, azimuth=0.0):
    """A field cube of elliptic Gaussians: sigmas_xy (F, D, W, 2) in pixels; the rgb channels are
    the wavelengths reversed (W = 3)."""
    sigmas_xy = np.asarray(sigmas_xy, dtype=float)
    psf = np.array([[[elliptic(128, *s) for s in row] for row in field] for field in sigmas_xy])
    fields, depths = psf.shape[:2]
    angles = [0.1 * k for k in range(fields)]
    metadata = {
        "pixel_pitch_m": PITCH,
        "field_angles_rad": angles,
        "field_azimuth_rad": azimuth,
        "chief_ray_m": [[4e-3 * math.tan(a), 0.0] for a in angles],
        "window_centre_px": [[round(4e-3 * math.tan(a) / PITCH), 0] for a in angles],
    }
    rgb_psf = psf[:, :, ::-1].copy() if rgb else None
    return PsfCube(
        psf[0],
        None if rgb_psf is None else rgb_psf[0],
        np.array([450e-9, 530e-9, 630e-9][: psf.shape[2]]),
        np.array([0.045, math.inf][:depths]),
        metadata,
        psf,
        rgb_psf,
    )


def test_cube_mtf_over_the_field_and_mtf50_closed_form():
    # MTF50 of exp(−2π²σ²ν²): ν50 = √(ln 2/(2π²σ²)) cycles/pixel, over p for lp/m. Linear
    # interpolation between samples h = 1/128 cycle/px apart errs by h²/8·|MTF''|/|MTF'| at the
    # crossing: 1.9e-4 relative for σ = 1.5 px, 7.6e-4 for 3 px (measured: at most 4.8e-4), the
    # curves' own 1e-4 (above) over a slope ≥ 5.5 per cycle/px at most 3e-4 more: rtol 1.5e-3.
    sigmas = np.array([[[[1.5, 1.5], [1.5, 2.0], [2.0, 2.5]]], [[[1.6, 2.2], [1.8, 2.6], [2.0, 3.0]]]])
    cube = field_cube(sigmas)
    result = cube_mtf(cube)
    field = result.field
    assert field.tangential.shape == (2, 1, 3, 65) and field.rgb_sagittal.shape == (2, 1, 3, 65)
    expected = np.sqrt(np.log(2) / (2 * np.pi**2 * sigmas**2)) / PITCH * 1e-3  # (F, D, W, [x, y])
    assert_allclose(field.tangential_mtf50_lpmm, expected[..., 0], rtol=1.5e-3)
    assert_allclose(field.sagittal_mtf50_lpmm, expected[..., 1], rtol=1.5e-3)
    assert_allclose(field.rgb_tangential_mtf50_lpmm, expected[:, :, ::-1, 0], rtol=1.5e-3)
    assert_allclose(field.sagittal[1, 0, 2], gaussian_mtf(128, 3.0), atol=CLOSED_FORM_ATOL)
    assert_allclose(result.mtf, psf_mtf(cube.field_psf[0], radial_grid(128, PITCH)))  # radial curves: field 0
    records = result.field_records()
    assert [r["field"] for r in records] == [0, 1] and records[1]["angle_deg"] == pytest.approx(0.1 * 180 / math.pi)
    assert len(records[0]["mtf50_lpmm"]) == 3 + 3 and records[1]["window_centre_px"] == [217, 0]
    assert set(records[0]["mtf50_lpmm"][-1]) == {"depth_m", "channel", "tangential", "sagittal"}
    assert records[1]["mtf50_lpmm"][0]["sagittal"] == pytest.approx(expected[1, 0, 0, 1], rel=1.5e-3)
    curves = result.field_curves()
    assert len(curves) == 2 * 6 * 2 and [c["direction"] for c in curves[:2]] == ["tangential", "sagittal"]
    assert cube_mtf(field_cube(sigmas[:1], rgb=False)).field.rgb_tangential is None
    on_axis = PsfCube(cube.psf, cube.rgb, cube.wavelengths_m, cube.depths_m, {"pixel_pitch_m": PITCH})
    assert cube_mtf(on_axis).field is None and cube_mtf(on_axis).field_records() == []


def test_azimuth_turns_tangential_and_sagittal():
    # Fields along +y (ψ = 90°): tangential along y (σy), sagittal along x (σx).
    result = cube_mtf(field_cube([[[[1.5, 2.5]]]], rgb=False, azimuth=math.pi / 2)).field
    assert_allclose(result.tangential[0, 0, 0], gaussian_mtf(128, 2.5), atol=CLOSED_FORM_ATOL)
    assert_allclose(result.sagittal[0, 0, 0], gaussian_mtf(128, 1.5), atol=CLOSED_FORM_ATOL)


def test_line_mtf_refuses_an_empty_psf():
    psf = np.stack([gaussian(16, 1.0), np.zeros((16, 16), np.float32)])
    with pytest.raises(InputError, match=r"index \(1,\) has no power"):
        line_mtf(psf, radial_grid(16, PITCH), 0.3)
