"""Off-axis PSFs (``optics.field``): the on-axis limit, the direct Rayleigh-Sommerfeld reference,
energy, the chief ray, symmetry under mirror and rotation, and Seidel coma of a low-NA lens."""

import math

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose

from metalens_cli.errors import InputError
from metalens_cli.optics import lens as L
from metalens_cli.optics import propagate as prop
from metalens_cli.optics import sampling
from metalens_cli.optics.field import chief_ray, field_angle, field_psf
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid
from metalens_cli.optics.source import field_direction

# NA 0.29 on 153² sites (the small lens of tests/optics/test_psf_physics.py)
SMALL = dict(lambda_d_m=532e-9, focal_length_m=100e-6, aperture_m=60e-6, pitch_m=395e-9)
F64 = dict(dtype=torch.float64)


def small(radial=True):
    return L.hyperbolic(**SMALL, radial=radial)


def rel(a, b):
    return float((a - b).norm() / b.norm())


def centroid(psf: np.ndarray, pitch: float) -> tuple[float, float]:
    c = (np.arange(psf.shape[-1]) - psf.shape[-1] // 2) * pitch
    return float((psf.sum(0) * c).sum() / psf.sum()), float((psf.sum(1) * c).sum() / psf.sum())


@pytest.mark.parametrize("radial", [True, False])
def test_zero_angle_is_the_on_axis_psf_bit_for_bit(radial):
    lens = small(radial)
    px = dict(pixels=17, pixel_pitch_m=1e-6)
    kw = dict(**F64)
    axis = compute_psf(lens, PsfGrid([532e-9, 600e-9], [math.inf, 0.002], **px), **kw)
    field = field_psf(lens, PsfGrid([532e-9, 600e-9], [math.inf, 0.002], **px), angle_rad=0.0, azimuth_rad=1.0, **kw)
    assert torch.equal(field.psf, axis.psf)
    assert field.centre_px == (0, 0) and field.chief_ray_m == (0.0, 0.0)


def test_shifted_path_tends_to_the_on_axis_psf():
    """At a vanishing angle the shifted angular spectrum is the on-axis asm with a differently
    shaped band limit (a mask on the rays instead of a square) on a grid sized by the window's
    light instead of the band: measured 9e-5 and 4.6e-4."""
    lens = small()
    px = dict(pixels=33, pixel_pitch_m=1e-6)
    kw = dict(**F64)
    for depth in (math.inf, 0.002):
        axis = compute_psf(lens, PsfGrid([532e-9], [depth], **px), propagator="asm", **kw).psf
        tilted = field_psf(lens, PsfGrid([532e-9], [depth], **px), angle_rad=1e-9, **kw)
        assert tilted.propagator == "asm" and tilted.grid["kind"] == "asm-shifted"
        assert rel(tilted.psf, axis) < 2e-3


def test_tilted_plane_wave_matches_direct_rayleigh_sommerfeld():
    """The accuracy target, ≤ 1e-3 relative L2, against the direct sum over the sites of the full
    tilted field (carrier included; its output step 0.1 µm, converged to 7e-5): measured 5.3e-4."""
    lens = L.hyperbolic(532e-9, 70e-6, 40e-6, 395e-9)  # NA 0.27, 101² sites
    px = dict(pixels=11, pixel_pitch_m=1e-6)
    kw = dict(**F64)
    fast = field_psf(lens, PsfGrid([532e-9], [math.inf], **px), angle_rad=math.radians(10), **kw)
    exact = field_psf(lens, PsfGrid([532e-9], [math.inf], **px), angle_rad=math.radians(10), propagator="rs", **kw)
    assert fast.centre_px == exact.centre_px == (12, 0)
    assert rel(fast.psf, exact.psf) < 1e-3


@pytest.mark.slow
def test_tilted_point_source_matches_direct_rayleigh_sommerfeld():
    lens = small()
    px = dict(pixels=21, pixel_pitch_m=1e-6)
    kw = dict(**F64)
    for angle in (5, 15):
        fast = field_psf(lens, PsfGrid([480e-9], [0.002], **px), angle_rad=math.radians(angle), azimuth_rad=0.3, **kw)
        exact = field_psf(
            lens,
            PsfGrid([480e-9], [0.002], **px),
            angle_rad=math.radians(angle),
            azimuth_rad=0.3,
            propagator="rs",
            **kw,
        )
        assert rel(fast.psf, exact.psf) < 1e-3


def test_grid_sized_by_the_light_that_reaches_the_window(monkeypatch):
    """The side S = 2a + W + 2·3·√(λd) leaves out the band's waves that miss the window from every
    pupil point; a guard four times as wide (a grid twice the side) moves the PSF by 1.2e-4 (∞) and
    2.0e-4 (2 mm), converging (eight times: 1.1e-4, 1.9e-4), where no guard moves it by 2e-3."""
    px = dict(pixels=21, pixel_pitch_m=1e-6)
    kw = dict(angle_rad=math.radians(15), **F64)
    lens = small()
    lam, depths = 480e-9, [math.inf, 0.002]
    fitted = field_psf(lens, PsfGrid([lam], depths, **px), **kw)
    a, width = lens.radius_m, 21 * 1e-6
    assert fitted.grid["fft_size"] * lens.pitch_m >= 2 * a + width + 6 * math.sqrt(lam * lens.focal_length_m)
    monkeypatch.setattr(sampling, "REACH_FRESNEL", 12.0)
    wide = field_psf(lens, PsfGrid([lam], depths, **px), **kw)
    assert wide.grid["fft_size"] > 1.5 * fitted.grid["fft_size"]
    for k in range(2):
        assert rel(fitted.psf[k], wide.psf[k]) < 5e-4


@pytest.mark.parametrize("azimuth", [0.0, 0.7])
def test_band_stops_where_the_transfer_function_does(azimuth):
    """Beyond the planned half-width K the shifted transfer function keeps no wave (each would
    travel more than S/2 from the window's centre), so the narrower band is exact; here (NA 0.05)
    that travel, not the angle margin, sets K."""
    lens = L.hyperbolic(532e-9, 400e-6, 40e-6, 395e-9)
    lam, angle, pitch = 480e-9, math.radians(4), 1e-6
    carrier = tuple(c / lam for c in field_direction(angle, azimuth))
    x, y = chief_ray(lens, lam, angle, azimuth, lens.focal_length_m)
    centre_m = (round(x / pitch) * pitch, round(y / pitch) * pitch)
    f_max = sampling.lens_frequency(lens)[0]
    grid, k_max = sampling.plan_field_asm(
        lens, sampling.PsfGrid([lam], [math.inf], 21, pitch), lam, f_max, carrier, centre_m
    )
    assert k_max < math.floor(sampling.sin_limit(f_max, [lam], 2.0) / lam * grid.extent_m)
    whole = (grid.size - 1) // 2
    h, _ = prop.asm_transfer_shifted(grid, lam, lens.focal_length_m, whole, carrier, centre_m, torch.complex128)
    kept = h.abs() > 0
    outside = torch.ones_like(kept)
    outside[whole - k_max : whole + k_max + 1, whole - k_max : whole + k_max + 1] = False
    assert not kept[outside].any()
    rows, columns = torch.nonzero(kept, as_tuple=True)
    assert int(torch.maximum((rows - whole).abs(), (columns - whole).abs()).max()) >= k_max - 2  # and no wider


@pytest.mark.parametrize("depth", [math.inf, 0.01])
def test_energy_is_conserved_off_axis(depth):
    lens = small()
    psf = field_psf(lens, PsfGrid([532e-9], [depth], 101, 1e-6), math.radians(12), **F64).psf
    # as on axis (tests/optics/test_psf_physics.py): the window misses only edge-diffracted light
    total = psf.sum().item()
    assert total <= 1 + 1e-9
    assert_allclose(total, 1.0, atol=1.5e-2)


def test_chief_ray_follows_the_lens_phase_gradient():
    """A 2-D lens whose centre carries a linear phase (a prism of period Λ) bends the chief ray:
    sin = sin α + λ/Λ; the PSF's centroid lands there, within the coma of this low-NA lens."""
    lam, f, pitch = 532e-9, 400e-6, 395e-9
    base = L.hyperbolic(lam, f, 40e-6, pitch, radial=False)
    m = base.grid_size
    x = (np.arange(m) - m // 2) * pitch
    period = 40e-6
    theta = base.theta.numpy() + (math.pi * x / period)[None, :]  # φ = 2θ gains 2π·x/Λ
    lens = L.from_array(theta, pitch, 40e-6, f)
    alpha = math.radians(4)
    x_c, y_c = chief_ray(lens, lam, alpha, 0.0, f)
    s = math.sin(alpha) + lam / period
    assert_allclose(x_c, f * s / math.sqrt(1 - s**2), rtol=1e-6)
    assert y_c == pytest.approx(0.0, abs=1e-12)
    result = field_psf(lens, PsfGrid([lam], [math.inf], 61, 0.5e-6), alpha, **F64)
    assert result.centre_px == (round(x_c / 0.5e-6), 0)
    cx, cy = centroid(result.psf[0, 0].numpy(), 0.5e-6)
    # coma centroid sin α·a²/(2f) = 0.09 µm at NA 0.05; the window truncation adds as much
    assert abs(cx + result.centre_px[0] * 0.5e-6 - x_c) < 0.25e-6
    assert abs(cy) < 1e-9


def test_radial_lens_psf_is_mirror_symmetric_about_the_meridional_plane():
    psf = field_psf(small(), PsfGrid([532e-9], [0.003], 31, 1e-6), math.radians(10), **F64).psf[0, 0]
    assert_allclose(psf.numpy(), psf.flip(0).numpy(), rtol=0, atol=1e-12 * psf.max().item())


@pytest.mark.parametrize("depth", [math.inf, 0.003])
def test_mirrored_half_equals_the_whole_pupil(depth):
    """On the +x axis a radial lens's pupil field is even in y and half its rows serve; at ψ = 2π
    (sin ψ ≠ 0 in floating point) the whole pupil is propagated: the same PSF to rounding."""
    px = dict(pixels=31, pixel_pitch_m=1e-6)
    kw = dict(angle_rad=math.radians(10), **F64)
    half = field_psf(small(), PsfGrid([532e-9], [depth], **px), azimuth_rad=0.0, **kw)
    whole = field_psf(small(), PsfGrid([532e-9], [depth], **px), azimuth_rad=2 * math.pi, **kw)
    assert half.grid["mirror_y"] and not whole.grid["mirror_y"]
    assert half.centre_px == whole.centre_px
    assert rel(half.psf, whole.psf) < 1e-12


def test_rotating_lens_and_azimuth_rotates_the_psf():
    """A 2-D lens without rotational symmetry (hyperbolic plus astigmatism): turning the map and
    the field by 90° turns the PSF by 90°, sensor pixel for sensor pixel."""
    lam, pitch = 532e-9, 395e-9
    base = L.hyperbolic(**SMALL, radial=False)
    m = base.grid_size
    c = (np.arange(m) - m // 2) * pitch
    theta = base.theta.numpy() + 2e9 * (c[None, :] ** 2 - 0.3 * c[:, None] ** 2)  # rad, ≤ 1.4 rad at the rim
    # np.rot90(θ, 1)[i, j] = θ[j, M−1−i]: the map turned by −90° in (x = column, y = row); turning the
    # lens by +90° (counter-clockwise) is np.rot90(θ, −1)
    lens = L.from_array(theta, pitch, SMALL["aperture_m"], SMALL["focal_length_m"])
    turned = L.from_array(np.rot90(theta, -1).copy(), pitch, SMALL["aperture_m"], SMALL["focal_length_m"])
    alpha, psi = math.radians(8), math.radians(20)
    px = dict(pixels=25, pixel_pitch_m=1e-6)
    kw = dict(**F64)
    a = field_psf(lens, PsfGrid([lam], [0.004], **px), angle_rad=alpha, azimuth_rad=psi, **kw)
    b = field_psf(turned, PsfGrid([lam], [0.004], **px), angle_rad=alpha, azimuth_rad=psi + math.pi / 2, **kw)
    assert b.centre_px == (-a.centre_px[1], a.centre_px[0])
    # (x, y) → (−y, x): new[i, j] = old[N−1−j, i], torch.rot90(old, −1)
    assert rel(b.psf[0, 0], torch.rot90(a.psf[0, 0], -1, dims=(0, 1))) < 1e-9


def test_radial_psf_at_an_azimuth_is_the_rotated_psf():
    lens = small()
    px = dict(pixels=25, pixel_pitch_m=1e-6)
    kw = dict(**F64)
    a = field_psf(lens, PsfGrid([532e-9], [math.inf], **px), angle_rad=math.radians(9), **kw)
    b = field_psf(lens, PsfGrid([532e-9], [math.inf], **px), angle_rad=math.radians(9), azimuth_rad=math.pi / 2, **kw)
    assert b.centre_px == (0, a.centre_px[0])
    assert rel(b.psf[0, 0], torch.rot90(a.psf[0, 0], -1, dims=(0, 1))) < 1e-9


def test_seidel_coma_of_a_low_na_lens():
    """Third-order coma of a hyperbolic lens with the stop at the lens, W = (sin α/2f²)·x·(x² + y²):
    the PSF's centroid (the mean transverse ray aberration, exact in diffraction theory) sits
    sin α·a²/(2f) outside the chief ray, linear in α. NA 0.1, window 100 µm (99 % of the light):
    measured ratios 0.977 and 0.993 at 2.5° and 5° (fifth-order terms and the window)."""
    f, a = 1e-3, 100e-6
    lens = L.hyperbolic(532e-9, f, 2 * a, 395e-9)
    offsets = []
    for degrees in (2.5, 5.0):
        alpha = math.radians(degrees)
        result = field_psf(lens, PsfGrid([532e-9], [math.inf], 201, 0.5e-6), alpha, **F64)
        cx, _ = centroid(result.psf[0, 0].numpy(), 0.5e-6)
        offset = cx + result.centre_px[0] * 0.5e-6 - result.chief_ray_m[0]
        assert_allclose(offset, math.sin(alpha) * a**2 / (2 * f), rtol=5e-2)
        offsets.append(offset)
    assert_allclose(offsets[1] / offsets[0], 2.0, rtol=3e-2)


def test_field_angle_from_height_and_refusals():
    assert_allclose(field_angle(0.47e-3, 4e-3), math.atan(0.47 / 4))
    lens = small()
    with pytest.raises(InputError, match="angle_rad"):
        field_psf(lens, PsfGrid([532e-9], [math.inf], 9, 1e-6), -0.1)
    with pytest.raises(InputError, match="propagator"):
        field_psf(lens, PsfGrid([532e-9], [math.inf], 9, 1e-6), 0.1, propagator="radial")


@pytest.mark.parametrize("radial", [True, False])
@pytest.mark.parametrize("depth", [math.inf, 0.002])
def test_off_axis_psf_is_differentiable_in_theta(radial, depth):
    """What training over the field needs: the gradient of a weighted sum of an off-axis PSF
    (5°) with respect to θ, by autograd through the shifted angular spectrum, against central
    finite differences along a random direction (float64; measured 1e-11 to 8e-8 apart)."""
    base = small(radial)
    weights = torch.linspace(0, 1, 2 * 17 * 17, dtype=torch.float64).reshape(1, 2, 17, 17)

    def loss(theta):
        lens = L.Metalens(theta, base.pitch_m, base.aperture_m, base.focal_length_m)
        psf = field_psf(lens, PsfGrid([532e-9, 600e-9], [depth], 17, 1e-6), math.radians(5), **F64).psf
        return (psf * weights).sum()

    theta = base.theta.detach().double().clone().requires_grad_(True)
    (gradient,) = torch.autograd.grad(loss(theta), theta)
    direction = torch.randn(theta.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    step = 1e-5
    with torch.no_grad():
        finite = (loss(theta + step * direction) - loss(theta - step * direction)) / (2 * step)
    assert float((gradient * direction).sum()) == pytest.approx(float(finite), rel=1e-6)
