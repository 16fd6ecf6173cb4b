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


def bench_frame(
    spot: np.ndarray,
    rng: np.random.Generator,
    photons: float = 1.2e6,
    dark_level: float = 600.0,
    read_noise: float = 4.0,
    background: float = 30.0,
) -> np.ndarray:
    """A 16-bit camera frame of a spot (unit energy): Poisson photons, a dark offset, a flat
    background and Gaussian read noise, clipped to 0..65535 like the camera does."""
    signal = rng.poisson(photons * spot + background) + dark_level + rng.normal(0, read_noise, spot.shape)
    return np.clip(np.rint(signal), 0, 65535).astype(np.uint16)


def texture(height: int, width: int, seed: int) -> np.ndarray:
    """A (H, W, 3) linear RGB test scene in 0.05..0.95: multi-scale smoothed noise (structure at
    2-32 pixels, so features and optical flow have something to hold) with random colour."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    scene = np.zeros((height, width, 3))
    for sigma in (2, 4, 8, 16, 32):
        layer = gaussian_filter(rng.normal(size=(height, width)), sigma)
        scene += (layer / layer.std())[:, :, None] * rng.uniform(0.3, 1.0, 3)
    scene -= scene.min()
    return (0.05 + 0.9 * scene / scene.max()).astype(np.float32)


def warp(
    image: np.ndarray, homography: np.ndarray, ripple_px: float = 0.0, size: tuple[int, int] | None = None
) -> np.ndarray:
    """``image`` (H, W, C) seen through a camera: output pixel (x, y) samples the image at
    H·(x, y, 1) plus a smooth ripple of ``ripple_px`` pixels (a lens distortion stand-in)."""
    import cv2

    h, w = size or image.shape[:2]
    y, x = np.mgrid[:h, :w].astype(np.float64)
    u = homography[0, 0] * x + homography[0, 1] * y + homography[0, 2]
    v = homography[1, 0] * x + homography[1, 1] * y + homography[1, 2]
    s = homography[2, 0] * x + homography[2, 1] * y + homography[2, 2]
    u, v = u / s, v / s
    u += ripple_px * np.sin(2 * np.pi * y / h) * np.cos(np.pi * x / w)
    v += ripple_px * np.cos(2 * np.pi * x / w) * np.sin(np.pi * y / h)
    return cv2.remap(image, u.astype(np.float32), v.astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def save_png(path, image: np.ndarray, bits: int = 8) -> None:
    """Write an (H, W) or (H, W, 3) RGB image of 0..1 values as an 8- or 16-bit PNG, making its folder."""
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    top = 255 if bits == 8 else 65535
    pixels = np.round(np.clip(image, 0, 1) * top).astype(np.uint8 if bits == 8 else np.uint16)
    cv2.imwrite(str(path), pixels[:, :, ::-1] if pixels.ndim == 3 else pixels)
