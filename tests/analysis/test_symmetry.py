"""Depth-wavelength model against its closed forms (Suppl. Note 1)."""

import math

import pytest
from numpy.testing import assert_allclose

from metalens_cli.analysis import symmetry as m
from metalens_cli.errors import InputError

F, LD = 4e-3, 450e-9


def test_depth_closed_form():
    # z = λd f / (λ − λd): 530 nm from a 450 nm, 4 mm lens focuses from 22.5 mm exactly.
    row = m.depth_for_wavelength(530e-9, LD, F)
    assert row.kind == "real"
    assert_allclose(row.depth_m, 450e-9 * 4e-3 / 80e-9, rtol=1e-12)
    assert_allclose(row.depth_m, 22.5e-3, rtol=1e-12)


@pytest.mark.parametrize("wavelength", [451e-9, 500e-9, 700e-9, 450.0001e-9])
def test_round_trip(wavelength):
    # λ(z(λ)) = λ to float64 rounding, including next to the asymptote (z ~ 20 m).
    z = m.depth_for_wavelength(wavelength, LD, F).depth_m
    assert_allclose(m.wavelength_for_depth(z, LD, F), wavelength, rtol=1e-12)


def test_asymptote_and_virtual_source():
    assert m.depth_for_wavelength(450e-9, LD, F) == m.DepthRow(450e-9, None, "infinite")
    assert m.depth_for_wavelength(440e-9, LD, F).kind == "virtual"
    assert m.depth_for_wavelength(440e-9, LD, F).depth_m is None
    # Approaching λd from above the depth grows without bound as 1/(λ − λd).
    near = [m.depth_for_wavelength(LD * (1 + eps), LD, F).depth_m for eps in (1e-3, 1e-6)]
    assert_allclose(near, [F / 1e-3, F / 1e-6], rtol=1e-9)
    assert m.wavelength_for_depth(math.inf, LD, F) == LD


def test_delta_wavelength_matches_difference_of_wavelengths():
    # Δλ = λ(z) − λ(z − Δz) by definition; the closed form must agree.
    d = m.delta_wavelength(5e-3, 45e-3, LD, F)
    expected = m.wavelength_for_depth(45e-3, LD, F) - m.wavelength_for_depth(40e-3, LD, F)
    assert_allclose(d.delta_wavelength_m, expected, rtol=1e-12)
    assert_allclose(d.delta_wavelength_m, -5e-9, rtol=1e-9)  # 490 nm → 495 nm


def test_delta_wavelength_refuses_non_real_shifted_depth():
    with pytest.raises(InputError, match="--delta-z"):
        m.delta_wavelength(50e-3, 45e-3, LD, F)


def test_default_grid():
    assert len(m.DEFAULT_WAVELENGTHS_M) == 31
    assert m.DEFAULT_WAVELENGTHS_M[0] == 400e-9 and m.DEFAULT_WAVELENGTHS_M[-1] == 700e-9
