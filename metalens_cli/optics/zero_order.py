"""The lens's zero-order light: what the nanofins do not convert, and where it lands.

A geometric-phase nanofin converts a fraction η(λ) of circularly polarised light into the opposite
hand with the phase 2θ (the focused light); the rest, 1 − η, leaves co-polarised with one phase
for every rotation θ, as if the lens were a clear aperture. A circular analyzer behind the lens
passes a fraction ``leak`` of it (its extinction). That light is not focused: from a point
source at depth z it fills the cone through the aperture, a uniform disc on the sensor plane at d
of radius a·(1 + d/z) centred on the chief ray (the geometric shadow of the aperture; the
Fresnel number a²/(λd) ≈ 750 for the paper's lens, so its diffraction edge is a few pixels of a
disc 1360 px across). Lengths in SI metres; windows are odd N × N with the axis at (N//2, N//2).
"""

from __future__ import annotations

import math

import numpy as np

EDGE_SUBSAMPLES = 8  # per axis: pixels the disc's edge crosses are integrated on an 8 × 8 grid


def zero_order_radius_m(aperture_m: float, distance_m: float, depth_m: float) -> float:
    """Radius (m) of the zero-order disc of a source at ``depth_m`` (inf: a plane wave) on the
    plane at ``distance_m`` behind an aperture of diameter ``aperture_m``: a·(1 + d/z)."""
    return 0.5 * aperture_m * (1.0 + (0.0 if math.isinf(depth_m) else distance_m / depth_m))


def zero_order_psf(aperture_m: float, distance_m: float, depth_m: float, pixel_pitch_m: float) -> np.ndarray:
    """(N, N) float64 unit-sum PSF of the zero-order light: each pixel holds the fraction of the
    disc (:func:`zero_order_radius_m`) it covers, exactly inside and outside the disc and on an
    ``EDGE_SUBSAMPLES``² grid where the edge crosses it; N = 2⌈R/pitch⌉ + 1."""
    radius = zero_order_radius_m(aperture_m, distance_m, depth_m) / pixel_pitch_m
    half = math.ceil(radius)
    axis = np.arange(-half, half + 1, dtype=float)
    r = np.hypot(axis[:, None], axis[None, :])
    psf = (r + math.sqrt(0.5) <= radius).astype(float)
    edge = np.nonzero(np.abs(r - radius) < math.sqrt(0.5))
    offsets = (np.arange(EDGE_SUBSAMPLES) + 0.5) / EDGE_SUBSAMPLES - 0.5
    sy, sx = np.meshgrid(offsets, offsets, indexing="ij")
    ys, xs = axis[edge[0], None, None] + sy, axis[edge[1], None, None] + sx
    psf[edge] = np.mean(np.hypot(ys, xs) <= radius, axis=(1, 2))
    return psf / psf.sum()
