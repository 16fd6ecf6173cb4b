"""Clean training scenes for the optimiser, drawn afresh at every step from (seed, step, index).

With a folder of images (``optimize.images``): a random crop (half to full of the shorter side),
resized to the sensor and randomly flipped. Without one: procedural scenes that need no download,
a sum of random coloured fractal-noise layers, rectangles, discs and bar gratings, so that every
spatial frequency up to Nyquist is present. Linear RGB in 0..1, (3, H, W) float32.

The built-in evaluation images (``imaging.images.builtin_images``) are never used for training:
they stay held out.
"""

from __future__ import annotations

import numpy as np

from metalens_cli.imaging.noise import fractal_noise


def procedural_scene(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """One random linear-RGB scene (3, H, W) in 0.02..1."""
    h, w = shape
    y, x = (np.mgrid[0:h, 0:w] / max(h, w)).astype(np.float32)
    base = rng.uniform(0.1, 0.6, size=(3, 1, 1)).astype(np.float32)
    noise = np.stack([fractal_noise((h, w), max(h, w) / rng.uniform(2, 8), 4, rng) for _ in range(3)])
    image = base + rng.uniform(0.1, 0.4) * noise
    for _ in range(rng.integers(3, 9)):
        colour = rng.uniform(0.0, 1.0, size=(3, 1, 1))
        kind = rng.integers(3)
        cx, cy, size = rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0.05, 0.4)
        if kind == 0:
            inside = (np.abs(x - cx) < size / 2) & (np.abs(y - cy) < rng.uniform(0.3, 1.0) * size / 2)
        elif kind == 1:
            inside = np.hypot(x - cx, y - cy) < size / 2
        else:
            angle, period = rng.uniform(0, np.pi), rng.uniform(2.0, 12.0) / max(h, w)
            bars = np.sin(2 * np.pi * (x * np.cos(angle) + y * np.sin(angle)) / period) > 0
            inside = bars & (np.hypot(x - cx, y - cy) < size)
        image[:, inside] = colour[:, :, 0]
    return np.clip(image, 0.02, 1.0).astype(np.float32)


def random_crop(image: np.ndarray, shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A random square-ish crop of a (3, H0, W0) image resized to ``shape``, randomly flipped."""
    import cv2

    _, h0, w0 = image.shape
    side = int(rng.uniform(0.5, 1.0) * min(h0, w0))
    top, left = rng.integers(0, h0 - side + 1), rng.integers(0, w0 - side + 1)
    crop = np.transpose(image[:, top:top + side, left:left + side], (1, 2, 0))
    crop = cv2.resize(crop, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    crop = np.transpose(crop, (2, 0, 1))
    if rng.random() < 0.5:
        crop = crop[:, :, ::-1]
    return np.ascontiguousarray(crop, dtype=np.float32)


def training_scene(shape: tuple[int, int], seed: int, step: int, index: int, pool: list[np.ndarray] | None = None) -> np.ndarray:
    """The clean scene number ``index`` of step ``step``: the same (seed, step, index), the same scene."""
    rng = np.random.default_rng([seed, step, index, 11])
    if pool:
        return random_crop(pool[rng.integers(len(pool))], shape, rng)
    return procedural_scene(shape, rng)
