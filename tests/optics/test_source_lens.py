"""Source phase without cancellation, lens builders and their validation."""

import math

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose

from metalens_cli.errors import InputError
from metalens_cli.optics import lens as L
from metalens_cli.optics.source import source_amplitude, source_phase

R = torch.linspace(0, 1.258e-3, 2001)  # the paper's pupil radius


@pytest.mark.parametrize("depth", [20.0, 1000.0])
def test_source_phase_float32_matches_float64(depth):
    exact = source_phase(R.double(), 532e-9, depth).numpy()
    single = source_phase(R.float(), 532e-9, depth).double().numpy()
    # float32 carries ~6e-8 relative error on a phase of ≤ 0.5 rad (z = 20 m): 1e-6 rad is ample,
    # while the cancelling form k·√(r² + z²) − k·z loses everything in float32 (checked below:
    # 0.4 rad at 20 m, the whole 9 mrad phase at 1 km).
    assert_allclose(single, exact, rtol=0, atol=1e-6)
    k = 2 * math.pi / 532e-9
    r32, z32 = R.float(), torch.tensor(depth, dtype=torch.float32)
    naive = (k * torch.sqrt(r32**2 + z32**2) - k * z32).double().numpy()
    assert np.abs(naive - exact).max() > 1e-3


@pytest.mark.parametrize("depth", [1e-3, 1e3, 1e150, 1e300])
def test_source_phase_against_its_series_at_any_depth(depth):
    """k(√(r² + z²) − z) = k r²/(2z) · (1 − r²/(4z²) + r⁴/(8z⁴) − …): the closed form for r ≪ z,
    finite and without overflow up to z = 1e300 m (z² would overflow)."""
    k = 2 * math.pi / 532e-9
    r = R.double()[1:]
    phase = source_phase(r, 532e-9, depth).numpy()
    x = (r.numpy() / depth) ** 2
    series = k * r.numpy() ** 2 / (2 * depth) * (1 - x / 4 + x**2 / 8 - 5 * x**3 / 64)
    if depth > 1e-2:
        assert_allclose(phase, series, rtol=1e-12)
    else:  # r ~ z: the direct form (which cancels to ~1e-10 relative near the axis)
        assert_allclose(phase, k * (np.hypot(r.numpy(), depth) - depth), rtol=1e-9)


def test_plane_wave_and_amplitude():
    assert torch.all(source_phase(R, 500e-9, math.inf) == 0)
    assert torch.all(source_amplitude(R, math.inf) == 1)
    # amplitude z/R: exact closed form at r = z
    assert_allclose(
        source_amplitude(torch.tensor([1e-3], dtype=torch.float64), 1e-3).item(), 1 / math.sqrt(2), rtol=1e-12
    )


def test_hyperbolic_phase_has_no_cancellation():
    r = np.array([1e-6, 1e-4, 1.258e-3])
    f, lam = 4e-3, 532e-9
    # exact value from the identity √(r²+f²) − f = r²/(√(r²+f²)+f) in extended precision
    exact = -(2 * math.pi / lam) * np.array(
        [float((np.longdouble(x) ** 2 + np.longdouble(f) ** 2) ** np.longdouble(0.5) - np.longdouble(f)) for x in r]
    )
    assert_allclose(L.hyperbolic_phase(r, lam, f), exact, rtol=1e-9)  # long double: ~1e-10 here


def test_radial_profile_interpolates_linearly_and_is_differentiable():
    lens = L.from_array(np.array([0.0, 1.0, 3.0]), pitch_m=1e-6, aperture_m=3e-6)
    theta = lens.theta.clone().requires_grad_(True)
    lens = L.Metalens(theta, 1e-6, 3e-6)
    phase = lens.phase_at_radius(torch.tensor([0.5e-6, 1.5e-6], dtype=torch.float64))
    assert_allclose(phase.detach().numpy(), [1.0, 4.0], rtol=1e-12)  # φ = 2θ, linear
    phase.sum().backward()
    assert_allclose(theta.grad.numpy(), [1.0, 2.0, 1.0], rtol=1e-12)


def test_grid_has_axis_on_centre_site():
    lens = L.hyperbolic(532e-9, 1e-3, 20e-6, 1e-6, radial=False)
    phase, r = lens.grid_phase()
    m = phase.shape[0]
    assert m == 21 and r[m // 2, m // 2] == 0 and phase[m // 2, m // 2] == 0
    radial = L.hyperbolic(532e-9, 1e-3, 20e-6, 1e-6)
    pupil = (r <= lens.radius_m).numpy()
    # linear interpolation of θ(r) between k·p: error ≤ p²·max|φ''|/8 = p²·k/(8f) ≈ 1.5e-3 rad
    assert_allclose(radial.grid_phase()[0].numpy()[pupil], phase.numpy()[pupil], rtol=0, atol=2e-3)


@pytest.mark.parametrize(
    "theta", [np.zeros(5), np.zeros((7, 8)), np.zeros((5, 5)), np.zeros((2, 2, 2)), np.array([0.0, np.nan] * 10)]
)
def test_from_array_rejects_bad_shapes(theta):
    with pytest.raises(InputError):
        L.from_array(theta, pitch_m=1e-6, aperture_m=10e-6)


def test_from_array_accepts_matching_shapes():
    assert L.from_array(np.zeros(6), 1e-6, 10e-6).radial
    assert not L.from_array(np.zeros((11, 11)), 1e-6, 10e-6).radial
