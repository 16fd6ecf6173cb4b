"""Seeded colour dead-leaves chart (the texture target of ISO 19567-2): (3, H, W) linear RGB.

Disks with radius density p(r) ∝ r⁻³ on [r_min, r_max] (pixels; scale invariant, power spectrum
≈ 1/f²), uniform random centres and colours uniform over 8-bit sRGB levels 38..242 (0.15..0.95,
decoded with the sRGB EOTF to linear ≈ 0.02..0.89), stacked in dead-leaves order: each new disk
lies *behind* those already drawn, until every pixel is opaque. Edges are antialiased by a
1-pixel linear ramp, composited front to back; a disk that would leave a pixel less than
``OPAQUE`` transmittance takes all of it (the pixel is then covered).

Geometry. Pixel (i, j) sits at y = i − (H−1)/2, x = j − (W−1)/2 (pixels from the array centre).
The plane is tiled into square cells of side max(r_max, ``MIN_CELL_PX``); cell (iy, ix) draws
its disks, a fixed number per chunk, from ``numpy.random.default_rng([seed, iy, ix])`` (indices
zigzag-mapped to non-negative), each with a depth key that orders the chunk across cells; chunks
go front to back. Every cell within r_max + ½ pixel of the array is used, and a pixel's colour
depends only on the disks over it, so only on its position relative to the centre, the seed and
the radii, never on ``shape``: a canvas with equal margins on every side holds the smaller
array exactly (bit for bit) at its centre. ``sensor_shape`` only sets the default r_max (a
quarter of its shorter side). Per-pixel arithmetic is element-wise and correctly rounded, and
each pixel composites its own disks in depth order, for that reason.
"""

from __future__ import annotations

import math

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io.image_files import srgb_to_linear

SRGB_LEVELS = (38, 242)  # disk colours: 8-bit sRGB levels, uniform per channel (0.15..0.95)
OPAQUE = 1e-3  # transmittance below which a pixel counts as covered (< 8-bit step)
MAX_CHUNKS = 64  # chunk k leaves a fraction ≈ e^-(k+1) uncovered; the rest is background
R_MAX_FRACTION = 0.25  # default r_max, × the sensor's shorter side
MIN_CELL_PX = 64  # cell side max(r_max, this): few random streams on large canvases
TILE = 16  # pixels per side of the tiles that cull disks far from uncovered pixels


LINEAR_LEVELS = srgb_to_linear(np.arange(256) / 255, dtype=np.float64)  # lookup: the same bits for every canvas
BACKGROUND = LINEAR_LEVELS[128]  # mid grey, only where MAX_CHUNKS runs out


def _zigzag(i: int) -> int:
    """…, −2, −1, 0, 1, 2, … → 3, 1, 0, 2, 4 (SeedSequence entropy must be non-negative)."""
    return 2 * i if i >= 0 else -2 * i - 1


def _chunk(rngs, cells: np.ndarray, n: int, side: float, r_min: float, r_max: float):
    """The next ``n`` disks of every cell: depth key, centre y, x (px), radius (px), linear RGB.
    Element-wise arithmetic only (correctly rounded), so a disk's values never depend on the canvas."""
    u = np.concatenate([g.random((n, 7)) for g in rngs])
    cell = np.repeat(cells, n, axis=0)
    a, b = r_min**-2, r_max**-2
    radius = 1 / np.sqrt(a - u[:, 3] * (a - b))  # inverse CDF of p(r) ∝ r⁻³
    lo, hi = SRGB_LEVELS
    rgb = LINEAR_LEVELS[(lo + u[:, 4:] * (hi - lo + 1)).astype(np.int64)]
    return u[:, 0], (cell[:, 0] + u[:, 1]) * side, (cell[:, 1] + u[:, 2]) * side, radius, rgb


def _spans(starts: np.ndarray, stops: np.ndarray):
    """(owner, value) for every integer in each [start, stop): owner indexes the span."""
    count = stops - starts
    owner = np.repeat(np.arange(count.size), count)
    return owner, starts[owner] + np.arange(owner.size) - np.repeat(np.cumsum(count) - count, count)


def _bounds(centre, reach, origin: float, size: int):
    """Pixel index range [lo, hi) around centre ± reach, one pixel wider so that rounding never
    drops a touched pixel, clipped to the array."""
    lo = np.clip(np.floor(centre - reach - origin), 0, size).astype(np.int64)
    return lo, np.clip(np.ceil(centre + reach - origin) + 1, 0, size).astype(np.int64)


def _live_tiles(live: np.ndarray):
    """Live pixels left of each column per row (H, W+1), and a summed-area table of live pixels
    per ``TILE`` × ``TILE`` tile."""
    h, w = live.shape
    prefix = np.zeros((h, w + 1), np.int32)
    np.cumsum(live, axis=1, out=prefix[:, 1:])
    edges = np.arange(0, w + TILE, TILE).clip(max=w)
    counts = np.add.reduceat(np.diff(prefix[:, edges], axis=1), np.arange(0, h, TILE), axis=0)
    tiles = np.zeros((counts.shape[0] + 1, counts.shape[1] + 1), np.int64)
    tiles[1:, 1:] = counts.cumsum(0).cumsum(1)
    return prefix, tiles


def _near_live(tiles: np.ndarray, cy, cx, radius, ys, xs) -> np.ndarray:
    """Indices of the disks whose box meets a tile with live pixels."""
    i0, i1 = _bounds(cy, radius + 0.5, ys[0], len(ys))
    j0, j1 = _bounds(cx, radius + 0.5, xs[0], len(xs))
    ti0, ti1, tj0, tj1 = i0 // TILE, -(-i1 // TILE), j0 // TILE, -(-j1 // TILE)
    seen = tiles[ti1, tj1] - tiles[ti0, tj1] - tiles[ti1, tj0] + tiles[ti0, tj0]
    return np.flatnonzero((seen > 0) & (i1 > i0) & (j1 > j0))


def _fragments(live: np.ndarray, prefix: np.ndarray, cy, cx, radius, ys, xs):
    """(disk, pixel, alpha) for every live pixel a disk touches; disk rows whose span holds no
    live pixel are skipped before they are expanded into pixels."""
    w = live.shape[1]
    reach = radius + 0.5
    disk, row = _spans(*_bounds(cy, reach, ys[0], len(ys)))
    dy = ys[row] - cy[disk]
    c0, c1 = _bounds(cx[disk], np.sqrt(np.maximum(reach[disk] ** 2 - dy * dy, 0.0)), xs[0], w)
    keep = np.flatnonzero(prefix[row, c1] - prefix[row, c0] > 0)
    span, col = _spans(c0[keep], c1[keep])
    disk, row = disk[keep][span], row[keep][span]
    alive = live[row, col]
    disk, row, col = disk[alive], row[alive], col[alive]
    dy, dx = ys[row] - cy[disk], xs[col] - cx[disk]
    alpha = np.minimum(radius[disk] + 0.5 - np.sqrt(dy * dy + dx * dx), 1.0)
    hit = alpha > 0
    return disk[hit], row[hit] * w + col[hit], alpha[hit]


def _composite(transmit: np.ndarray, colour: np.ndarray, disk, pix, alpha, rgb) -> None:
    """Composite fragments behind what is drawn, in place: (N,) transmittance, (3, N) colour;
    ``disk`` indexes ``rgb`` (D, 3) front to back. Each round takes every pixel's front-most
    remaining fragment; one that would leave less than ``OPAQUE`` counts as opaque. Colour is
    summed per pixel in depth order (``bincount`` adds in array order)."""
    if not pix.size:
        return
    front = np.full(transmit.size, np.iinfo(np.int64).max)
    drawn, weights = [], []
    todo = np.arange(pix.size)
    while todo.size:
        np.minimum.at(front, pix[todo], disk[todo])
        now = front[pix[todo]] == disk[todo]
        front[pix[todo]] = np.iinfo(np.int64).max
        k = todo[now]
        before = transmit[pix[k]]
        after = before * (1 - alpha[k])
        after[after < OPAQUE] = 0.0
        transmit[pix[k]] = after
        drawn.append(k)
        weights.append(before - after)
        todo = todo[~now]
        todo = todo[transmit[pix[todo]] > 0]
    k, weight = np.concatenate(drawn), np.concatenate(weights)
    for c in range(3):
        colour[c] += np.bincount(pix[k], weight * rgb[disk[k], c], minlength=transmit.size)


def _positive_shape(field: str, shape) -> tuple[int, int]:
    """(height, width) as ints, or InputError."""
    if len(shape) != 2 or any(int(s) != s or s < 1 for s in shape):
        raise InputError(field, repr(shape), "(height, width) positive integers")
    return int(shape[0]), int(shape[1])


def dead_leaves(
    shape: tuple[int, int],
    seed: int,
    *,
    sensor_shape: tuple[int, int] | None = None,
    r_min_px: float = 1.0,
    r_max_px: float | None = None,
) -> np.ndarray:
    """Dead-leaves chart of ``shape`` (H, W): (3, H, W) float32 linear RGB in about 0.02..0.89.

    ``seed`` (integer ≥ 0) fixes the chart; radii in pixels, r_max by default a quarter of the
    shorter side of ``sensor_shape`` (default ``shape``). The centre is shared exactly with any
    larger ``shape`` of equal margins on every side (same seed, radii and sensor_shape).
    """
    h, w = _positive_shape("dead leaves shape", shape)
    sensor = _positive_shape("dead leaves sensor shape", shape if sensor_shape is None else sensor_shape)
    if int(seed) != seed or seed < 0:
        raise InputError("dead leaves seed", repr(seed), "an integer ≥ 0")
    r_min = float(r_min_px)
    r_max = R_MAX_FRACTION * min(sensor) if r_max_px is None else float(r_max_px)
    if not 0 < r_min <= r_max < math.inf:
        raise InputError("dead leaves radii", f"r_min {r_min} px, r_max {r_max} px", "0 < r_min ≤ r_max, finite")
    side = max(r_max, MIN_CELL_PX)
    mean_r2 = r_min**2 if r_min == r_max else math.log(r_max / r_min) / (0.5 * (r_min**-2 - r_max**-2))
    n = math.ceil(side**2 / (math.pi * mean_r2))  # disks per cell and chunk: mean coverage 1
    ys, xs = np.arange(h) - (h - 1) / 2, np.arange(w) - (w - 1) / 2
    reach = r_max + 0.5
    cells = np.array(
        [
            (iy, ix)
            for iy in range(math.floor((ys[0] - reach) / side), math.floor((ys[-1] + reach) / side) + 1)
            for ix in range(math.floor((xs[0] - reach) / side), math.floor((xs[-1] + reach) / side) + 1)
        ]
    )
    rngs = [np.random.default_rng([int(seed), _zigzag(iy), _zigzag(ix)]) for iy, ix in cells.tolist()]
    transmit, colour = np.ones(h * w), np.zeros((3, h * w))
    for _ in range(MAX_CHUNKS):
        depth, cy, cx, radius, rgb = _chunk(rngs, cells, n, side, r_min, r_max)
        live = transmit.reshape(h, w) > 0
        prefix, tiles = _live_tiles(live)
        near = _near_live(tiles, cy, cx, radius, ys, xs)
        near = near[np.argsort(depth[near], kind="stable")]  # front first; cell order breaks ties
        disk, pix, alpha = _fragments(live, prefix, cy[near], cx[near], radius[near], ys, xs)
        _composite(transmit, colour, disk, pix, alpha, rgb[near])
        if not transmit.any():
            break
    colour += transmit * BACKGROUND
    return colour.reshape(3, h, w).astype(np.float32)
