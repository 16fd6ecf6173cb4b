"""Gradient (Perlin) noise and its fractal sums, for procedural scenes and obstructions.

Arrays are float64 (H, W), seeded through a ``numpy.random.Generator``; lengths in pixels.
"""

from __future__ import annotations

import math

import numpy as np


def perlin(
    shape: tuple[int, int],
    cell_px: float,
    rng: np.random.Generator,
    at: list[tuple[np.ndarray, np.ndarray]] | None = None,
) -> np.ndarray | list[np.ndarray]:
    """Gradient (Perlin) noise with lattice spacing ``cell_px`` pixels, values about in [-1, 1],
    on an H × W ``shape``: at every pixel, or one array per (rows, columns) pair of ``at`` (pixel
    coordinates in 0..H−1, 0..W−1), all on the same lattice (the same noise where they are pixels)."""
    h, w = shape
    cell = max(float(cell_px), 1.0)
    gh, gw = int(math.ceil(h / cell)) + 2, int(math.ceil(w / cell)) + 2
    angles = rng.uniform(0, 2 * math.pi, size=(gh, gw))
    gx, gy = np.cos(angles).astype(np.float32), np.sin(angles).astype(np.float32)
    offset = rng.uniform(0, 1, size=2)
    if at is None:
        return _gradient_noise(gx, gy, np.arange(h) / cell + offset[0], np.arange(w) / cell + offset[1])
    return [
        _gradient_noise(gx, gy, *(np.asarray(a, np.float64) / cell + o for a, o in zip(pair, offset))) for pair in at
    ]


def _gradient_noise(gx: np.ndarray, gy: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Perlin noise (len(y), len(x)) of the lattice gradients (gx, gy) at rows ``y`` × columns
    ``x`` in lattice cells."""
    y, x = y[:, None], x[None, :]
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = (y - y0).astype(np.float32), (x - x0).astype(np.float32)  # float32: noise, not physics

    def fade(t):
        return t * t * t * (t * (t * 6 - 15) + 10)

    # n = Σ_{dy,dx} w_dy(y)·w_dx(x)·g[y0 + dy, x0 + dx]·(x − dx, y − dy) with w_0 = 1 − fade, w_1 = fade:
    # the sum over dx runs on the lattice rows first (gh × W), the sum over dy then gathers whole rows
    u, v = fade(fx), fade(fy)
    cols = [x0[0] + dx for dx in (0, 1)]
    along = gx[:, cols[0]] * ((1 - u) * fx) + gx[:, cols[1]] * (u * (fx - 1))
    across = gy[:, cols[0]] * (1 - u) + gy[:, cols[1]] * u
    rows = [y0[:, 0] + dy for dy in (0, 1)]
    total = along[rows[0]] * (1 - v) + across[rows[0]] * ((1 - v) * fy)
    total += along[rows[1]] * v + across[rows[1]] * (v * (fy - 1))
    return total * math.sqrt(2)


SAMPLES_PER_CELL = 4  # the finest octave is evaluated at ≥ 4 samples per lattice cell, then resized
NORM_STRIDE = 8  # sampled_fractal_noise: normalised by its largest |·| on every 8th pixel per axis


def fractal_noise(
    shape: tuple[int, int],
    cell_px: float,
    octaves: int,
    rng: np.random.Generator,
    at: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Sum of Perlin octaves, each half the cell size and half the amplitude, normalised to max |·| 1.

    The sum is smooth on the scale of its finest cell, so it is evaluated on a grid coarser by
    s = ⌊finest cell / ``SAMPLES_PER_CELL``⌋ and resized to ``shape`` bilinearly (s² times fewer
    Perlin evaluations; s = 1 when the finest cell is under 8 pixels). With ``at`` (rows, columns
    in pixels, ``imaging.sample_grid``): :func:`sampled_fractal_noise` there.
    """
    import cv2

    if at is not None:
        return sampled_fractal_noise(shape, cell_px, octaves, rng, at)[0]
    h, w = shape
    step = max(int(cell_px / 2 ** (octaves - 1) / SAMPLES_PER_CELL), 1)
    coarse = (-(-h // step) + 1, -(-w // step) + 1)
    total = np.zeros(coarse, dtype=np.float32)
    for k in range(octaves):
        total += 0.5**k * perlin(coarse, cell_px / 2**k / step, rng)
    if step > 1:
        # to (c − 1)·step + 1 pixels; OpenCV's half-pixel convention puts coarse sample i within (step − 1)/2 pixels
        # of pixel i·step (at i·step exactly: design.device_scenes.fractal)
        total = cv2.resize(
            total, ((coarse[1] - 1) * step + 1, (coarse[0] - 1) * step + 1), interpolation=cv2.INTER_LINEAR
        )
    total = total[:h, :w]
    return total / max(np.abs(total).max(), 1e-12)


def sampled_fractal_noise(
    shape: tuple[int, int], cell_px: float, octaves: int, rng: np.random.Generator, at: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fractal_noise`'s octaves (the same random draws) evaluated exactly at the rows ×
    columns ``at`` (pixels) and on every ``NORM_STRIDE``-th pixel of each axis, both normalised by
    the largest |·| of the latter: whatever the samples, a pixel has the same value. Returns
    (values at ``at``, the uniform sample)."""
    h, w = shape
    step = max(int(cell_px / 2 ** (octaves - 1) / SAMPLES_PER_CELL), 1)
    coarse = (-(-h // step) + 1, -(-w // step) + 1)
    grids = [
        tuple(np.asarray(a, np.float64) / step for a in at),
        (np.arange(0, h, NORM_STRIDE) / step, np.arange(0, w, NORM_STRIDE) / step),
    ]
    total, uniform = (np.zeros((len(r), len(c)), dtype=np.float32) for r, c in grids)
    for k in range(octaves):
        values, sample = perlin(coarse, cell_px / 2**k / step, rng, at=grids)
        total += 0.5**k * values
        uniform += 0.5**k * sample
    norm = max(float(np.abs(uniform).max()), 1e-12)
    return total / norm, uniform / norm
