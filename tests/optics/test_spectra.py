"""Spectral sensitivity S^c = CRF^c · T_filter · η and wavelength sampling per channel."""

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose
from scipy.integrate import trapezoid
from scipy.special import erf

from metalens_cli.errors import InputError
from metalens_cli.optics import spectra

NM = 1e-9
PAPER_CENTRES = np.array([457, 530, 628]) * NM
PAPER_WIDTHS = np.array([22, 20, 28]) * NM
PAPER_ETA = (PAPER_CENTRES, np.array([0.784, 0.729, 0.669]))


def gaussian_sensitivity(centres_nm=(620, 530, 460), sigma_nm=(15, 12, 10), step_nm=0.05):
    """S^c as three Gaussians on a fine grid, with their exact CDFs."""
    grid = np.arange(380, 780 + step_nm / 2, step_nm) * NM
    centres, sigmas = np.array(centres_nm)[:, None] * NM, np.array(sigma_nm)[:, None] * NM
    values = np.exp(-0.5 * ((grid - centres) / sigmas) ** 2)
    return spectra.SpectralSensitivity(grid, values), centres.ravel(), sigmas.ravel()


def paper_sensitivity(grid=None):
    """The paper's camera chain: Nikon 5100 response, triple-band filter, RCWA efficiencies."""
    grid = spectra.wavelength_grid() if grid is None else grid
    return spectra.spectral_sensitivity(
        grid,
        spectra.camera_response(grid),
        spectra.bandpass_transmission(grid, PAPER_CENTRES, PAPER_WIDTHS),
        spectra.efficiency_from_table(grid, *PAPER_ETA),
    )


def half_maximum_crossings(grid, values):
    """Wavelengths where ``values`` crosses half its maximum (linear interpolation)."""
    above = values >= values.max() / 2
    edges = np.flatnonzero(np.diff(above.astype(int)))
    half = values.max() / 2
    return np.array(
        [grid[i] + (half - values[i]) / (values[i + 1] - values[i]) * (grid[i + 1] - grid[i]) for i in edges]
    )


# ---------------------------------------------------------------------------- import hygiene


def test_module_imports_neither_torch_nor_colour():
    code = "import sys, metalens_cli.optics.spectra; print('torch' in sys.modules, 'colour' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["False", "False"]


# ---------------------------------------------------------------------------- filter


@pytest.mark.parametrize("edge_nm", [1.0, 4.0, 12.0])
@pytest.mark.parametrize("peak", [1.0, 0.9])
def test_filter_band_has_the_requested_fwhm_and_peak(edge_nm, peak):
    grid = np.arange(420, 680, 0.001) * NM
    transmission = spectra.bandpass_transmission(
        grid, PAPER_CENTRES, PAPER_WIDTHS, edge_width_m=edge_nm * NM, peak=peak
    )
    for centre, width in zip(PAPER_CENTRES, PAPER_WIDTHS):
        band = np.abs(grid - centre) < width
        low, high = half_maximum_crossings(grid[band], transmission[band])
        # Linear interpolation on a 1 pm grid of a curve whose curvature scale is >= 0.1 nm:
        # the crossing is off by far less than 1e-3 nm; the model makes it exact in theory.
        assert_allclose([low, high], [centre - width / 2, centre + width / 2], atol=1e-3 * NM)
        # T(centre) = peak by construction; the other bands' tails add < e^-20 there.
        assert_allclose(
            spectra.bandpass_transmission(centre, PAPER_CENTRES, PAPER_WIDTHS, edge_width_m=edge_nm * NM, peak=peak),
            peak,
            rtol=1e-9,
        )


def test_filter_edge_width_is_the_10_to_90_percent_rise():
    grid = np.arange(560, 700, 0.001) * NM
    wide = spectra.bandpass_transmission(grid, 628 * NM, 60 * NM, edge_width_m=4 * NM)
    rising = grid < 628 * NM
    at_10 = np.interp(0.1, wide[rising], grid[rising])
    at_90 = np.interp(0.9, wide[rising], grid[rising])
    # For a band 15x wider than its edge the opposite edge's factor differs from 1 by ~e^-30
    # and the normalisation by ~e^-16, so the rise is that of a single logistic edge.
    assert_allclose(at_90 - at_10, 4 * NM, rtol=1e-6)


def test_filter_refuses_overlapping_or_too_narrow_bands():
    grid = spectra.wavelength_grid()
    with pytest.raises(InputError, match="overlap"):
        spectra.bandpass_transmission(grid, [500 * NM, 510 * NM], [20 * NM, 20 * NM])
    with pytest.raises(InputError, match="narrower"):
        spectra.bandpass_transmission(grid, [500 * NM], [2 * NM], edge_width_m=4 * NM)
    with pytest.raises(InputError, match="centres"):
        spectra.bandpass_transmission(grid, [500 * NM, 600 * NM], [20 * NM])


# ---------------------------------------------------------------------------- efficiency, camera


def test_efficiency_is_linear_with_flat_extrapolation():
    wavelengths = np.array([400, 457, 493.5, 530, 628, 700]) * NM
    eta = spectra.efficiency_from_table(wavelengths, *PAPER_ETA)
    # Exact table values, the midpoint of 457-530 nm, flat beyond both ends (float64 rounding).
    assert_allclose(eta, [0.784, 0.784, (0.784 + 0.729) / 2, 0.729, 0.669, 0.669], atol=1e-12)


def test_named_camera_matches_colour_science_and_is_ordered_rgb():
    import colour

    data = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    grid = np.asarray(data.wavelengths) * NM
    crf = spectra.camera_response(grid)
    assert crf.shape == (3, grid.size)
    # The data set's own columns red, green, blue, at its own wavelengths (the nm -> m -> nm
    # round trip moves them by an ulp, hence rtol at float64 rounding).
    assert_allclose(crf, np.asarray(data.values).T, rtol=1e-14)
    peaks = grid[np.argmax(crf, axis=1)]
    assert peaks[0] > peaks[1] > peaks[2]  # R peaks at the longest wavelength, B at the shortest
    assert np.all(spectra.camera_response(np.array([300, 900]) * NM) == 0)  # nothing outside the data


def test_paper_chain_puts_each_channel_peak_in_its_own_band():
    sensitivity = paper_sensitivity()
    peaks = sensitivity.wavelengths_m[np.argmax(sensitivity.values, axis=1)]
    for peak, centre, width in zip(peaks, PAPER_CENTRES[::-1], PAPER_WIDTHS[::-1]):
        assert abs(peak - centre) <= width / 2


def test_sensitivity_refuses_a_dead_channel():
    grid = spectra.wavelength_grid()
    crf = spectra.camera_response(grid)
    crf[1] = 0
    with pytest.raises(InputError, match="channel G"):
        spectra.spectral_sensitivity(grid, crf)


# ---------------------------------------------------------------------------- quadrature


def test_quadrature_weights_sum_to_one_and_integrate_smooth_functions():
    sensitivity, _, _ = gaussian_sensitivity()
    nodes = np.arange(380, 781, 5) * NM
    quadrature = spectra.quadrature_weights(sensitivity, nodes)
    assert_allclose(quadrature.weights.sum(axis=1), 1, rtol=1e-13)  # normalised exactly
    assert np.all(quadrature.weights >= 0)
    grid = sensitivity.wavelengths_m
    for f in (lambda x: 1 + 3 * x / NM, lambda x: np.cos(x / (40 * NM))):
        exact = trapezoid(sensitivity.values * f(grid), grid) / trapezoid(sensitivity.values, grid)
        # Linear f: exact up to rounding. cos: the error of linear interpolation between
        # nodes h = 5 nm apart is at most h²/8·max|f''| = 25/8/1600 ≈ 2e-3, and averages to far
        # less; the reference itself is a 0.05 nm trapezoid (error ~1e-7).
        assert_allclose(quadrature.weights @ f(nodes), exact, atol=2e-3, rtol=1e-9)
    # Linear f is integrated exactly: weights reproduce the channel's mean wavelength.
    assert_allclose(quadrature.weights @ nodes, [620 * NM, 530 * NM, 460 * NM], rtol=1e-7)


def test_quadrature_reports_the_covered_fraction():
    sensitivity, centres, sigmas = gaussian_sensitivity()
    nodes = np.arange(430, 621, 5) * NM  # ends at R's centre: half of R, nearly all of G and B
    quadrature = spectra.quadrature_weights(sensitivity, nodes)

    def mass(a, b):
        return 0.5 * (erf((b - centres) / (sigmas * math.sqrt(2))) - erf((a - centres) / (sigmas * math.sqrt(2))))

    expected = mass(nodes[0], nodes[-1]) / mass(380 * NM, 780 * NM)
    # Gaussian masses; the 0.05 nm grid integrates them to ~1e-7.
    assert_allclose(quadrature.coverage, expected, atol=1e-6)


def test_quadrature_refuses_a_scan_that_misses_a_channel():
    grid = spectra.wavelength_grid()
    sigma = spectra.camera_response(grid, "Sigma SDMerill (NPL)")  # tabulated 400-680 nm only
    sensitivity = spectra.spectral_sensitivity(grid, sigma)
    with pytest.raises(InputError, match="channel R"):
        spectra.quadrature_weights(sensitivity, np.arange(690, 760, 5) * NM)


# ---------------------------------------------------------------------------- importance sampling


def test_importance_samples_are_reproducible_with_a_seed():
    sensitivity = paper_sensitivity()
    first = spectra.sample_wavelengths(sensitivity, 8, 1234)
    second = spectra.sample_wavelengths(sensitivity, 8, np.random.default_rng(1234))
    other = spectra.sample_wavelengths(sensitivity, 8, 1235)
    assert np.array_equal(first.wavelengths_m, second.wavelengths_m)
    assert not np.array_equal(first.wavelengths_m, other.wavelengths_m)
    assert first.wavelengths_m.shape == (24,)
    assert_allclose(first.weights.sum(axis=1), 1, rtol=1e-15)


def test_importance_samples_follow_the_sensitivity():
    sensitivity, centres, sigmas = gaussian_sensitivity()
    n = 64
    samples = spectra.sample_wavelengths(sensitivity, n, 7)
    for c in range(3):
        drawn = np.sort(samples.wavelengths_m[c * n : (c + 1) * n])
        assert np.all(samples.weights[c, c * n : (c + 1) * n] == 1 / n)
        cdf = 0.5 * (1 + erf((drawn - centres[c]) / (sigmas[c] * math.sqrt(2))))
        upper = np.arange(1, n + 1) / n
        ks = max(np.max(upper - cdf), np.max(cdf - (upper - 1 / n)))
        # Stratification puts exactly one sample in each 1/n quantile band, so the KS distance
        # is at most 1/n (an i.i.d. sample would only be below ~1.36/sqrt(n) = 0.17 at 95 %);
        # the grid's piecewise-linear CDF adds < 1e-6 with a 0.05 nm step.
        assert ks <= 1 / n + 1e-6


def test_importance_samples_of_the_paper_chain_stay_where_s_is_positive():
    sensitivity = paper_sensitivity()
    samples = spectra.sample_wavelengths(sensitivity, 200, 0)
    grid = sensitivity.wavelengths_m
    for c in range(3):
        drawn = samples.wavelengths_m[c * 200 : (c + 1) * 200]
        values = np.interp(drawn, grid, sensitivity.values[c])
        assert np.all(values > 0)


# ---------------------------------------------------------------------------- mixing


def test_mix_channels_is_linear_and_differentiable():
    generator = torch.Generator().manual_seed(0)
    psf = torch.rand(2, 5, 7, 7, generator=generator, dtype=torch.float64, requires_grad=True)
    weights = torch.rand(3, 5, generator=generator, dtype=torch.float64, requires_grad=True)
    mixed = spectra.mix_channels(psf, weights)
    assert mixed.shape == (2, 3, 7, 7)
    expected = (weights[None, :, :, None, None] * psf[:, None]).sum(dim=2)
    # float64 sums of five products: rounding only.
    assert_allclose(mixed.detach().numpy(), expected.detach().numpy(), rtol=1e-14)
    other = torch.rand(2, 5, 7, 7, generator=generator, dtype=torch.float64)
    linear = spectra.mix_channels(2 * psf + other, weights) - 2 * mixed - spectra.mix_channels(other, weights)
    assert_allclose(linear.detach().numpy(), 0, atol=1e-14)
    assert torch.autograd.gradcheck(spectra.mix_channels, (psf[:1, :, :3, :3], weights))


def test_mix_channels_accepts_numpy_weights_and_checks_shapes():
    psf = torch.ones(4, 3, 3, dtype=torch.float32)
    quadrature = spectra.quadrature_weights(gaussian_sensitivity()[0], np.linspace(400, 700, 4) * NM)
    mixed = spectra.mix_channels(psf, quadrature.weights)
    assert mixed.dtype == torch.float32
    assert_allclose(mixed.numpy(), 1, rtol=1e-6)  # weights sum to 1 per channel (float32 rounding)
    with pytest.raises(InputError, match="weights"):
        spectra.mix_channels(psf, np.ones((3, 5)))


def test_midpoint_quadrature_is_fixed_and_lies_at_the_strata_centres():
    """rng=None: λ at the (k + 0.5)/n quantiles of S^c, the same every call: against the
    Gaussians' exact quantiles (0.05 nm grid: the piecewise CDF is within 1e-3 nm of them)."""
    from scipy.special import erfinv

    sens, centres, sigmas = gaussian_sensitivity()
    a, b = spectra.sample_wavelengths(sens, 4, None), spectra.sample_wavelengths(sens, 4, None)
    np.testing.assert_array_equal(a.wavelengths_m, b.wavelengths_m)
    u = (np.arange(4) + 0.5) / 4
    for c in range(3):
        exact = centres[c] + sigmas[c] * math.sqrt(2) * erfinv(2 * u - 1)
        np.testing.assert_allclose(a.wavelengths_m[4 * c : 4 * c + 4], exact, rtol=0, atol=1e-3 * NM)


# ---------------------------------------------------------------------------- the filter in torch


def _torch_filter(centres_nm, widths_nm, edge_nm, peak=0.9):
    c = torch.tensor(centres_nm, dtype=torch.float64, requires_grad=True)
    w = torch.tensor(widths_nm, dtype=torch.float64, requires_grad=True)
    e = torch.tensor(edge_nm, dtype=torch.float64, requires_grad=True)
    return c, w, e, lambda grid_m: spectra.bandpass_transmission(grid_m, c * NM, w * NM, edge_width_m=e * NM, peak=peak)


@pytest.mark.parametrize("edge_nm", [1.0, 2.0, 6.0])
def test_torch_filter_meets_its_definition(edge_nm):
    # closed-form properties, not the numpy path: peak at the centre, half of it at c ± w/2,
    # 10 % and 90 % of the peak one edge width apart (for a band wide enough that its edges
    # do not touch)
    _, _, _, transmission = _torch_filter([457.0, 530.0, 628.0], [22.0, 20.0, 28.0], edge_nm)
    for c, w in zip((457.0, 530.0, 628.0), (22.0, 20.0, 28.0)):
        at = torch.tensor([c, c - w / 2, c + w / 2], dtype=torch.float64) * NM
        assert_allclose(transmission(at).detach().numpy(), [0.9, 0.45, 0.45], rtol=1e-9)
    grid = torch.linspace(600, 628, 280001, dtype=torch.float64) * NM  # R's rising edge, 0.1 pm steps
    t = transmission(grid).detach().numpy() / 0.9
    rise = grid.numpy()[np.searchsorted(t, 0.9)] - grid.numpy()[np.searchsorted(t, 0.1)]
    assert rise == pytest.approx(edge_nm * NM, abs=2e-13 + 0.01 * edge_nm * NM if edge_nm > 5 else 2e-13)


def test_torch_filter_gradients_match_finite_differences():
    c, w, e, _ = _torch_filter([457.0, 530.0, 628.0], [22.0, 20.0, 28.0], 2.0)
    grid = torch.linspace(430, 660, 461, dtype=torch.float64) * NM

    def t(c, w, e):
        return spectra.bandpass_transmission(grid, c * NM, w * NM, edge_width_m=e * NM, peak=0.9)

    assert torch.autograd.gradcheck(t, (c, w, e), eps=1e-6, atol=1e-7)


def test_torch_filter_equals_the_numpy_filter():
    grid = np.linspace(400, 700, 3001) * NM
    _, _, _, transmission = _torch_filter([457.0, 530.0, 628.0], [22.0, 20.0, 28.0], 2.0)
    expected = spectra.bandpass_transmission(grid, PAPER_CENTRES, PAPER_WIDTHS, edge_width_m=2 * NM, peak=0.9)
    assert_allclose(transmission(torch.from_numpy(grid)).detach().numpy(), expected, atol=1e-12)
