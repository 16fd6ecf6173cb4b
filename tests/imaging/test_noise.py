"""Perlin noise against the textbook definition, evaluated pixel by pixel."""

from __future__ import annotations

import math

import numpy as np
from numpy.testing import assert_allclose

from metalens_cli.imaging.noise import fractal_noise, perlin


def _perlin_by_pixel(shape, cell, rng):
    """Ken Perlin's gradient noise at each pixel from its cell's four corners (the same draws)."""
    h, w = shape
    gh, gw = math.ceil(h / cell) + 2, math.ceil(w / cell) + 2
    angles = rng.uniform(0, 2 * math.pi, size=(gh, gw))
    offset = rng.uniform(0, 1, size=2)
    out = np.empty(shape)
    for i in range(h):
        for j in range(w):
            y, x = i / cell + offset[0], j / cell + offset[1]
            iy, ix = math.floor(y), math.floor(x)
            fy, fx = y - iy, x - ix
            dots = {
                (dy, dx): math.cos(angles[iy + dy, ix + dx]) * (fx - dx)
                + math.sin(angles[iy + dy, ix + dx]) * (fy - dy)
                for dy in (0, 1)
                for dx in (0, 1)
            }
            u, v = (t * t * t * (t * (t * 6 - 15) + 10) for t in (fx, fy))
            top = dots[0, 0] * (1 - u) + dots[0, 1] * u
            bottom = dots[1, 0] * (1 - u) + dots[1, 1] * u
            out[i, j] = (top * (1 - v) + bottom * v) * math.sqrt(2)
    return out


def test_perlin_equals_the_pixel_by_pixel_definition():
    for shape, cell in (((37, 53), 4.5), ((20, 11), 1.0), ((16, 40), 13.3)):
        got = perlin(shape, cell, np.random.default_rng(3))
        assert_allclose(got, _perlin_by_pixel(shape, cell, np.random.default_rng(3)), atol=2e-6)


def test_fractal_noise_is_normalised_and_seeded():
    a = fractal_noise((64, 80), 24.0, 4, np.random.default_rng(1))
    assert a.shape == (64, 80) and np.isclose(np.abs(a).max(), 1.0)
    assert np.array_equal(a, fractal_noise((64, 80), 24.0, 4, np.random.default_rng(1)))
