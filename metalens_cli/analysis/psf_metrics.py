"""Scalar summaries of sensor PSFs (numpy arrays, axis at pixel (N//2, N//2), values = power fractions)."""

from __future__ import annotations

import numpy as np


def central_energy(psf: np.ndarray, window: int = 5) -> np.ndarray:
    """Power in the central ``window`` × ``window`` pixels around (N//2, N//2); leading axes kept."""
    c, h = psf.shape[-1] // 2, window // 2
    return psf[..., c - h : c + h + 1, c - h : c + h + 1].sum(axis=(-2, -1))


def fwhm_pixels(row: np.ndarray) -> float | None:
    """Full width at half maximum (pixels) of a 1-D profile through its centre pixel N//2.

    Linear interpolation between pixel centres on each side of the centre; None when the
    profile does not fall to half its central value inside the window or peaks off-centre.
    """
    c = row.shape[0] // 2
    half = row[c] / 2
    if row[c] <= 0:
        return None

    def crossing(direction: int) -> float | None:
        i = c
        while 0 <= i + direction < row.shape[0]:
            j = i + direction
            if row[j] <= half:
                return i + direction * (row[i] - half) / (row[i] - row[j])
            i = j
        return None

    left, right = crossing(-1), crossing(+1)
    return None if left is None or right is None else float(right - left)


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
