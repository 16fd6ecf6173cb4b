"""Split-spectrum conditions and their closed-form windows."""

import math

import pytest
from numpy.testing import assert_allclose

from metalens_cli.analysis import bands as m
from metalens_cli.errors import InputError
from metalens_cli.optics.split_spectrum import incidence_factor

PAPER = m.bands_from_centers([457e-9, 530e-9, 628e-9], [22e-9, 20e-9, 28e-9])


def test_paper_configuration_holds_with_its_window():
    report = m.check_bands(PAPER, 4e-3, (0.045, 0.045))
    assert report.ok
    assert_allclose(report.s[0], 1 + 4 / 45, rtol=1e-12)
    names = [c.name for c in report.conditions]
    assert names[:5] == ["B.min_into_stop", "B.max_below_G", "G.min_into_stop", "G.max_below_R", "R.min_into_stop"]
    # Window: s ∈ (468/446, 520/468) → z ∈ (f/(520/468 − 1), f/(468/446 − 1)) = (36 mm, 81.09 mm).
    lo, hi = report.z_near_window_m
    assert_allclose(lo, 4e-3 / (520 / 468 - 1), rtol=1e-9)
    assert_allclose(hi, 4e-3 / (468 / 446 - 1), rtol=1e-9)
    assert lo < 0.045 < hi
    f_lo, f_hi = report.f_window_m
    assert f_lo < 4e-3 < f_hi


def test_margins_are_the_two_sides_difference():
    report = m.check_bands(PAPER, 4e-3, (0.045, 0.045))
    first = report.conditions[0]
    s = 1 + 4 / 45
    assert_allclose(first.lhs_m, 446e-9 * s, rtol=1e-12)
    assert_allclose(first.rhs_m, 468e-9, rtol=1e-12)
    assert_allclose(first.margin_m, 446e-9 * s - 468e-9, rtol=1e-9)


def test_window_edges_flip_the_verdict():
    # Just inside the z_near window everything holds; just outside, the named condition fails.
    lo, hi = m.check_bands(PAPER, 4e-3, (0.045, 0.045)).z_near_window_m
    assert m.check_bands(PAPER, 4e-3, (lo * 1.001, hi * 0.999)).ok
    far = m.check_bands(PAPER, 4e-3, (hi * 1.001, hi * 1.001))
    assert not far.ok and not next(c for c in far.conditions if c.name == "B.min_into_stop").ok
    near = m.check_bands(PAPER, 4e-3, (lo * 0.999, lo * 0.999))
    assert not near.ok and not next(c for c in near.conditions if c.name == "B.max_below_G").ok


def test_range_checked_at_worst_depth():
    report = m.check_bands(PAPER, 4e-3, (0.04, 0.05))
    by_name = {c.name: c for c in report.conditions}
    assert by_name["B.min_into_stop"].depth_m == 0.05  # smallest shift
    assert by_name["B.max_below_G"].depth_m == 0.04  # largest shift
    assert report.ok


def test_general_condition_catches_overlap():
    # Two close bands: the first band shifted at 100 mm lands on the second.
    bands = m.bands_from_centers([500e-9, 515e-9], [10e-9, 10e-9])
    report = m.check_bands(bands, 4e-3, (0.1, 0.1))
    general = {c.name: c for c in report.conditions}["band1.clear_of_pass_bands"]
    assert not general.ok and general.margin_m < 0


def test_band_shifted_beyond_sensor_is_clear():
    bands = m.bands_from_centers([680e-9], [20e-9])
    report = m.check_bands(bands, 4e-3, (0.01, 0.01))
    general = report.conditions[-1]
    assert general.ok and general.rhs_m == 700e-9
    assert report.z_near_window_m[0] == 0.0  # one band: no upper bound on s


def test_no_window_when_bands_too_wide():
    bands = m.bands_from_centers([450e-9, 520e-9], [60e-9, 40e-9])
    report = m.check_bands(bands, 4e-3, (0.045, 0.045))
    assert report.z_near_window_m is None and report.f_window_m is None and not report.ok


def test_bands_from_transmission_interpolates_edges():
    wl = [400e-9 + i * 1e-9 for i in range(301)]
    t = [1.0 if 446e-9 <= w <= 468e-9 else 0.0 for w in wl]
    (band,) = m.bands_from_transmission(wl, t, threshold=0.5)
    # Edges are mid-way between the last 0 and first 1 samples: 1 nm grid → ±0.5 nm.
    assert_allclose([band.lo_m, band.hi_m], [445.5e-9, 468.5e-9], atol=1e-15)


def test_filter_csv_percent_and_header(tmp_path):
    path = tmp_path / "filter.csv"
    rows = ["wavelength_nm,transmission"] + [f"{400 + i},{90 if 520 <= 400 + i <= 540 else 1}" for i in range(301)]
    path.write_text("\n".join(rows))
    wl, t = m.read_filter_csv(path)
    assert max(t) == pytest.approx(0.9)
    (band,) = m.bands_from_transmission(wl, t)
    assert 519e-9 < band.lo_m < 520e-9 and 540e-9 < band.hi_m < 541e-9


def test_bad_bands_refused():
    with pytest.raises(InputError, match="overlap"):
        m.bands_from_centers([500e-9, 505e-9], [20e-9, 20e-9])
    with pytest.raises(InputError, match="no pass band"):
        m.bands_from_transmission([400e-9, 500e-9], [0.1, 0.2])


@pytest.mark.parametrize("degrees", [0.0, 30.0, 89.99999, 89.999999999])
def test_incidence_factor_is_cos_theta_at_n_eff_one(degrees):
    """Closed form: with n_eff = 1 the band factor is cos θ, to full relative precision near 90°
    (the difference form 1 − sin²θ rounded it to 0 at 89.999999999°)."""
    theta = math.radians(degrees)
    assert incidence_factor(theta, 1.0) == pytest.approx(math.cos(theta), rel=1e-12)
    assert incidence_factor(theta, 1.5) == pytest.approx(math.sqrt(1 - (math.sin(theta) / 1.5) ** 2), rel=1e-12)


def test_grazing_incidence_fails_the_conditions_without_an_error():
    """Rays at 89.999999999° on a filter with n_eff = 1 move every band's short edge to ~0 nm:
    the conditions fail and there is no window (it was a ZeroDivisionError)."""
    bands = m.bands_from_centers([457e-9, 530e-9, 628e-9], [22e-9, 20e-9, 28e-9])
    k = incidence_factor(math.radians(89.999999999), 1.0)
    report = m.check_bands(bands, 4e-3, (0.040, 0.050), incidence=k)
    assert not report.ok and report.z_near_window_m is None and report.f_window_m is None
