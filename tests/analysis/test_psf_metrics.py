"""FWHM of sampled profiles against the closed form of a pixel-integrated Gaussian."""

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import ndtr

from metalens_cli.analysis.psf_metrics import fwhm_pixels


def box_gaussian(x, sigma):
    """A unit Gaussian of σ integrated over a pixel of width 1 centred at x (the sampled value)."""
    return ndtr((x + 0.5) / sigma) - ndtr((x - 0.5) / sigma)


@pytest.mark.parametrize("sigma", [1.5, 2.0, 4.0])
@pytest.mark.parametrize("offset", [0.0, 0.15, 0.3, 0.5])
def test_fwhm_of_a_pixel_integrated_gaussian_within_04_percent(sigma, offset):
    """The continuous profile a pixel records, box_gaussian(x − offset), has its half maximum
    where box_gaussian(x) = box_gaussian(0)/2 (found by root finding, not sampled)."""
    half = box_gaussian(0.0, sigma) / 2
    truth = 2 * brentq(lambda x: box_gaussian(x, sigma) - half, 0.0, 10 * sigma)
    row = box_gaussian(np.arange(61) - 30 - offset, sigma)
    assert fwhm_pixels(row) == pytest.approx(truth, rel=4e-3)


def test_no_width_without_light_at_the_centre_or_a_half_maximum_inside():
    x = np.arange(41) - 20.0
    assert fwhm_pixels(np.exp(-0.5 * (x / 40) ** 2)) is None  # wider than the window
    assert fwhm_pixels(np.zeros(41)) is None
    assert fwhm_pixels(np.exp(-0.5 * ((x - 10) / 2) ** 2) * (np.abs(x) > 0)) is None  # nothing at the centre
