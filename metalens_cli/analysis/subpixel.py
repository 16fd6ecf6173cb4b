"""Sub-pixel operations on sampled images: a shift by a phase ramp and a three-point peak."""

from __future__ import annotations

import numpy as np


def fourier_shift(image: np.ndarray, dy: float, dx: float) -> np.ndarray:
    """``image`` (H, W) moved by (dy, dx) pixels (content at p goes to p + d) with a phase ramp
    in its DFT: exact for a band-limited image; content moved past one edge wraps to the other,
    so the image should be dark near its edges. Real input, real output (float64)."""
    if dy == 0 and dx == 0:
        return np.asarray(image, dtype=np.float64)
    ky = np.fft.fftfreq(image.shape[0])[:, None]
    kx = np.fft.fftfreq(image.shape[1])[None, :]
    return np.real(np.fft.ifft2(np.fft.fft2(image) * np.exp(-2j * np.pi * (ky * dy + kx * dx))))


def parabola_vertex(before: float, peak: float, after: float) -> float:
    """Offset (−½ … ½ samples) of the vertex of the parabola through three equally spaced
    samples around a maximum ``peak``; 0 where they do not curve downwards."""
    curvature = before - 2 * peak + after
    return 0.0 if curvature >= 0 else float(np.clip(0.5 * (before - after) / curvature, -0.5, 0.5))
