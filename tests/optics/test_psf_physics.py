"""Physics of the PSF simulator: diffraction limit, energy, chromatic focal shift, agreement
between the three propagators, band limiting, the sampling guard and gradients."""

import math

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose
from scipy.special import j0, j1

from metalens_cli.errors import SamplingError
from metalens_cli.optics import lens as L
from metalens_cli.optics import propagate as prop
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

# Low-NA lens (NA 0.05, Fresnel number 25): paraxial diffraction theory holds to O(NA²) ≈ 3e-3.
LAM, F, D = 500e-9, 5e-3, 0.5e-3


def on_axis_field(lens, wavelength, distances, radii):
    """Field of a plane wave through ``lens`` at ``radii`` for several distances (radial path),
    normalised so that |E|² integrates to the power through the pupil = 1."""
    a = lens.radius_m
    kernel = prop.hankel_kernel(3000, 2.5 * a, a, 4096)
    field = torch.polar(torch.ones_like(kernel.r), lens.phase_at_radius(kernel.r))[:, None]
    power = (kernel.weight * field[:, 0].abs() ** 2).sum()
    out = prop.hankel_output_matrix(kernel, torch.as_tensor(radii, dtype=torch.float64))
    rows = [
        prop.radial_propagate(field, kernel, prop.radial_transfer(kernel, torch.tensor([wavelength]), d, 0.3), out)[
            :, 0
        ]
        for d in distances
    ]
    return torch.stack(rows) / power.sqrt()


def test_airy_pattern_at_low_na():
    lens = L.hyperbolic(LAM, F, D, 395e-9)
    rho = np.linspace(0, 20e-6, 2001)
    intensity = (on_axis_field(lens, LAM, [F], rho)[0].abs() ** 2).numpy()
    v = 2 * math.pi * (D / 2) * rho / (LAM * F)
    with np.errstate(invalid="ignore"):
        airy = np.where(v > 0, (2 * j1(v) / v) ** 2, 1.0) * math.pi * (D / 2) ** 2 / (LAM * F) ** 2
    # profile and peak within 1 % of the peak: O(NA²) = 2.5e-3 non-paraxial corrections
    assert_allclose(intensity, airy, rtol=0, atol=1e-2 * airy[0])
    # first zero at 1.22 λf/D·√(1 + (D/2f)²) (exact NA): 0.5 % allows the residual paraxiality
    near = (rho > 4e-6) & (rho < 8e-6)
    first_zero = rho[near][np.argmin(intensity[near])]
    assert_allclose(first_zero, 1.22 * LAM * F / D, rtol=5e-3)
    # encircled energy 1 − J0²(v) − J1²(v) at the first three rings (trapezoid on 10 nm steps)
    ee = np.concatenate(
        [
            [0],
            np.cumsum(
                np.diff(rho) * 0.5 * np.diff(2 * np.pi * rho * intensity)
                + np.diff(rho) * (2 * np.pi * rho * intensity)[:-1]
            ),
        ]
    )
    for zero in (3.8317, 7.0156, 10.1735):
        i = np.searchsorted(v, zero)
        assert_allclose(ee[i], 1 - j0(v[i]) ** 2 - j1(v[i]) ** 2, atol=5e-3)


def test_airy_peak_pixel():
    lens = L.hyperbolic(LAM, F, D, 395e-9)
    pitch = 2e-6
    psf = compute_psf(lens, PsfGrid([LAM], [math.inf], 9, pitch), dtype=torch.float64).psf[0, 0]
    # central pixel of the Airy pattern by a 400² midpoint rule (error < 1e-5)
    x = (np.arange(400) + 0.5) / 400 * pitch - pitch / 2
    v = 2 * math.pi * (D / 2) * np.hypot(x[:, None], x[None, :]) / (LAM * F)
    airy = (2 * j1(v) / v) ** 2 * math.pi * (D / 2) ** 2 / (LAM * F) ** 2
    assert_allclose(psf[4, 4].item(), airy.mean() * pitch**2, rtol=1e-2)  # O(NA²) as above


@pytest.mark.parametrize("propagator", ["radial", "asm"])
@pytest.mark.parametrize("wavelength", [532e-9, 450e-9])
def test_energy_conservation(propagator, wavelength):
    lens = L.hyperbolic(532e-9, 200e-6, 100e-6, 395e-9)  # NA 0.24
    psf = compute_psf(
        lens, PsfGrid([wavelength], [math.inf, 0.01], 101, 1e-6), propagator=propagator, dtype=torch.float64
    ).psf
    # the 101 µm window holds the focus or the geometric blur (≤ 16 µm); what misses is the
    # edge-diffracted light beyond ±50 µm, measured 0.9 % (bound 1.5 %), and nothing is created.
    total = psf.sum((-2, -1))
    assert torch.all(total <= 1 + 1e-9)
    assert_allclose(total.numpy(), 1.0, atol=1.5e-2)


def test_best_focus_moves_as_f_lambda_d_over_lambda():
    lens = L.hyperbolic(LAM, F, D, 395e-9)
    for wavelength in (450e-9, 560e-9, 620e-9):
        expected = F * LAM / wavelength
        d = expected * np.linspace(0.97, 1.03, 121)
        axial = (on_axis_field(lens, wavelength, d, [0.0])[:, 0].abs() ** 2).numpy()
        i = int(np.argmax(axial))
        c = np.polyfit(d[i - 3 : i + 4], axial[i - 3 : i + 4], 2)
        best = -c[1] / (2 * c[0])
        # the focal shift of Fresnel number 25 (≈ 12/(π²N²) = 0.2 %) plus residual aberration
        assert_allclose(best, expected, rtol=5e-3)


def test_radial_matches_2d_asm_on_small_lens():
    lens = L.hyperbolic(532e-9, 100e-6, 60e-6, 395e-9)  # NA 0.29, 153² sites
    px = dict(pixels=33, pixel_pitch_m=1e-6)
    kw = dict(dtype=torch.float64)
    for wavelength, depth in [(532e-9, math.inf), (480e-9, 0.002)]:
        radial = compute_psf(lens, PsfGrid([wavelength], [depth], **px), propagator="radial", **kw).psf
        asm = compute_psf(lens, PsfGrid([wavelength], [depth], **px), propagator="asm", **kw).psf
        # the 2-D grid models the pupil edge as a staircase of 395 nm sites; measured 1e-3 and
        # 3.5e-3 (halving with the pitch), so 6e-3 relative L2
        err = ((radial - asm).norm() / radial.norm()).item()
        assert err < 6e-3, err


def test_asm_pads_each_wavelength_for_its_own_rays():
    """An optimiser plans for 400-700 nm; each λ is padded only as far as its own steepest ray
    needs (blue on a smaller grid than red) and still matches the radial path."""
    lens = L.hyperbolic(532e-9, 100e-6, 60e-6, 395e-9)
    px = dict(pixels=33, pixel_pitch_m=1e-6)
    kw = dict(dtype=torch.float64, plan_wavelengths_m=[400e-9, 700e-9])
    lams = [450e-9, 650e-9]
    radial = compute_psf(lens, PsfGrid(lams, [0.002], **px), propagator="radial", **kw).psf
    asm = compute_psf(lens, PsfGrid(lams, [0.002], **px), propagator="asm", **kw).psf
    errors = ((radial - asm).flatten(2).norm(dim=-1) / radial.flatten(2).norm(dim=-1)).flatten()
    assert (errors < 6e-3).all(), errors  # the staircase pupil edge, as above
    sizes = [compute_psf(lens, PsfGrid([lam], [0.002], **px), propagator="asm", **kw).grid["fft_size"] for lam in lams]
    assert sizes[0] < sizes[1], sizes


@pytest.mark.parametrize("wavelength,depth", [(532e-9, math.inf), (580e-9, 0.045)])
def test_rs_matches_radial_on_paper_lens(wavelength, depth):
    lens = L.hyperbolic(532e-9, 4e-3, 2.516e-3, 395e-9)
    px = dict(pixels=5, pixel_pitch_m=1.85e-6)
    kw = dict(dtype=torch.float64)
    rs = compute_psf(lens, PsfGrid([wavelength], [depth], **px), propagator="rs", **kw).psf
    radial = compute_psf(lens, PsfGrid([wavelength], [depth], **px), propagator="radial", **kw).psf
    # the accuracy target (relative L2 ≤ 1e-3) on the central 5 × 5 pixels (sharp focus)
    err = ((radial - rs).norm() / rs.norm()).item()
    assert err < 1e-3, err


def test_band_limit_removes_aliasing_of_random_phase():
    n, pitch, lam, d = 128, 0.5e-6, 0.5e-6, 300e-6
    gen = torch.Generator().manual_seed(0)
    phase = 2 * math.pi * torch.rand(n, n, generator=gen, dtype=torch.float64)
    field = torch.polar(torch.ones_like(phase), phase)

    def padded(size):
        out = torch.zeros(size, size, dtype=torch.complex128)
        out[:n, :n] = field
        return out

    # reference: 16× padding, where the band limit (sin θ ≤ 0.8) keeps every ray that matters
    ref = prop.asm_propagate_plain(padded(16 * n), pitch, lam, d)[:n, :n]
    plain = prop.asm_propagate_plain(padded(2 * n), pitch, lam, d, band_limit=False)[:n, :n]
    limited = prop.asm_propagate_plain(padded(2 * n), pitch, lam, d)[:n, :n]

    def err(x):
        return ((x.abs() ** 2 - ref.abs() ** 2).norm() / (ref.abs() ** 2).norm()).item()

    # plain ASM wraps the steep rays of the random phase back in (measured ~1.5); the
    # band-limited one only loses them (measured ~0.7): require a factor 1.5 between them
    assert err(limited) * 1.5 < err(plain), (err(limited), err(plain))


def test_sampling_guard_refuses_undersampled_lens():
    lens = L.hyperbolic(532e-9, 100e-6, 200e-6, 395e-9)  # NA 0.71: 1.33 > 1.27 cycles/µm
    with pytest.raises(SamplingError, match="expected a pitch ≤"):
        compute_psf(lens, PsfGrid([532e-9], [math.inf], 5, 1e-6))
    with pytest.raises(SamplingError, match="expected a pitch ≤"):  # a source 50 µm away: chirp
        compute_psf(L.hyperbolic(532e-9, 1e-3, 200e-6, 395e-9), PsfGrid([450e-9], [50e-6], 5, 1e-6))
    psf = compute_psf(lens, PsfGrid([532e-9], [math.inf], 5, 1e-6), force=True).psf
    assert torch.isfinite(psf).all()


def test_gradients_reach_theta():
    base = L.hyperbolic(532e-9, 20e-6, 8e-6, 0.4e-6)

    def central_power(theta):
        lens = L.Metalens(theta, base.pitch_m, base.aperture_m, base.focal_length_m)
        psf = compute_psf(lens, PsfGrid([532e-9, 600e-9], [math.inf, 1e-3], 3, 0.5e-6), dtype=torch.float64).psf
        return psf[..., 1, :]

    theta = base.theta.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(central_power, (theta,), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_gradients_reach_theta_2d_asm():
    """Through the checkpointed path: 2 λ × 2 depths, so the backward pass rebuilds each PSF and
    its transfer function (cache of one) in reverse order."""
    base = L.hyperbolic(532e-9, 20e-6, 4e-6, 0.4e-6, radial=False)  # 11 × 11 sites

    def central_power(theta):
        lens = L.Metalens(theta, base.pitch_m, base.aperture_m, base.focal_length_m)
        return compute_psf(
            lens, PsfGrid([532e-9, 600e-9], [math.inf, 1e-3], 3, 0.5e-6), propagator="asm", dtype=torch.float64
        ).psf

    theta = base.theta.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(central_power, (theta,), eps=1e-6, atol=1e-7, rtol=1e-4, fast_mode=True)


def test_output_rows_grow_by_their_missing_rows_and_match_the_bessel_series():
    """Rows for more radii extend those for fewer (a view, then only the new rows are built),
    and every row is J0(2πν_m·kδ)·c_m with c_m = 1/(πR²·J1(j_m)²) (scipy's Bessel functions)."""
    prop.clear_caches()
    kernel = prop.hankel_kernel(200, 2e-4, 1e-4, 256)
    step = 3e-7
    few = prop.hankel_output_rows(kernel, step, 40)
    assert prop.hankel_output_rows(kernel, step, 25).data_ptr() == few.data_ptr()  # a prefix: no new matrix
    many = prop.hankel_output_rows(kernel, step, 90)
    assert many.shape == (90, 200) and torch.equal(many[:40], few)
    nu = kernel.nu.numpy()
    jm = 2 * math.pi * nu * 2e-4
    expect = j0(2 * math.pi * (np.arange(90) * step)[:, None] * nu) / (math.pi * 2e-4**2 * j1(jm) ** 2)
    # torch.special.bessel_j0 agrees with scipy's j0 to about 4e-7 (absolute) at these arguments
    assert_allclose(many.numpy(), expect, rtol=0, atol=1e-6 * np.abs(expect).max())
    prop.clear_caches()


def test_transfer_cache_keeps_only_the_most_recent():
    grid = prop.AsmGrid(size=64, pitch_m=0.4e-6, input_size=11, window_half=4, upsample=2)
    cache = prop.TransferCache(capacity=2)
    first = cache.get(grid, 500e-9, 20e-6, torch.complex64, "cpu")
    assert cache.get(grid, 500e-9, 20e-6, torch.complex64, "cpu")[0] is first[0]
    cache.get(grid, 600e-9, 20e-6, torch.complex64, "cpu")
    cache.get(grid, 700e-9, 20e-6, torch.complex64, "cpu")
    assert len(cache.store) == 2 and [k[0] for k in cache.store] == [600e-9, 700e-9]


@pytest.mark.parametrize("block_bytes", [None, 2048])  # 2 kB: a few rows per block
def test_asm_adjoint_identity(monkeypatch, block_bytes):
    """⟨A x, y⟩ = ⟨x, Aᴴ y⟩ to rounding (float64), whole arrays or row blocks; the gradient of
    a 2-D PSF is this adjoint."""
    if block_bytes:
        monkeypatch.setattr(prop, "BLOCK_BYTES", block_bytes)
    grid = prop.AsmGrid(size=96, pitch_m=0.4e-6, input_size=41, window_half=17, upsample=2)
    transfer = prop.asm_transfer(grid, 500e-9, 60e-6, torch.complex128)
    g = torch.Generator().manual_seed(0)
    x = torch.randn(41, 41, dtype=torch.complex128, generator=g)
    y = torch.randn(35, 35, dtype=torch.complex128, generator=g)
    ax = prop.asm_propagate(x, grid, lambda: transfer)
    lhs, rhs = (
        torch.vdot(ax.flatten(), y.flatten()),
        torch.vdot(x.flatten(), prop.asm_propagate_adjoint(y, grid, lambda: transfer).flatten()),
    )
    assert abs(lhs - rhs) < 1e-12 * abs(lhs), (lhs, rhs)
    # the forward pass against the plain band-limited ASM on the same padded grid, at the window's
    # points that fall on input samples (odd indices); at 60 µm the band limit is below Nyquist
    padded = torch.zeros(96, 96, dtype=torch.complex128)
    padded[:41, :41] = x
    plain = prop.asm_propagate_plain(padded, 0.4e-6, 500e-9, 60e-6)[12:29, 12:29]  # axis at 20, ±8 samples
    assert torch.allclose(ax[1::2, 1::2], plain, rtol=0, atol=1e-12)


@pytest.mark.parametrize("block_bytes", [None, 2048])
def test_even_field_propagation_is_the_whole_fields(monkeypatch, block_bytes):
    """``asm_propagate_even_y`` from the rows y ≥ 0 of a field even in y equals ``asm_propagate``
    of the whole field, through the shifted transfer function of a window off axis along x, to
    rounding (float64); and its adjoint identity holds."""
    if block_bytes:
        monkeypatch.setattr(prop, "BLOCK_BYTES", block_bytes)
    grid = prop.AsmGrid(size=96, pitch_m=0.4e-6, input_size=41, window_half=17, upsample=2)
    k = 30
    args = (grid, 500e-9, 60e-6, k, (3e5, 0.0), (5e-6, 0.0), torch.complex128)
    whole, _ = prop.asm_transfer_shifted(*args)
    half_h, _ = prop.asm_transfer_shifted(*args, nonnegative_v=True)
    assert torch.equal(half_h, whole[k:]) and torch.equal(half_h, whole[: k + 1].flip(0))
    g = torch.Generator().manual_seed(1)
    half = torch.randn(21, 41, dtype=torch.complex128, generator=g)
    full = torch.cat([half[1:].flip(0), half])
    ax = prop.asm_propagate_even_y(half, grid, lambda: (half_h, k))
    reference = prop.asm_propagate(full, grid, lambda: (whole, k))
    assert float((ax - reference).abs().max()) < 1e-12 * float(reference.abs().max())
    y = torch.randn(35, 35, dtype=torch.complex128, generator=g)
    lhs = torch.vdot(ax.flatten(), y.flatten())
    rhs = torch.vdot(half.flatten(), prop.asm_propagate_even_y_adjoint(y, grid, lambda: (half_h, k)).flatten())
    assert abs(lhs - rhs) < 1e-12 * abs(lhs), (lhs, rhs)
    with pytest.raises(ValueError, match="even in v"):
        prop.asm_transfer_shifted(grid, 500e-9, 60e-6, k, (3e5, 1e4), (5e-6, 0.0), nonnegative_v=True)
