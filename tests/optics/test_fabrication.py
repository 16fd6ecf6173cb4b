"""Fabrication errors against closed forms, through drawn 2-D maps and the 2-D propagator (an
independent path: the expected-value factors of optics.fabrication are never used to make the
PSFs they are compared with)."""

import math

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.optics import fabrication as fab
from metalens_cli.optics.lens import hyperbolic
from metalens_cli.optics.psf import compute_psf
from metalens_cli.optics.sampling import PsfGrid

LAMBDA = 532e-9
# 80 µm, f = 300 µm (NA 0.13): 16 000 fins, 5 Fresnel zones; a well-corrected lens at its design λ
LENS = hyperbolic(LAMBDA, 300e-6, 80e-6, 395e-9)
GRID = PsfGrid([LAMBDA], [math.inf], 21, 0.5e-6, 300e-6)


def peak(lens) -> float:
    psf = compute_psf(lens, GRID, propagator="asm", dtype=torch.float64).psf[0, 0]
    return float(psf[10, 10])  # the axis pixel: where the design focuses


NOMINAL = peak(fab.fabricated_map(LENS, fab.FabricationErrors(), np.random.default_rng(0)))


def test_no_error_leaves_the_map_and_its_psf_unchanged():
    flat = hyperbolic(LAMBDA, 300e-6, 80e-6, 395e-9, radial=False)
    drawn = fab.fabricated_map(flat, fab.FabricationErrors(), np.random.default_rng(1))
    assert torch.equal(drawn.theta, flat.theta)
    a, b = (compute_psf(x, GRID, propagator="asm", dtype=torch.float64).psf for x in (flat, drawn))
    assert torch.equal(a, b)
    # a radial design drawn on the grid: its profile interpolated at each site's radius, within
    # the linear interpolation's error |θ''|·pitch²/8 of the closed form (θ'' ≈ π/(λf) here)
    radial = fab.fabricated_map(LENS, fab.FabricationErrors(), np.random.default_rng(1))
    bound = math.pi / (LAMBDA * 300e-6) * 395e-9**2 / 8
    _, r = flat.grid_phase()
    inside = r <= flat.radius_m  # beyond the pupil a radial profile holds its last sample
    assert float((radial.theta - flat.theta)[inside].abs().max()) <= 1.01 * bound


@pytest.mark.parametrize("sigma", [0.05, 0.1, 0.2])
def test_rotation_errors_lose_the_marechal_fraction(sigma):
    rng = np.random.default_rng(2)
    errors = fab.FabricationErrors(rotation_sigma_rad=sigma)
    ratio = np.mean([peak(fab.fabricated_map(LENS, errors, rng)) for _ in range(2)]) / NOMINAL
    # Maréchal for Gaussian phase errors 2δθ: exp(−(2σ)²); the scattered light adds about
    # (1 − κ)/N of the peak (N = 16 000 fins) and the draws vary by O(1/√N): 2e-3 covers both
    assert ratio == pytest.approx(math.exp(-((2 * sigma) ** 2)), abs=2e-3)
    assert fab.rotation_factor(sigma) == pytest.approx(math.exp(-((2 * sigma) ** 2)), rel=1e-12)


@pytest.mark.parametrize("levels", [2, 4, 8, 16])
def test_theta_levels_lose_the_known_efficiency(levels):
    ratio = peak(fab.fabricated_map(LENS, fab.FabricationErrors(theta_levels=levels), None)) / NOMINAL
    x = math.pi / levels
    # the first-order efficiency of an N-level staircase, sinc²(π/N): 0.405, 0.811, 0.950, 0.987;
    # a 5-zone lens samples its levels unevenly near the axis: within 2e-3
    assert ratio == pytest.approx((math.sin(x) / x) ** 2, abs=2e-3)
    assert fab.quantization_factor(levels) == pytest.approx((math.sin(x) / x) ** 2, rel=1e-12)


def test_stitching_loses_the_pupil_mean_of_its_phase_spread():
    rng = np.random.default_rng(3)
    errors = fab.FabricationErrors(stitch_sigma_m=100e-9, stitch_field_m=10e-6)
    ratio = np.mean([peak(fab.fabricated_map(LENS, errors, rng)) for _ in range(3)]) / NOMINAL
    # 64 write fields: the draws vary by about (1 − κ)/√64 ≈ 2e-3 about the expectation
    assert ratio == pytest.approx(fab.stitching_factor(LENS, 100e-9), abs=3e-3)
    # the expectation's closed form for a parabolic phase: |∇φ| = 2πr/(λf), a mean over the disc
    # of exp(−s·r²/a²) with s = (2πσa/(λf))²/2 is (1 − e^{−s})/s
    s = (2 * math.pi * 100e-9 * 40e-6 / (LAMBDA * 300e-6)) ** 2 / 2
    assert fab.stitching_factor(LENS, 100e-9) == pytest.approx(((1 - math.exp(-s)) / s) ** 2, rel=2e-3)


def test_a_fin_map_is_placed_by_write_field():
    """Each write field moves as one piece: sites of a field share their offset."""
    flat = hyperbolic(LAMBDA, 300e-6, 80e-6, 395e-9, radial=False)
    errors = fab.FabricationErrors(stitch_sigma_m=50e-9, stitch_field_m=20e-6)
    drawn = fab.fabricated_map(flat, errors, np.random.default_rng(4))
    m = flat.grid_size
    coords = (np.arange(m) - m // 2) * flat.pitch_m
    field = np.floor((coords + flat.radius_m) / 20e-6).astype(int)
    delta = (drawn.theta - flat.theta).numpy()
    gy, gx = np.gradient(flat.theta.numpy(), flat.pitch_m)
    # first order: δθ = −d·∇θ with one d per field; solve for d in each field and check the fit
    for fy in range(2):
        for fx in range(2):
            rows, cols = np.nonzero((field[:, None] == fy + 1) & (field[None, :] == fx + 1))
            a = np.stack([-gx[rows, cols], -gy[rows, cols]], 1)
            d, *_ = np.linalg.lstsq(a, delta[rows, cols], rcond=None)
            assert np.allclose(a @ d, delta[rows, cols], atol=1e-9)
            assert 0 < np.hypot(*d) < 5 * 50e-9


def test_veil_per_pixel_integrates_a_flat_spectrum():
    # p²·sinc² over |ν| < 1/λ holds ≤ 1 of the power: the per-pixel share times the sensor area
    # the propagating cone reaches (π(λd·ν)² at ν = 1/λ... near the axis) stays below 1
    share = fab.veil_per_pixel(395e-9, 1.85e-6, 530e-9, 4e-3)
    assert share == pytest.approx((395e-9 * 1.85e-6 / (530e-9 * 4e-3)) ** 2)
    assert share * 512**2 < 0.05  # the paper's sensor collects a few % of scattered light


@pytest.mark.parametrize(
    "field, value, option",
    [
        ("rotation_sigma_rad", -0.1, "--rotation-sigma"),
        ("theta_levels", 1, "--theta-levels"),
        ("theta_levels", 2.5, "--theta-levels"),
        ("missing", 1.0, "--missing"),
        ("missing", math.nan, "--missing"),
        ("stitch_sigma_m", -1e-9, "--stitch-sigma"),
        ("stitch_field_m", 0.0, "--stitch-field"),
        ("width_sigma_m", math.inf, "--width-sigma"),
    ],
)
def test_impossible_errors_are_refused_naming_the_option(field, value, option):
    with pytest.raises(InputError) as caught:
        fab.FabricationErrors(**{field: value})
    assert caught.value.field == option
