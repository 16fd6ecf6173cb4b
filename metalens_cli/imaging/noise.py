"""Gradient (Perlin) noise and its fractal sums, for procedural scenes and obstructions.

Arrays are float64 (H, W), seeded through a ``numpy.random.Generator``; lengths in pixels.
"""

from __future__ import annotations

import math

import numpy as np


def perlin(shape: tuple[int, int], cell_px: float, rng: np.random.Generator) -> np.ndarray:
    """Gradient (Perlin) noise with lattice spacing ``cell_px`` pixels, values about in [-1, 1]."""
    h, w = shape
    cell = max(float(cell_px), 1.0)
    gh, gw = int(math.ceil(h / cell)) + 2, int(math.ceil(w / cell)) + 2
    angles = rng.uniform(0, 2 * math.pi, size=(gh, gw))
    gx, gy = np.cos(angles).astype(np.float32), np.sin(angles).astype(np.float32)
    offset = rng.uniform(0, 1, size=2)
    y = np.arange(h)[:, None] / cell + offset[0]
    x = np.arange(w)[None, :] / cell + offset[1]
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


def fractal_noise(shape: tuple[int, int], cell_px: float, octaves: int, rng: np.random.Generator) -> np.ndarray:
    """Sum of Perlin octaves, each half the cell size and half the amplitude, normalised to max |·| 1.

    The sum is smooth on the scale of its finest cell, so it is evaluated on a grid coarser by
    s = ⌊finest cell / ``SAMPLES_PER_CELL``⌋ and resized to ``shape`` bilinearly (s² times fewer
    Perlin evaluations; s = 1 when the finest cell is under 8 pixels).
    """
    import cv2

    h, w = shape
    step = max(int(cell_px / 2 ** (octaves - 1) / SAMPLES_PER_CELL), 1)
    coarse = (-(-h // step) + 1, -(-w // step) + 1)
    total = np.zeros(coarse, dtype=np.float32)
    for k in range(octaves):
        total += 0.5**k * perlin(coarse, cell_px / 2**k / step, rng)
    if step > 1:
        # corner-aligned resize: coarse sample i sits at pixel i·step
        total = cv2.resize(
            total, ((coarse[1] - 1) * step + 1, (coarse[0] - 1) * step + 1), interpolation=cv2.INTER_LINEAR
        )
    total = total[:h, :w]
    return total / max(np.abs(total).max(), 1e-12)
