"""Statistics that tell a photograph from a synthetic scene: spectrum slope, colour, edges.

Inputs are linear RGB (3, H, W) float arrays in 0..1. Each statistic is a plain number so that
sets of scenes can be compared by their means (``summarise``):

- ``spectrum_slope``: the slope of log power against log spatial frequency of the linear
  luminance (Hann-windowed, radially averaged over 4-64 cycles per image width of a square
  crop); natural images give about −2 (Field 1987; van der Schaaf & van Hateren 1996).
- ``luminance_median`` and ``log_luminance_std``: the median of linear luminance and the standard
  deviation of its log10 (floored at ``DARK``): photographs are dark-heavy with a wide range.
- ``saturation``: the mean HSV saturation (max − min)/max of the sRGB-encoded colours.
- ``edge_density``: the fraction of pixels whose sRGB-encoded luminance changes by more than
  ``EDGE_STEP`` per pixel (Sobel gradient / 8).
"""

from __future__ import annotations

import numpy as np

from metalens_cli.imaging.images import luminance
from metalens_cli.io.image_files import linear_to_srgb

STATISTICS = ("spectrum_slope", "luminance_median", "log_luminance_std", "saturation", "edge_density")
DARK = 1e-3  # linear luminance floor of the log statistics
EDGE_STEP = 0.04  # sRGB levels (0..1) per pixel: ≈ 10 of 255
SLOPE_BAND = (4, 64)  # cycles per image width over which the power law is fitted


def spectrum_slope(image: np.ndarray) -> float:
    """Slope of log P(f) against log f, P the radially averaged power of the luminance of the
    central square crop (side ≥ 2·SLOPE_BAND[1]), mean removed, Hann window."""
    y = luminance(np.asarray(image, dtype=np.float64))
    n = min(y.shape)
    if n < 2 * SLOPE_BAND[1]:
        raise ValueError(f"spectrum_slope needs at least {2 * SLOPE_BAND[1]} pixels per side, got {n}")
    top, left = (y.shape[0] - n) // 2, (y.shape[1] - n) // 2
    y = y[top : top + n, left : left + n]
    window = np.outer(np.hanning(n), np.hanning(n))
    power = np.abs(np.fft.fftshift(np.fft.fft2((y - y.mean()) * window))) ** 2
    k = np.arange(n) - n // 2
    radius = np.rint(np.hypot(*np.meshgrid(k, k, indexing="ij"))).astype(int)
    radial = np.bincount(radius.ravel(), power.ravel()) / np.bincount(radius.ravel())
    f = np.arange(SLOPE_BAND[0], SLOPE_BAND[1] + 1)
    return float(np.polyfit(np.log(f), np.log(radial[f] + 1e-30), 1)[0])


def scene_statistics(image: np.ndarray) -> dict[str, float]:
    """The :data:`STATISTICS` of one linear RGB image (3, H, W)."""
    import cv2

    image = np.asarray(image, dtype=np.float32)
    y = luminance(image)
    srgb = linear_to_srgb(image)
    top, bottom = srgb.max(axis=0), srgb.min(axis=0)
    saturation = np.where(top > 0, (top - bottom) / np.maximum(top, 1e-6), 0.0)
    y_srgb = linear_to_srgb(y)
    gx, gy = cv2.Sobel(y_srgb, cv2.CV_32F, 1, 0) / 8, cv2.Sobel(y_srgb, cv2.CV_32F, 0, 1) / 8
    return {
        "spectrum_slope": spectrum_slope(image),
        "luminance_median": float(np.median(y)),
        "log_luminance_std": float(np.log10(np.maximum(y, DARK)).std()),
        "saturation": float(saturation.mean()),
        "edge_density": float((np.hypot(gx, gy) > EDGE_STEP).mean()),
    }


def summarise(images) -> dict[str, dict[str, float]]:
    """Mean, standard deviation, min and max of each statistic over ``images`` (linear RGB arrays)."""
    values = {name: [] for name in STATISTICS}
    for image in images:
        for name, value in scene_statistics(image).items():
            values[name].append(value)
    return {
        name: {"mean": float(np.mean(v)), "std": float(np.std(v)), "min": float(np.min(v)), "max": float(np.max(v))}
        for name, v in values.items()
    }
