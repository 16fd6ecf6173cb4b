"""The Binary 2 fit against the hyperbolic lens's closed form and its Taylor series, evaluated
here independently of the code under test."""

import math

import numpy as np
import pytest

from metalens_cli.analysis.phase_export import choose_binary2, fit_binary2, radial_phase_samples
from metalens_cli.errors import InputError
from metalens_cli.optics.lens import from_array, hyperbolic

LAMBDA, F, D, PITCH = 532e-9, 4e-3, 2.516e-3, 395e-9  # the paper's hyperbolic baseline
R = D / 2


def closed_form(r):
    """φ(r) = −(2π/λd)(√(r² + f²) − f), in the form without cancellation."""
    return -(2 * math.pi / LAMBDA) * r**2 / (np.sqrt(r**2 + F**2) + F)


@pytest.fixture(scope="module")
def samples():
    return radial_phase_samples(hyperbolic(LAMBDA, F, D, PITCH))


@pytest.mark.parametrize("order", [3, 5, 8])
def test_fit_reproduces_the_closed_form_within_its_reported_residual(samples, order):
    r, phase, _ = samples
    fit = fit_binary2(r, phase, order, R)
    assert r[-1] <= R and r.size == math.floor(R / PITCH + 1e-9) + 1  # the design's samples in the pupil
    dense = np.linspace(0, r[-1], 20001)  # between the samples too (up to the last one, 0.32 µm inside D/2)
    a = np.array(fit.surface.coefficients_rad)
    mine = sum(a[i] * (dense / R) ** (2 * i + 2) for i in range(order))  # the Binary 2 sum, written out
    error = np.abs(mine - closed_form(dense))
    # The residual is smooth (a polynomial minus a function analytic far beyond the pupil), so between
    # samples 395 nm apart it cannot exceed its extremes at them by more than float64 rounding (1e-9 rad).
    assert error.max() <= fit.max_rad * 1.01 + 1e-9
    assert fit.max_rad <= {3: 2 * math.pi * 1e-3, 5: 2 * math.pi * 1e-6, 8: 1e-9}[order]


def test_leading_coefficients_match_the_taylor_series(samples):
    r, phase, _ = samples
    fit = fit_binary2(r, phase, 8, R)
    # √(f² + R²u) − f = f(εu/2 − ε²u²/8 + …), ε = R²/f² ≈ 0.099: A_1 = −πR²/(λf), A_2 = πR⁴/(4λf³).
    a1, a2 = -math.pi * R**2 / (LAMBDA * F), math.pi * R**4 / (4 * LAMBDA * F**3)
    # The first omitted term, (2πf/λ)·|C(1/2, 9)|·ε⁹ ≈ 8e-7 rad, is all the fit can move A_1 and A_2 by
    # (times the modest Legendre-to-power-series factor at order 8), far below 1e-6 relative.
    assert fit.surface.coefficients_rad[0] == pytest.approx(a1, rel=1e-9)
    assert fit.surface.coefficients_rad[1] == pytest.approx(a2, rel=1e-6)
    assert a1 < 0  # converging: phase decreasing outward


def test_automatic_order_is_the_fewest_within_tolerance(samples):
    r, phase, _ = samples
    fit = choose_binary2(r, phase, norm_radius_m=R, tolerance_rad=2 * math.pi * 0.01)
    assert fit.surface.order == 3 and fit.max_rad <= 2 * math.pi * 0.01
    assert fit_binary2(r, phase, 2, R).max_rad > 2 * math.pi * 0.01


def test_unreachable_tolerance_is_refused_with_the_best_residual():
    rng = np.random.default_rng(0)
    theta = np.cumsum(rng.normal(0, 0.3, 200))  # a rough profile no polynomial follows
    r, phase, _ = radial_phase_samples(from_array(theta, 1e-6, 300e-6))
    with pytest.raises(
        InputError, match=r"^tolerance: no Binary 2 fit of up to 12 terms .* the best, \d+ terms, leaves"
    ):
        choose_binary2(r, phase, norm_radius_m=150e-6, tolerance_rad=1e-3, max_order=12)


def test_unwrapping_takes_the_smooth_representative():
    lens = hyperbolic(LAMBDA, F, 200e-6, PITCH)
    wrapped = np.mod(lens.theta.numpy(), math.pi)  # θ mod π: φ mod 2π, the same lens
    r, phase, _ = radial_phase_samples(from_array(wrapped, PITCH, 200e-6))
    np.testing.assert_allclose(phase, closed_form(r), atol=1e-9)  # steps < π at this pitch and NA
