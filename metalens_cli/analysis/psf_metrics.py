"""Scalar summaries of sensor PSFs (numpy arrays, axis at pixel (N//2, N//2), values = power fractions)."""

from __future__ import annotations

import numpy as np

SPLINE_MARGIN = 4  # samples beyond the half-maximum crossings in the spline (its end effects fade ×0.27 a sample)


def central_energy(psf: np.ndarray, window: int = 5) -> np.ndarray:
    """Power in the central ``window`` × ``window`` pixels around (N//2, N//2); leading axes kept."""
    c, h = psf.shape[-1] // 2, window // 2
    return psf[..., c - h : c + h + 1, c - h : c + h + 1].sum(axis=(-2, -1))


def fwhm_pixels(row: np.ndarray) -> float | None:
    """Full width at half maximum (pixels) of a 1-D profile through its centre pixel N//2.

    A cubic spline through the samples; its maximum within a pixel of the centre; the nearest
    half-maximum crossings on each side. A pixel-integrated Gaussian of σ ≥ 1.5 px comes out
    within 0.4 % of its FWHM at any sub-pixel offset (linear interpolation between samples,
    from the centre sample: up to 2.7 % wide); below, a profile sampled this coarsely has no
    well-defined width (σ = 0.7 px: up to 12 %). None when the profile does not fall to half
    its maximum inside the window on both sides, or has no light at the centre.
    """
    from scipy.interpolate import CubicSpline

    row = np.asarray(row, dtype=np.float64)
    c = row.shape[0] // 2
    if row[c] <= 0:
        return None
    below = np.flatnonzero(row < 0.45 * row[max(c - 1, 0) : c + 2].max())  # under any half maximum the spline can have
    left, right = below[below < c], below[below > c]
    if not left.size or not right.size:
        return None
    lo, hi = (
        max(left[-1] - SPLINE_MARGIN, 0),
        min(right[0] + SPLINE_MARGIN, row.shape[0] - 1),
    )  # a spline of the light only
    spline = CubicSpline(np.arange(lo, hi + 1), row[lo : hi + 1])
    stationary = spline.derivative().roots(extrapolate=False)
    candidates = np.concatenate([[c], stationary[np.abs(stationary - c) <= 1]])
    top = candidates[int(np.argmax(spline(candidates)))]
    crossings = spline.solve(float(spline(top)) / 2, extrapolate=False)
    left, right = crossings[crossings < top], crossings[crossings > top]
    return None if not left.size or not right.size else float(right.min() - left.max())


def summarize(psf: np.ndarray, pixel_pitch_m: float) -> dict:
    """Peak, energy in the window, energy in the central 5 × 5 pixels, FWHM (m) of one N × N PSF."""
    c = psf.shape[-1] // 2
    fwhm = fwhm_pixels(psf[c])
    return {
        "peak": float(psf.max()),
        "energy_in_window": float(psf.sum()),
        "energy_center_5x5": float(central_energy(psf, 5)),
        "fwhm_m": None if fwhm is None else fwhm * pixel_pitch_m,
    }
