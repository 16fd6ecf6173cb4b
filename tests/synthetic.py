"""Synthetic test images shared by several test modules (on sys.path via pytest's `pythonpath`)."""

import math

import numpy as np
from scipy.special import ndtr

DARK, BRIGHT = 0.2, 0.8


def render_edge(height: int, width: int, tilt_deg: float, sigma_px: float, supersampling: int = 8) -> np.ndarray:
    """A straight edge through the image centre, tilted ``tilt_deg`` from vertical, blurred by a
    Gaussian of σ pixels (the blurred step is Φ(distance/σ)) and integrated over square pixels
    by supersampling^2 midpoint samples (error ~1e-5 for σ ≥ 0.8 px)."""
    theta = math.radians(tilt_deg)
    offsets = (np.arange(supersampling) + 0.5) / supersampling - 0.5
    y = np.arange(height)[:, None, None, None] + offsets[None, None, :, None]
    x = np.arange(width)[None, :, None, None] + offsets[None, None, None, :]
    distance = (x - (width - 1) / 2) * math.cos(theta) - (y - (height - 1) / 2) * math.sin(theta)
    return DARK + (BRIGHT - DARK) * ndtr(distance / sigma_px).mean(axis=(2, 3))


def gaussian_spot(height: int, width: int, centre: tuple[float, float], sigma_px: float) -> np.ndarray:
    """A unit-energy Gaussian spot of σ pixels centred at (row, column) ``centre``, integrated
    exactly over square pixels (pixel (i, j) covers [i − ½, i + ½] × [j − ½, j + ½])."""
    rows = np.arange(height + 1) - 0.5 - centre[0]
    cols = np.arange(width + 1) - 0.5 - centre[1]
    return np.outer(np.diff(ndtr(rows / sigma_px)), np.diff(ndtr(cols / sigma_px)))


def bench_frame(spot: np.ndarray, rng: np.random.Generator, photons: float = 1.2e6, dark_level: float = 600.0,
                read_noise: float = 4.0, background: float = 30.0) -> np.ndarray:
    """A 16-bit camera frame of a spot (unit energy): Poisson photons, a dark offset, a flat
    background and Gaussian read noise, clipped to 0..65535 like the camera does."""
    signal = rng.poisson(photons * spot + background) + dark_level + rng.normal(0, read_noise, spot.shape)
    return np.clip(np.rint(signal), 0, 65535).astype(np.uint16)
