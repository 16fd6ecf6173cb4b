"""Numerical focal-intensity map against closed forms and the paraxial model."""

import math

import numpy as np
from numpy.testing import assert_allclose

from metalens_cli.analysis.focal_map import on_axis_intensity, required_samples, validate_symmetry


def test_in_focus_intensity_matches_closed_form():
    # A hyperbolic lens at λ = λd with a plane wave makes φ + kR = k·f on the whole pupil, so
    # E(0, f) = ∫ (f/R²)(1/R − ik) r dr = (1 − cos α) − i (k f / 2) ln(1 / cos² α) exactly.
    lam, f, D = 532e-9, 4e-3, 2.516e-3
    cos_a = f / math.hypot(D / 2, f)
    k = 2 * math.pi / lam
    expected = (1 - cos_a) ** 2 + (k * f / 2 * math.log(1 / cos_a**2)) ** 2
    got = on_axis_intensity(np.array([lam]), np.array([math.inf]), lam, f, D)[0, 0]
    assert_allclose(got, expected, rtol=1e-9)  # Simpson on a smooth integrand: ~machine precision


def test_quadrature_converged_for_defocused_sources():
    # With the samples chosen by required_samples, Simpson is in its asymptotic regime: doubling
    # the samples cuts the error ~16× (4th order; we require ≥ 8×), and the coarse map is within
    # 1e-6 of the in-focus peak intensity, the scale on which the map is read.
    lam, depths = np.array([480e-9, 650e-9]), np.array([5e-3, 0.045, math.inf])
    args = (lam, depths, 450e-9, 4e-3, 2.516e-3)
    n = required_samples(*args)
    coarse, fine, finer = (on_axis_intensity(*args, samples=m * (n - 1) + 1) for m in (1, 2, 4))
    peak = on_axis_intensity(np.array([450e-9]), np.array([math.inf]), 450e-9, 4e-3, 2.516e-3)[0, 0]
    assert_allclose(coarse, finer, rtol=0, atol=1e-6 * peak)
    assert np.max(np.abs(coarse - fine) / fine) > 8 * np.max(np.abs(fine - finer) / finer)


def test_low_na_follows_paraxial_model():
    # At NA ≈ 0.025 the paraxial model holds to O(NA²) ≈ 6e-4.
    v = validate_symmetry([500e-9, 600e-9], 450e-9, 4e-3, 0.2e-3)
    assert all(abs(r.rel_deviation) < 1e-3 for r in v.rows)
    assert v.convergence < 1e-6


def test_paper_na_deviates_by_a_few_percent():
    # NA 0.3: the exact best-focus depth lies 1-3 % beyond the paraxial depth (the non-paraxial focal shift).
    v = validate_symmetry([490e-9], 450e-9, 4e-3, 2.516e-3)
    (row,) = v.rows
    assert_allclose(row.model_depth_m, 0.045, rtol=1e-12)
    assert 0.005 < row.rel_deviation < 0.04


def test_virtual_source_has_no_model_depth():
    v = validate_symmetry([440e-9, 500e-9], 450e-9, 4e-3, 0.2e-3)
    assert v.rows[0].model_depth_m is None and v.rows[0].rel_deviation is None
