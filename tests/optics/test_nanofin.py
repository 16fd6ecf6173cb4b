"""The reference RCWA (optics.nanofin.fin_response_meent) against cases whose answer needs no code: a homogeneous
layer is a Fabry-Pérot slab and converts nothing, a square fin converts nothing, a fin turned
by 90° converts the same, a lossless fin conserves energy."""

import math

import numpy as np
import pytest

from metalens_cli.errors import InputError
from metalens_cli.optics.fin import Fin
from metalens_cli.optics.nanofin import fin_response_meent

WAVELENGTHS = np.array([457e-9, 530e-9, 628e-9])
N_SUB = 1.46


def response(fin, n_fin=2.0, harmonics=5, wavelengths=WAVELENGTHS):
    return fin_response_meent(
        fin,
        np.full(len(wavelengths), n_fin, complex),
        np.full(len(wavelengths), N_SUB, complex),
        wavelengths,
        harmonics,
    )


def test_a_homogeneous_layer_is_a_fabry_perot_slab_and_converts_nothing():
    """w = l = p: a film of index n2 and thickness d between glass (n1) and air (n3):
    T = (n3/n1)·|t12·t23·e^{iβ}/(1 + r12·r23·e^{2iβ})|², β = 2π·n2·d/λ."""
    d, n2 = 700e-9, 2.0
    r = response(Fin(395e-9, d, 395e-9, 395e-9), n2, harmonics=3)
    n1, n3 = N_SUB, 1.0
    beta = 2 * math.pi * n2 * d / WAVELENGTHS
    t = (
        (2 * n1 / (n1 + n2))
        * (2 * n2 / (n2 + n3))
        * np.exp(1j * beta)
        / (1 + ((n1 - n2) / (n1 + n2)) * ((n2 - n3) / (n2 + n3)) * np.exp(2j * beta))
    )
    np.testing.assert_allclose(r.transmittance, n3 / n1 * np.abs(t) ** 2, rtol=1e-9)
    np.testing.assert_allclose(np.abs(r.t_xx) ** 2, r.transmittance, rtol=1e-9)  # one order: all of T is in it
    np.testing.assert_allclose(r.t_xx, r.t_yy, atol=1e-12)  # isotropic: the TE/TM phase convention is right
    assert np.all(r.conversion < 1e-20)


def test_a_square_fin_converts_nothing_in_the_limit():
    """By symmetry η = 0; meent's x-then-y factorisation breaks it at finite N, less as N grows."""
    coarse, fine = (response(Fin(395e-9, 700e-9, 200e-9, 200e-9), harmonics=n) for n in (5, 9))
    assert np.all(fine.conversion < 1e-5) and np.all(fine.conversion < 0.2 * coarse.conversion)
    assert np.all(fine.co_polarized > 0.3)


def test_a_fin_turned_by_90_degrees_converts_the_same_in_the_limit():
    """Turning the fin swaps t_xx and t_yy: η is the same, up to the factorisation's asymmetry."""
    gaps = []
    for n in (5, 9):
        a, b = (
            response(Fin(395e-9, 700e-9, 305e-9, 125e-9), harmonics=n),
            response(Fin(395e-9, 700e-9, 125e-9, 305e-9), harmonics=n),
        )
        gaps.append(np.abs(a.conversion - b.conversion).max())
        np.testing.assert_allclose(a.t_xx, b.t_yy, atol=0.05)
    assert gaps[1] < 5e-3 and gaps[1] < 0.7 * gaps[0]
    assert np.all(a.conversion > 0.3)  # a half-wave-like fin converts a good part


def test_energy_is_conserved_for_a_lossless_fin_and_lost_in_an_absorbing_one():
    fin = Fin(395e-9, 700e-9, 305e-9, 125e-9)
    lossless = response(fin)
    np.testing.assert_allclose(lossless.transmittance + lossless.reflectance, 1.0, atol=1e-9)
    assert np.all(
        lossless.conversion + lossless.co_polarized <= lossless.transmittance + 1e-12
    )  # the zeroth order is part of T
    lossy = response(fin, 2.0 + 0.05j)
    assert np.all(lossy.transmittance + lossy.reflectance < 0.99)


@pytest.mark.parametrize(
    ("fin", "message"),
    [
        ((395e-9, 700e-9, 400e-9, 125e-9), "width: 400 nm is larger than the 395 nm period"),
        ((395e-9, 700e-9, 305e-9, 0.0), "length_m: 0 is out of range"),
        ((395e-9, -1e-9, 305e-9, 125e-9), "height"),
    ],
)
def test_bad_geometry_is_refused(fin, message):
    with pytest.raises(InputError, match=message):  # a fin is checked as it is made
        response(Fin(*fin))


def test_an_even_number_of_harmonics_is_refused():
    with pytest.raises(InputError, match="an odd number"):
        response(Fin(395e-9, 700e-9, 305e-9, 125e-9), harmonics=4)


def test_an_independent_package_agrees():
    """torcwa (plain Laurent rule, stored once in data/torcwa_fin.json) against meent (Li's rule)
    at 530 nm: the same Jones coefficients in the same convention (phase and time sign
    included), η within 1e-2 for a low-contrast fin (n = 1.6) where Laurent converges; for
    n = 2.0 Laurent's η is still 0.02 low at 25 × 25 (issue 17 measured 0.016 at 31 × 31), so
    only the coefficients are compared there, within 0.05 for t_xx and 0.1 for t_yy (the
    polarisation across the fin, where the factorisation rule matters)."""
    import json
    from pathlib import Path

    reference = json.loads((Path(__file__).parent / "data" / "torcwa_fin.json").read_text())
    fin = Fin(395e-9, 700e-9, 305e-9, 125e-9)
    for case in reference["cases"]:
        r = response(fin, case["n_fin"], harmonics=15, wavelengths=np.array([reference["wavelength_m"]]))
        assert abs(r.t_xx[0] - complex(*case["t_xx"])) < 0.05
        assert abs(r.t_yy[0] - complex(*case["t_yy"])) < 0.1
        if case["n_fin"] == 1.6:
            assert abs(r.conversion[0] - case["conversion"]) < 1e-2
