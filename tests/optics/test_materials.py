"""Optical materials: published dispersion formulas against published values, closed forms,
tabulated interpolation, and the Kramers–Kronig consistency of the Tauc–Lorentz model."""

import dataclasses
import json
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import quad

from metalens_cli.errors import InputError
from metalens_cli.optics import materials
from metalens_cli.optics.materials import BUILTIN, Cauchy, Constant, Sellmeier, Tabulated, TaucLorentz

NM = 1e-9
# Fraunhofer lines: d (He, 587.5618 nm), C (H, 656.2725 nm), F (H, 486.1327 nm)
D_LINE, C_LINE, F_LINE = 587.5618 * NM, 656.2725 * NM, 486.1327 * NM


def test_fused_silica_malitson_spot_values():
    # Malitson (1965) tabulates n_d = 1.45846, n_C = 1.45637, n_F = 1.46313 for fused silica at
    # 20 °C; his Sellmeier fit reproduces his data to about 1e-5, hence 5e-5.
    n_d, n_c, n_f = BUILTIN["fused-silica"].index([D_LINE, C_LINE, F_LINE]).real
    assert n_d == pytest.approx(1.45846, abs=5e-5)
    assert n_c == pytest.approx(1.45637, abs=5e-5)
    assert n_f == pytest.approx(1.46313, abs=5e-5)
    assert (n_d - 1) / (n_f - n_c) == pytest.approx(67.8, abs=0.3)  # Abbe number of fused silica


def test_sinx_luke_spot_values():
    n = BUILTIN["sinx"].index(np.array([1550 * NM, 532 * NM]))
    assert n[0].real == pytest.approx(1.996, abs=0.002)  # Luke et al. 2015: n ≈ 1.996 at 1550 nm
    # 2.056 is the value of Luke et al.'s published formula at 532 nm (refractiveindex.info's
    # "Luke et al. 2015" entry gives the same); stoichiometric Si3N4 is about 2.04 near 633 nm.
    assert n[1].real == pytest.approx(2.056, abs=0.002)
    assert n[0].imag == n[1].imag == 0.0


def test_tio2_rutile_ordinary_spot_value():
    # rutile's ordinary index at the sodium D line is 2.61 (DeVore 1951 and handbooks)
    assert BUILTIN["tio2"].index(589.3 * NM).real == pytest.approx(2.613, abs=0.005)


@pytest.mark.parametrize("name, lo_nm", [("fused-silica", 400), ("sinx", 400), ("tio2", 430), ("a-si", 600)])
def test_builtin_dielectrics_have_normal_dispersion_in_the_visible(name, lo_nm):
    # a-Si: normal only red of its ε₁ maximum (n peaks near 500 nm), so from 600 nm
    n = BUILTIN[name].index(np.linspace(lo_nm, 700, 61) * NM).real
    assert np.all(np.diff(n) < 0)


def test_air_and_vacuum_are_one():
    for name in ("air", "vacuum"):
        assert_allclose(BUILTIN[name].index([100 * NM, 10e-6]), 1.0, rtol=0, atol=0)


@pytest.mark.parametrize(
    "material",
    [
        Constant(1.5 + 0.01j),
        Cauchy(1.9, 0.012, 1e-4),
        materials.SINX,
        materials.A_SI,
        Tabulated([400 * NM, 800 * NM], [2.0, 1.9], [0.1, 0.0]),
    ],
)
@pytest.mark.parametrize("shape", [(), (3,), (2, 3), (0,)])
def test_every_model_returns_complex128_of_the_input_shape(material, shape):
    wavelengths = np.full(shape, 532 * NM)
    out = material.index(wavelengths)
    assert out.dtype == np.complex128 and out.shape == shape
    assert np.all(out.imag >= 0) and np.all(out.real > 0)
    assert_allclose(material.permittivity(wavelengths), out**2, rtol=1e-15)


def test_constant_and_cauchy_closed_forms():
    lam = np.array([400, 532, 700, 1550]) * NM
    assert np.all(Constant(2.0 + 0.01j).index(lam) == 2.0 + 0.01j)
    um = lam / 1e-6
    assert_allclose(Cauchy(1.9, 0.012, 3e-4).index(lam), 1.9 + 0.012 / um**2 + 3e-4 / um**4, rtol=1e-15)
    assert_allclose(Cauchy(1.5, 0.004).index(lam), 1.5 + 0.004 / um**2, rtol=1e-15)


def test_sellmeier_of_one_term_is_its_closed_form():
    lam = np.array([0.5, 1.0, 2.0])
    material = Sellmeier((1.2,), (0.01,), valid_m=(0.3e-6, 3e-6))
    assert_allclose(material.index(lam * 1e-6), np.sqrt(1 + 1.2 * lam**2 / (lam**2 - 0.01)), rtol=1e-15)


def test_tabulated_is_exact_at_nodes_and_linear_between():
    lam = np.array([400, 500, 700]) * NM
    n, k = np.array([2.1, 2.05, 2.0]), np.array([0.02, 0.01, 0.0])
    table = Tabulated(lam, n, k)
    assert np.array_equal(table.index(lam), n + 1j * k)
    assert table.index(450 * NM) == pytest.approx(2.075 + 0.015j, abs=1e-14)
    assert table.index(650 * NM) == pytest.approx(2.0125 + 0.0025j, abs=1e-14)
    assert table.valid_m == (400 * NM, 700 * NM)
    assert Tabulated(lam, n).index(450 * NM).imag == 0.0  # k omitted: 0


def test_range_ends_allow_one_rounding_error():
    table = Tabulated([400e-9, 700e-9], [2.0, 1.9])
    assert 700 * NM > 700e-9 and table.index(700 * NM) == 1.9  # flat at the end within the slack
    assert materials.FUSED_SILICA.valid_m[1] < 3.71e-6  # 3.71 * 1e-6 rounds below 3.71e-6 (parse_length's 3.71um)
    assert 1.39 < materials.FUSED_SILICA.index(3.71e-6).real < 1.41  # accepted
    with pytest.raises(InputError):
        table.index(700e-9 * (1 + 1e-8))


@pytest.mark.parametrize("wavelength", [399 * NM, 701 * NM, 10e-6])
def test_tabulated_refuses_wavelengths_outside_the_table(wavelength):
    table = Tabulated(np.array([400, 700]) * NM, [2.0, 1.9])
    with pytest.raises(InputError) as info:
        table.index([500 * NM, wavelength], field="--wavelengths")
    assert info.value.field == "--wavelengths" and "400-700 nm" in str(info.value)


@pytest.mark.parametrize(
    "lam, n, k, why",
    [
        ([500, 400], [2, 2], None, "not strictly increasing"),
        ([400, 400], [2, 2], None, "not strictly increasing"),
        ([400], [2], None, "at least 2"),
        ([400, 500], [2, 0], None, "n > 0"),
        ([400, 500], [2, 2], [0, -0.1], "k >= 0"),
        ([400, math.nan], [2, 2], None, "finite"),
        ([400, 500], [2, 2, 2], None, "one n and k per wavelength"),
    ],
)
def test_tabulated_refuses_bad_tables(lam, n, k, why):
    with pytest.raises(InputError, match=why):
        Tabulated(np.array(lam) * NM, n, k)


def test_models_are_immutable():
    table = Tabulated(np.array([400, 700]) * NM, [2.0, 1.9])
    with pytest.raises(ValueError):
        table.n[0] = 3.0  # read-only arrays
    with pytest.raises(dataclasses.FrozenInstanceError):
        materials.SINX.b = (1.0,)


@pytest.mark.parametrize(
    "name, outside_nm",
    [("fused-silica", 200), ("sinx", 300), ("sinx", 5600), ("tio2", 420), ("tio2", 1600), ("a-si", 190)],
)
def test_builtins_refuse_wavelengths_outside_their_published_range(name, outside_nm):
    with pytest.raises(InputError) as info:
        BUILTIN[name].index(outside_nm * NM, field="--wavelength")
    assert info.value.field == "--wavelength" and name in str(info.value)


@pytest.mark.parametrize("bad", [0.0, -500 * NM, math.nan, math.inf])
def test_index_refuses_non_wavelengths(bad):
    with pytest.raises(InputError, match="not a wavelength"):
        Constant(1.5).index([500 * NM, bad], field="--wavelength")


@pytest.mark.parametrize(
    "make, why",
    [
        (lambda: Constant(2.0 - 0.1j), "gain"),
        (lambda: Constant(0), "n <= 0"),
        (lambda: Constant(math.nan), "finite"),
        (lambda: Cauchy(-1.0, 0.01), "not positive"),
        (lambda: Cauchy(1.5, math.inf), "not finite"),
        (lambda: Sellmeier((1.0,), (0.25,), valid_m=(0.3e-6, 1e-6)), "pole"),
        (lambda: Sellmeier((1.0, 2.0), (0.01,), valid_m=(0.3e-6, 1e-6)), "as many B as C"),
    ],
)
def test_models_refuse_bad_parameters(make, why):
    with pytest.raises(InputError, match=why):
        make()


def test_cauchy_refuses_wavelengths_where_its_index_is_not_positive():
    with pytest.raises(InputError, match="not a refractive index"):
        Cauchy(1.0, -0.5).index([1e-6, 0.5e-6])


def test_describe_is_json():
    for material in (*BUILTIN.values(), Cauchy(1.9, 0.01), Tabulated(np.array([400, 700]) * NM, [2.0, 1.9])):
        summary = json.loads(json.dumps(material.describe(), allow_nan=False))
        assert set(summary) == {"kind", "name", "parameters", "source", "valid_m"}
    assert materials.FUSED_SILICA.describe()["valid_m"] == pytest.approx([0.21e-6, 3.71e-6])
    assert "Malitson" in materials.FUSED_SILICA.describe()["source"]
    assert BUILTIN["air"].describe()["valid_m"] is None


# --- amorphous silicon: Tauc–Lorentz (Jellison & Modine 1996) ----------------------------------


def kramers_kronig_eps1(model: TaucLorentz, energy: float) -> float:
    """ε₁(∞) + (2/π)·P∫ ξ·ε₂(ξ)/(ξ² − E²) dξ by quadrature (Cauchy principal value where the
    pole lies above the gap), independently of the model's closed form."""
    eg, cut = model.eg_ev, 100.0

    def tail(x):
        return x * model.eps2(x) / (x * x - energy * energy)

    if energy > eg:
        body = quad(lambda x: x * model.eps2(x) / (x + energy), eg, cut, weight="cauchy", wvar=energy, limit=200)[0]
    else:
        body = quad(tail, eg, cut, limit=200)[0]
    return model.eps_inf + 2.0 / math.pi * (body + quad(tail, cut, math.inf)[0])


@pytest.mark.parametrize("energy", [0.6, 1.0, 1.2, 1.5, 2.0, 2.5, 3.45, 4.5, 6.0])
def test_tauc_lorentz_closed_form_obeys_kramers_kronig(energy):
    a_si = materials.A_SI
    assert a_si.eps1(energy) == pytest.approx(kramers_kronig_eps1(a_si, energy), abs=1e-3)


def test_tauc_lorentz_other_parameters_obey_kramers_kronig():
    # a narrow, high-gap oscillator (a nitride-like film) exercises the other signs of the closed form
    model = TaucLorentz(50.0, 8.0, 1.5, 4.5, 1.8, valid_m=(0.1e-6, 2e-6))
    for energy in (1.0, 4.5, 6.0, 8.0, 12.0):
        assert model.eps1(energy) == pytest.approx(kramers_kronig_eps1(model, energy), abs=1e-3)


def test_amorphous_silicon_is_absorbing_in_the_visible():
    a_si = BUILTIN["a-si"]
    n500, n600, n1000, n1200 = a_si.index(np.array([500, 600, 1000, 1200]) * NM)
    assert n500.imag > 0.5  # strongly absorbing in the green (Palik/Pierce-Spicer: k ≈ 1.1 at 496 nm)
    assert np.all(a_si.index(np.linspace(300, 1000, 71) * NM).imag > 0)
    # published a-Si at 600 nm: n ≈ 4.2-4.4 (Pierce & Spicer in Palik: 4.36 at 564 nm, 4.23 at 620 nm)
    assert 4.0 < n600.real < 4.6
    assert n1200.imag == 0.0  # below the Tauc gap (1.2 eV ↔ 1033 nm)
    assert a_si.eps2(np.array([0.5, 1.19, 1.2])).tolist() == [0.0, 0.0, 0.0]
