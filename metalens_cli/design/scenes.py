"""Clean training scenes for the optimiser, drawn afresh at every step from (seed, step, index).

With a folder of images (``optimize.images``): a random crop (half to full of the shorter side),
resized to the sensor and randomly flipped. Without one: procedural scenes that need no download,
built to have the statistics of photographs (spectrum slope, luminance distribution, colour
saturation, edge density; ``imaging.scene_statistics``). Linear RGB in 0..1, (3, H, W) float32.
``procedural_scene(..., structure=True)`` adds what photographs of made things hold and these
lack: text, tilings (bricks, tiles, windows, fences), flat surfaces and smooth gradients (the
reconstruction network's "natural" scenes; the optimiser's scenes are unchanged).

The evaluation sets (``imaging.images``: the photographs and the dead-leaves charts) are never
used for training: they stay held out.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from metalens_cli.imaging.noise import fractal_noise
from metalens_cli.imaging.sample_grid import SampleGrid
from metalens_cli.io.image_files import srgb_to_linear

SHAPES_PER_256_SQUARE = 250  # shapes per 256² pixels (density, not count: scenes are alike at every size)
RADIUS_PX = (2.0, 0.4)  # shape radii: 2 px to 0.4 × the field's longer side
RADIUS_EXPONENT = 1.3  # p(r) ∝ r^-(1 + this): many small shapes, few large ones
SHAPE_KINDS = (0.4, 0.3, 0.2, 0.1)  # ellipses, rectangles, strokes (1-3 px lines), grating patches
TEXTURE = 1.5  # largest amplitude of the fine texture inside a shape
LIGHT_DECADES = 0.55  # illumination varies over ±this many decades (shading, shadows)
FINE_RADIUS_PX = 16  # shapes smaller than this, and the fine texture, are drawn only near the field
DETAIL_BAND_PX = 32  # ... the sensor's field grown by this many pixels
# within this of the field lies every shape narrower than 2.5 px (r < 8.3 px, reaching ≤ 2.5 r past the detail
# band), whose coverage a 5-px cell would overstate: a scene drawn in blocks keeps pixels there (imaging.sample_grid)
FINE_BAND_PX = DETAIL_BAND_PX + 24

# structure=True only
STRUCTURE_KINDS = (0.34, 0.24, 0.14, 0.08, 0.12, 0.08)  # SHAPE_KINDS' four, then tilings and text blocks
FLAT_FRACTION = 0.35  # shapes with neither texture nor shading ramp
GRADIENT_FRACTION = 0.5  # scenes whose background is a smooth two-colour ramp (sky, lit wall) instead of texture
TILT_RAD = 0.08  # tilings and text are axis-aligned to within ± this
GLYPH_PX = (4.0, 24.0)  # glyph cell heights, log-uniform (at most the text block's 2r)
TEXT_WIDTH = 2.5  # a text block's half-width, × its shape radius r (half-height ≤ r)
ALPHABET = 48  # glyphs per scene
GLYPH_STROKES = (0.3, 0.2, 0.15, 0.25, 0.1)  # a glyph's strokes: stems, bars, diagonals, arcs, dots


def procedural_scene(
    shape: tuple[int, int],
    rng: np.random.Generator,
    margin: int = 0,
    *,
    structure: bool = False,
    grid: SampleGrid | None = None,
) -> np.ndarray:
    """One random linear-RGB scene (3, H, W) in 0.002..1 whose statistics are those of the
    photographs of ``imaging.images`` (``imaging.scene_statistics``; tests/design/test_scenes.py):
    a textured background under occluding ellipses, rectangles, thin strokes and grating patches
    (radii p(r) ∝ r^-2.3, so every scale has edges), each a photo-like colour (hue uniform,
    HSV saturation and value Beta-distributed, sRGB-decoded) with its own texture and shading
    ramp, then lit by a smooth illumination field spanning about a decade.

    On a canvas with a ``margin`` of M pixels around the sensor's field (``imaging.canvas``),
    detail finer than ``FINE_RADIUS_PX`` is drawn only within ``DETAIL_BAND_PX`` of the field:
    the margin reaches the sensor only through PSF tails hundreds of pixels wide, which see its
    mean colour, not its fine structure, and the canvases of the quick presets are ~190× the
    field's area (most of a scene's cost). Sizes (radii, texture and light scales) are relative
    to the field, so the field looks the same whatever the margin.

    ``structure``: also man-made structure and flat surfaces (it draws other random numbers;
    without it the scene is the same, bit for bit, as before it existed). With probability
    ``GRADIENT_FRACTION`` the background is a smooth ramp between two colours (vertical or any
    direction) instead of a texture; ``FLAT_FRACTION`` of the shapes are flat (one colour, no
    texture or ramp); shape kinds ``STRUCTURE_KINDS`` add tilings (:func:`_tiling`) and text
    blocks (:func:`_text`), which, being fine detail, are plain rectangles when their centre lies
    outside the detailed region.

    ``grid`` (``imaging.sample_grid``, without ``structure``): the scene evaluated at its samples
    only, each cell of the canvas filled with its sample. Every random draw is the one the pixel
    grid makes, so it is the same scene at the grid's resolution; edges are antialiased over each
    sample's footprint, strokes and gratings covered in proportion within it."""
    h, w = shape
    grid = grid or SampleGrid.pixels(shape)
    if grid.shape != (h, w) or (structure and not grid.whole):
        raise ValueError(f"a grid of the canvas {(h, w)} (structure scenes: at every pixel, grid=None)")
    side = max(max(h, w) - 2 * int(margin), 1)  # the field's side: every scale is relative to it, as a photo's framing
    band = max(int(margin) - DETAIL_BAND_PX, 0)
    top, left, bottom, right = band, band, h - band, w - band  # the detailed region
    coarse = fractal_noise((h, w), side / rng.uniform(2, 6), 3, rng, at=grid.at).astype(np.float32)
    fine = np.zeros(grid.samples, np.float32)
    (i0, i1, j0, j1), at = grid.within(top, bottom, left, right)
    fine[i0:i1, j0:j1] = fractal_noise((bottom - top, right - left), rng.uniform(4, 16), 3, rng, at=at)
    y, x = grid.rows[:, None], grid.cols[None, :]
    footprint = None if grid.whole else grid.footprint()
    if structure and rng.random() < GRADIENT_FRACTION:
        image = _ramp(y - h / 2, x - w / 2, side, rng)
    else:
        image = _colour(rng).astype(np.float32)[:, None, None] * (1 + 0.4 * coarse + fine)  # float32 throughout
    r_min, r_max, a = RADIUS_PX[0], RADIUS_PX[1] * side, RADIUS_EXPONENT
    split = min(max(FINE_RADIUS_PX, r_min), r_max)
    density = (
        SHAPES_PER_256_SQUARE / 256**2 * rng.uniform(0.6, 1.4) / (r_min**-a - r_max**-a)
    )  # shapes per px² per unit CDF
    shapes = []
    for lo, hi, (y0, x0, y1, x1) in ((r_min, split, (top, left, bottom, right)), (split, r_max, (0, 0, h, w))):
        count = int(density * (lo**-a - hi**-a) * (y1 - y0) * (x1 - x0))
        radii = (lo**-a - rng.uniform(size=count) * (lo**-a - hi**-a)) ** (-1 / a)  # inverse CDF on [lo, hi]
        shapes += [(r, rng.uniform(y0 - r, y1 + r), rng.uniform(x0 - r, x1 + r)) for r in radii]
    alphabet = _alphabet(rng) if structure else None
    weights = STRUCTURE_KINDS if structure else SHAPE_KINDS
    kinds_cdf = (np.cumsum(weights) / sum(weights)).tolist()  # rng.choice(p=weights)'s draw, without its overhead
    row_at, col_at = grid.span_table(0), grid.span_table(1)
    for k in rng.permutation(len(shapes)):  # occlusion order independent of size
        r, cy, cx = shapes[k]
        kind = bisect.bisect_right(kinds_cdf, rng.random())  # np.searchsorted(side="right") on a list
        if kind >= 4 and not (top <= cy < bottom and left <= cx < right):
            kind = 1  # structure is fine detail: a plain rectangle away from the field
        reach = r * (3 if kind == 2 else 1.5)
        if kind == 5:
            reach = r * (TEXT_WIDTH + 1) + 4  # a text block's half-diagonal with its sign and strokes
        i0, i1, j0, j1 = (
            max(int(cy - reach), 0),
            min(int(cy + reach) + 1, h),
            max(int(cx - reach), 0),
            min(int(cx + reach) + 1, w),
        )
        if i0 >= i1 or j0 >= j1:
            continue
        angle = rng.uniform(0, np.pi) if kind < 4 else rng.uniform(-TILT_RAD, TILT_RAD)
        size = aspect = 0.0  # a stroke's half-width, a grating's period (px); an ellipse's or rectangle's aspect
        if kind < 4:  # only the part of the box that the shape can cover is drawn
            if kind < 2:
                aspect = rng.uniform(0.4, 1.0) if kind == 0 else rng.uniform(0.3, 1.0)
            elif kind == 2:
                size = rng.uniform(0.5, 1.5)
            i0, i1, j0, j1 = _shape_box((i0, i1, j0, j1), kind, r, aspect, size, cy, cx, angle, grid.block)
        i0, i1, j0, j1 = row_at[i0], row_at[i1], col_at[j0], col_at[j1]  # grid.span; empty ones still draw
        dy, dx = y[i0:i1] - cy, x[:, j0:j1] - cx
        along, across = dx * np.cos(angle) + dy * np.sin(angle), dy * np.cos(angle) - dx * np.sin(angle)
        cell = 1.0 if footprint is None else footprint[i0:i1, j0:j1]
        if kind == 0:  # ellipse; inside distance ≈ pixels to the edge
            inside = r - np.sqrt(along**2 + (across / aspect) ** 2)
        elif kind == 1:  # rectangle
            inside = np.minimum(r - np.abs(along), aspect * r - np.abs(across))
        elif kind == 2:  # stroke
            inside = np.minimum(size - np.abs(across), 3 * r - np.abs(along))
        elif kind == 3:  # grating patch
            size = rng.uniform(2.0, 10.0)  # period
            bars = np.sin(2 * np.pi * along / size) > 0
            inside = np.where(bars, r - np.hypot(along, across), -1.0)
        flat = structure and rng.random() < FLAT_FRACTION
        if kind == 4:
            mask, paint = _tiling(along, across, r, rng)
        elif kind == 5:
            mask, paint = _text(along, across, r, alphabet, rng)
        elif footprint is None:
            mask = np.clip(inside + 0.5, 0, 1)  # 1-pixel antialiased edge
            colour = _colour(rng).astype(np.float32)
        else:
            mask = _sampled_mask(kind, inside, along, across, r, size, cell)
            colour = _colour(rng).astype(np.float32)
        shade = 1  # flat: one colour
        if not flat:  # texture and shading ramp
            shade = 1 + rng.uniform(0, TEXTURE) * fine[i0:i1, j0:j1] + rng.uniform(-0.3, 0.3) * along / max(r, 1.0)
        paint = colour[:, None, None] * (mask * shade) if kind < 4 else paint * shade
        box = image[:, i0:i1, j0:j1]  # image ← (1 − mask)·image + paint (premultiplied by mask), in place
        box *= 1 - mask
        box += paint
    light = 10 ** (LIGHT_DECADES * fractal_noise((h, w), side / rng.uniform(1, 3), 2, rng, at=grid.at))
    return grid.canvas(np.clip(image * light, 0.002, 1.0).astype(np.float32))


def _shape_box(box, kind: int, r: float, aspect: float, size: float, cy: float, cx: float, angle: float, grown: int):
    """``box`` (i0, i1, j0, j1: pixel rows and columns, ends excluded) cut to the bounding box of
    what a shape of ``kind`` 0-3 centred on (cy, cx) can cover along ``angle`` (rad): an ellipse of
    semi-axes r and ``aspect``·r, a rectangle of those half-sides, a stroke of half-length 3r and
    half-width ``size``, a grating's disc of radius r; each grown by ``grown`` px (at least half
    the widest cell's footprint, over which the edge is antialiased) and 1 px for rounding. Its
    mask is 0 outside, so drawing only there leaves the canvas as drawing the whole box does, bit
    for bit; the box (2·1.5r or 2·3r a side) is far larger for thin, long or tilted shapes."""
    along, across = {0: (r, aspect * r), 1: (r, aspect * r), 2: (3 * r, size), 3: (r, r)}[kind]
    a, b = along + grown + 1, across + grown + 1
    c, s = abs(math.cos(angle)), abs(math.sin(angle))
    if kind in (0, 3):  # an ellipse's extents
        ey, ex = math.hypot(a * s, b * c), math.hypot(a * c, b * s)
    else:  # a rectangle's
        ey, ex = a * s + b * c, a * c + b * s
    i0, i1, j0, j1 = box
    top, left = min(max(i0, int(cy - ey)), i1), min(max(j0, int(cx - ex)), j1)  # within the box, maybe empty
    return top, max(min(i1, int(cy + ey) + 2), top), left, max(min(j1, int(cx + ex) + 2), left)


def _sampled_mask(kind, inside, along, across, r: float, size: float, cell: np.ndarray) -> np.ndarray:
    """A shape's coverage of each sample's cell (``cell``: its footprint, pixels) on a grid coarser
    than the pixels: edges antialiased over the footprint; a stroke (half-width ``size``) covers
    the overlap of its band with the footprint; a grating (period ``size``) finer than two
    footprints covers half its disc."""
    if kind == 2:
        d = np.abs(across)
        band = np.clip((np.minimum(d + cell / 2, size) - np.maximum(d - cell / 2, -size)) / cell, 0, 1)
        return band * np.clip((3 * r - np.abs(along)) / cell + 0.5, 0, 1)
    if kind == 3:
        disc = np.clip((r - np.hypot(along, across)) / cell + 0.5, 0, 1)
        return disc * np.where(size < 2 * cell, 0.5, np.sin(2 * np.pi * along / size) > 0)
    return np.clip(inside / cell + 0.5, 0, 1)


def _ramp(dy: np.ndarray, dx: np.ndarray, side: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth background (3, H, W): two photo-like colours blended linearly over 1-3 field sides
    (``side`` px) along a direction, vertical (a sky) half the time; ``dy``, ``dx``: pixels from
    the canvas centre."""
    angle = np.pi / 2 if rng.random() < 0.5 else rng.uniform(0, 2 * np.pi)
    t = np.clip(0.5 + (dx * np.cos(angle) + dy * np.sin(angle)) / (side * rng.uniform(1, 3)), 0, 1)
    c0, c1 = _colour(rng).astype(np.float32), _colour(rng).astype(np.float32)
    return c0[:, None, None] + (c1 - c0)[:, None, None] * t


def _tiling(along: np.ndarray, across: np.ndarray, r: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle (half-sides r along, 0.4-1 r across; coordinates in px from its centre) tiled by
    a lattice: bricks (running bond), tiles, windows (grey panes in a wall) or a fence (bars and
    rails, transparent between them). Faces of pitch 4 px to r/2 along, lines of 1-2 px between
    them (mortar, joints: grey) or 30-60 % of the pitch (the wall between windows); each face's
    brightness is jittered. Returns the coverage (h, w) and the paint (3, h, w), premultiplied by it."""
    mask = np.clip(np.minimum(r - np.abs(along), rng.uniform(0.4, 1.0) * r - np.abs(across)) + 0.5, 0, 1)
    pattern = int(rng.integers(4))
    pa = np.exp(rng.uniform(np.log(4), np.log(max(r / 2, 4))))  # pitch along, px
    if pattern == 0:  # bricks
        pb, widths = pa * rng.uniform(0.3, 0.5), rng.uniform(1, 2, 2)
    elif pattern == 1:  # tiles
        pb, widths = pa, rng.uniform(1, 2, 2)
    elif pattern == 2:  # windows
        pb = pa * rng.uniform(1, 1.6)
        widths = rng.uniform(0.3, 0.6, 2) * (pa, pb)
    else:  # fence: bars, and rails r apart
        pb, widths = r, (rng.uniform(1, max(0.4 * pa, 1)), rng.uniform(1, 3))
    pb = max(pb, 3.0)  # pitch across, px
    v = across / pb + rng.uniform()
    row = np.floor(v)
    u = along / pa + rng.uniform() + (0.5 * (row % 2) if pattern == 0 else 0)
    line = np.maximum(  # lines at integer u and v, antialiased
        np.clip(widths[0] / 2 - pa * np.abs(u - np.round(u)) + 0.5, 0, 1),
        np.clip(widths[1] / 2 - pb * np.abs(v - np.round(v)) + 0.5, 0, 1),
    )
    colour = _colour(rng).astype(np.float32)
    if pattern < 2:  # coloured faces, grey mortar darker or lighter
        face, edge = colour, np.full(3, colour.mean() * rng.uniform(0.3, 2.0), np.float32)
    else:  # grey glass in a coloured wall, coloured bars
        face, edge = np.full(3, rng.uniform(0.01, 0.15), np.float32), colour
    jitter = rng.uniform(-1, 1, (8, 8)).astype(np.float32)[row.astype(int) % 8, np.floor(u).astype(int) % 8]
    faces = mask * (1 - line) * (pattern < 3)
    line = mask * line
    paint = face[:, None, None] * (faces * (1 + (0.15, 0.05, 0.1, 0)[pattern] * jitter)) + edge[:, None, None] * line
    return faces + line, paint


def _text(
    along: np.ndarray, across: np.ndarray, r: float, alphabet: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """A block of text (:func:`_glyph_rows`; coordinates in px from its centre): dark grey ink on a
    colour or light grey ink on a darkened colour, on a flat sign (a rectangle 0.3 glyph heights
    larger than the text) half the time. Returns the coverage (h, w) and the paint (3, h, w),
    premultiplied by it."""
    ink, width, height, g = _glyph_rows(along, across, r, alphabet, rng)
    colour = _colour(rng).astype(np.float32)
    if rng.random() < 0.7:
        ink_colour, sign_colour = np.full(3, rng.uniform(0.003, 0.03), np.float32), colour
    else:
        ink_colour, sign_colour = np.full(3, rng.uniform(0.4, 0.9), np.float32), colour * rng.uniform(0.05, 0.3)
    if rng.random() < 0.5:
        pad = 0.3 * g
        sign = np.clip(np.minimum(width / 2 + pad - np.abs(along), height / 2 + pad - np.abs(across)) + 0.5, 0, 1)
        return sign, sign_colour[:, None, None] * (sign * (1 - ink)) + ink_colour[:, None, None] * ink
    return ink, ink_colour[:, None, None] * ink


def _glyph_rows(
    along: np.ndarray, across: np.ndarray, r: float, alphabet: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, float, float, float]:
    """Ink coverage (h, w) of a block of text centred on along = across = 0 (px): rows of glyphs of
    ``alphabet`` (:func:`_alphabet`) ``GLYPH_PX`` tall (at most 2r), 0.5-0.8 as wide, strokes 1-2 px
    wide, a line pitch of 1.3-1.8 glyph heights; a fifth of the cells are word gaps, lines end
    raggedly, a tenth are blank. The block is at most 2·``TEXT_WIDTH``·r wide and max(2r, glyph)
    tall. Returns the coverage, the block's width and height and the glyph height (px)."""
    g = min(np.exp(rng.uniform(*np.log(GLYPH_PX))), max(GLYPH_PX[0], 2 * r))
    gw, pitch, stroke = g * rng.uniform(0.5, 0.8), g * rng.uniform(1.3, 1.8), rng.uniform(1, 2)
    rows, cols = max(int((2 * r * rng.uniform(0.3, 1) - g) / pitch) + 1, 1), max(int(2 * TEXT_WIDTH * r / gw), 1)
    used, ids = np.unique(rng.integers(len(alphabet), size=(rows, cols)), return_inverse=True)
    ids = ids.reshape(rows, cols)
    blank = rng.random((rows, cols)) < 0.2  # word gaps
    blank |= np.arange(cols) >= cols - rng.integers(0, cols // 3 + 1, size=(rows, 1))  # ragged line ends
    blank |= rng.random((rows, 1)) < 0.1  # blank lines
    # the glyphs used, antialiased: coverage (glyphs, cell h, cell w) from the distance to their segments
    segments = (alphabet[used] * np.array([gw, g, gw, g], np.float32))[:, :, None, None, :]
    py, px = np.mgrid[0 : int(g) + 2, 0 : int(gw) + 2].astype(np.float32) + 0.5  # pixel centres in a cell
    qx, qy = px - segments[..., 0], py - segments[..., 1]
    dx, dy = segments[..., 2] - segments[..., 0], segments[..., 3] - segments[..., 1]
    t = np.clip((qx * dx + qy * dy) / np.maximum(dx**2 + dy**2, 1e-6), 0, 1)
    bitmaps = np.clip(stroke / 2 - np.hypot(qx - t * dx, qy - t * dy).min(axis=1) + 0.5, 0, 1)
    height, width = (rows - 1) * pitch + g, cols * gw
    b, a = across + height / 2, along + width / 2  # px from the block's top-left corner
    row, col = np.floor(b / pitch).astype(int), np.floor(a / gw).astype(int)
    yi, xi = np.floor(b - row * pitch).astype(int), np.floor(a - col * gw).astype(int)
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols) & (yi < bitmaps.shape[1]) & (xi < bitmaps.shape[2])
    row, col = row[inside], col[inside]
    ink = np.zeros(along.shape, np.float32)
    ink[inside] = np.where(blank[row, col], 0, bitmaps[ids[row, col], yi[inside], xi[inside]])
    return ink, width, height, g


def _alphabet(rng: np.random.Generator) -> np.ndarray:
    """A scene's ``ALPHABET`` random glyphs: segments (ALPHABET, 18, 4) (x0, y0, x1, y1) in units of
    the glyph cell's width and height (y down from the cap line), unused ones far away. A glyph is
    1-3 strokes (``GLYPH_STROKES``) at x = 0.15, 0.5 or 0.85 and from the cap line (0) or x-height
    (0.4) to the baseline (1); an arc is 6 chords of the bowl centred at (0.5, 0.7) with semi-axes
    (0.35, 0.3), a straight stroke fills its 6 slots by itself."""
    shape = (ALPHABET, 3)
    kind = np.searchsorted(np.cumsum(GLYPH_STROKES), rng.random(shape) * sum(GLYPH_STROKES), side="right")
    x, top = rng.choice([0.15, 0.5, 0.85], shape), rng.choice([0.0, 0.4], shape)
    level, flip = rng.choice([0.4, 0.7, 1.0], shape), rng.random(shape) < 0.5
    one, near, far = np.ones(shape), np.full(shape, 0.15), np.full(shape, 0.85)
    lines = np.select(  # (ALPHABET, 3, 4): one segment per stroke
        [kind[..., None] == k for k in (0, 1, 2)],
        [
            np.stack([x, top, x, one], -1),  # stem
            np.stack([near, level, far, level], -1),  # bar
            np.stack([np.where(flip, far, near), top, np.where(flip, near, far), one], -1),  # diagonal
        ],
        np.stack([x, near, x, near], -1),  # dot at (x, 0.15)
    )
    start, extent = rng.uniform(0, 2 * np.pi, shape), np.pi * rng.choice([1.0, 1.5, 2.0], shape)
    theta = start[..., None] + extent[..., None] * np.linspace(0, 1, 7)  # half, three quarters or all of a bowl
    ax, ay = 0.5 + 0.35 * np.cos(theta), 0.7 + 0.3 * np.sin(theta)
    arcs = np.stack([ax[..., :-1], ay[..., :-1], ax[..., 1:], ay[..., 1:]], -1)  # (ALPHABET, 3, 6, 4)
    segments = np.where((kind == 3)[..., None, None], arcs, lines[:, :, None, :])
    segments[np.arange(3) >= rng.integers(1, 4, (ALPHABET, 1))] = 1e4  # 1-3 strokes used, the rest far away
    return segments.reshape(ALPHABET, 18, 4).astype(np.float32)


def _colour(rng: np.random.Generator) -> np.ndarray:
    """A linear RGB colour: hue uniform, HSV saturation Beta(2, 1.5) × 0.95, value Beta(2, 2), sRGB-decoded
    (one at a time through ``colorsys``: 9 µs, against 40 µs for :func:`colours` of one)."""
    import colorsys

    return srgb_to_linear(np.array(colorsys.hsv_to_rgb(rng.uniform(), 0.95 * rng.beta(2.0, 1.5), rng.beta(2.0, 2.0))))


def colours(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` photo-like linear RGB colours (n, 3) as :func:`_colour` draws them, drawn as arrays:
    hues, then saturations, then values (one colour: :func:`_colour`'s numbers, bit for bit)."""
    h, s, v = rng.uniform(size=n), 0.95 * rng.beta(2.0, 1.5, size=n), rng.beta(2.0, 2.0, size=n)
    sector = (h * 6.0).astype(int)  # colorsys.hsv_to_rgb, element-wise
    f = h * 6.0 - sector
    p, q, t = v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f))
    rgb = np.choose(
        sector[:, None] % 6,
        [np.stack(c, -1) for c in ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))],
    )
    return srgb_to_linear(np.where(s[:, None] == 0.0, v[:, None], rgb))


def random_crop(image: np.ndarray, shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A random square-ish crop of a (3, H0, W0) image resized to ``shape``, randomly flipped."""
    import cv2

    _, h0, w0 = image.shape
    side = int(rng.uniform(0.5, 1.0) * min(h0, w0))
    top, left = rng.integers(0, h0 - side + 1), rng.integers(0, w0 - side + 1)
    crop = np.transpose(image[:, top : top + side, left : left + side], (1, 2, 0))
    crop = cv2.resize(crop, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    crop = np.transpose(crop, (2, 0, 1))
    if rng.random() < 0.5:
        crop = crop[:, :, ::-1]
    return np.ascontiguousarray(crop, dtype=np.float32)


def training_scene(
    shape: tuple[int, int],
    seed: int,
    step: int,
    index: int,
    pool: list[np.ndarray] | None = None,
    margin: int = 0,
    grid: SampleGrid | None = None,
) -> np.ndarray:
    """The clean scene number ``index`` of step ``step`` on a canvas of ``shape`` with ``margin``
    pixels around the sensor's field: the same (seed, step, index), the same scene (a procedural
    one at ``grid``'s samples, ``procedural_scene``; a crop of a training image at every pixel)."""
    rng = np.random.default_rng([seed, step, index, 11])
    if pool:
        return random_crop(pool[rng.integers(len(pool))], shape, rng)
    return procedural_scene(shape, rng, margin, grid=grid)
