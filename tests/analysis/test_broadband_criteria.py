"""The broadband baseline's criteria (analysis.broadband_criteria): the verdicts at their
thresholds, the channel MTF against a closed form, and the hyperbolic lens judged by propagation."""

import json
import math

import numpy as np
import pytest
from scipy.special import ndtr

from metalens_cli.analysis import broadband_criteria as bc
from metalens_cli.errors import InputError
from metalens_cli.optics.lens import hyperbolic
from metalens_cli.optics.sampling import PsfGrid
from metalens_cli.optics.spectra import camera_response, spectral_sensitivity, wavelength_grid

PIXEL_M = 1.85e-6


def spectrum(core, mtf=(0.1, 0.1, 0.1)) -> bc.FarSpectrum:
    waves = bc.band_grid()
    core = np.broadcast_to(core, waves.shape).astype(float)
    return bc.FarSpectrum(waves, core, np.array(mtf), np.ones(3), np.ones(3))


def test_each_criterion_meets_its_threshold_and_fails_below_it():
    waves = bc.band_grid()
    core = np.where(waves < waves[round(bc.COVERAGE_SHARE * waves.size)], 0.03, 0.01)  # the first 80 % covered
    met = bc.judge(spectrum(core, (bc.BALANCE_LEVEL, 0.2, 0.3)), np.mean(core) / bc.MEAN_RATIO)
    assert met.coverage.value == pytest.approx(bc.COVERAGE_SHARE, abs=1 / waves.size) and met.coverage.passed
    assert met.band_mean.value == pytest.approx(bc.MEAN_RATIO) and met.band_mean.passed
    assert met.colour_balance.value == bc.BALANCE_LEVEL and met.colour_balance.passed
    assert met.recoverable.passed is None and met.passed is None  # not judged until the caller fills it

    core[np.flatnonzero(core > bc.COVERAGE_LEVEL)[-2:]] = 0.9 * bc.COVERAGE_LEVEL  # two wavelengths fewer
    failed = bc.judge(spectrum(core, (0.2, 0.9 * bc.BALANCE_LEVEL, 0.3)), np.mean(core) / (0.9 * bc.MEAN_RATIO))
    assert not failed.coverage.passed and not failed.band_mean.passed and not failed.colour_balance.passed
    assert failed.passed is False and "(G)" in failed.colour_balance.meaning


def test_recoverable_quality_is_met_when_one_row_has_its_interval_above_zero():
    judged = bc.judge(spectrum(0.05), 0.04)
    met = judged.with_recoverable({"wiener": (0.4, 0.2, 0.6), "recon": (0.1, -0.1, 0.3)})
    assert met.recoverable.passed and met.recoverable.value == 0.2 and met.passed
    missed = judged.with_recoverable({"wiener": (0.1, -0.05, 0.25)})
    assert missed.recoverable.passed is False and missed.passed is False
    json.dumps(met.report())  # JSON-ready
    with pytest.raises(InputError):
        judged.with_recoverable({})


def test_channel_mtf_of_a_pixel_integrated_gaussian_matches_its_closed_form():
    sigma, n = 20e-6, 401
    x = (np.arange(n) - n // 2) * PIXEL_M
    line = ndtr((x + PIXEL_M / 2) / sigma) - ndtr((x - PIXEL_M / 2) / sigma)
    psfs = np.stack([np.outer(line, line) * w for w in (1.0, 0.5, 0.2)])  # the scale does not matter
    nu = bc.BALANCE_LPMM * 1e3  # cycles/m
    # Gaussian OTF × the ring average of the pixel's sinc·sinc, 1 − (πνp)²/6 to second order
    expected = math.exp(-2 * (math.pi * sigma * nu) ** 2) * (1 - (math.pi * nu * PIXEL_M) ** 2 / 6)
    assert bc.channel_mtf(psfs, PIXEL_M) == pytest.approx(np.full(3, expected), abs=5e-4)
    # a window of ±5σ (109 px), too small to resolve 10 lp/mm, is padded: the same curve
    assert bc.channel_mtf(psfs[:, 146:255, 146:255], PIXEL_M) == pytest.approx(np.full(3, expected), abs=5e-4)


def test_psfs_must_hold_the_whole_band_at_1nm():
    waves = wavelength_grid(430e-9, 650e-9, 2e-9)
    sensitivity = spectral_sensitivity(waves, np.ones((3, waves.size)))
    with pytest.raises(InputError, match="1 nm"):
        bc.spectrum_from_psfs(np.ones((waves.size, 301, 301)), waves, PIXEL_M, sensitivity)


@pytest.fixture(scope="module")
def camera():
    """A broadband camera over 400-700 nm: the default colour camera's response, no filter, η = 1."""
    waves = wavelength_grid(400e-9, 700e-9, 1e-9)
    return spectral_sensitivity(waves, camera_response(waves))


def test_the_hyperbolic_lens_is_sharp_only_near_its_design_wavelength(camera):
    lens = hyperbolic(bc.REFERENCE_WAVELENGTH_M, 4e-3, 2.516e-3, 395e-9)  # the paper's lens
    far = bc.far_spectrum(lens, 4e-3, PIXEL_M, camera, capacity=601)
    judged = bc.judge(far, far.band_mean)
    assert judged.coverage.passed is False and judged.coverage.value < bc.COVERAGE_SHARE / 2
    covered = far.wavelengths_m[far.core >= bc.COVERAGE_LEVEL]
    assert np.all(np.abs(covered - bc.REFERENCE_WAVELENGTH_M) < 40e-9)
    assert judged.band_mean.passed  # its own reference
    # green holds the sharp wavelengths; the other channels are blurred by the chromatic focal shift
    mtf = dict(zip("RGB", far.channel_mtf))
    assert mtf["G"] > bc.BALANCE_LEVEL and mtf["G"] > 2 * max(mtf["R"], mtf["B"])
    assert np.all(far.channel_held > 0.998) and far.channel_coverage == pytest.approx(1)


def test_given_psfs_give_what_the_lens_gives(camera):
    """The two entry points on a small lens (f = 1 mm, D = 0.3 mm): cores alike, MTFs within the
    ring interpolation of windows of different sizes."""
    from metalens_cli.optics.psf import compute_psf

    lens = hyperbolic(bc.REFERENCE_WAVELENGTH_M, 1e-3, 0.3e-3, 395e-9)
    from_lens = bc.far_spectrum(lens, 1e-3, PIXEL_M, camera, capacity=301)
    waves = camera.wavelengths_m
    psfs = compute_psf(lens, PsfGrid(waves, [math.inf], 221, PIXEL_M)).psf[0].double().numpy()
    from_psfs = bc.spectrum_from_psfs(psfs, waves, PIXEL_M, camera)
    assert from_psfs.core == pytest.approx(from_lens.core, abs=2e-5)
    assert from_psfs.channel_mtf == pytest.approx(from_lens.channel_mtf, abs=1e-3)
