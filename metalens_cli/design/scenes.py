"""Clean training scenes for the optimiser, drawn afresh at every step from (seed, step, index).

With a folder of images (``optimize.images``): a random crop (half to full of the shorter side),
resized to the sensor and randomly flipped. Without one: procedural scenes that need no download,
built to have the statistics of photographs (spectrum slope, luminance distribution, colour
saturation, edge density; ``imaging.scene_statistics``). Linear RGB in 0..1, (3, H, W) float32.

The evaluation sets (``imaging.images``: the photographs and the dead-leaves charts) are never
used for training: they stay held out.
"""

from __future__ import annotations

import numpy as np

from metalens_cli.imaging.noise import fractal_noise
from metalens_cli.io.image_files import srgb_to_linear

SHAPES_PER_256_SQUARE = 250  # shapes per 256² pixels (density, not count: scenes are alike at every size)
RADIUS_PX = (2.0, 0.4)  # shape radii: 2 px to 0.4 × the field's longer side
RADIUS_EXPONENT = 1.3  # p(r) ∝ r^-(1 + this): many small shapes, few large ones
SHAPE_KINDS = (0.4, 0.3, 0.2, 0.1)  # ellipses, rectangles, strokes (1-3 px lines), grating patches
TEXTURE = 1.5  # largest amplitude of the fine texture inside a shape
LIGHT_DECADES = 0.55  # illumination varies over ±this many decades (shading, shadows)
FINE_RADIUS_PX = 16  # shapes smaller than this, and the fine texture, are drawn only near the field
DETAIL_BAND_PX = 32  # ... the sensor's field grown by this many pixels


def procedural_scene(shape: tuple[int, int], rng: np.random.Generator, margin: int = 0) -> np.ndarray:
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
    to the field, so the field looks the same whatever the margin."""
    h, w = shape
    side = max(max(h, w) - 2 * int(margin), 1)  # the field's side: every scale is relative to it, as a photo's framing
    band = max(int(margin) - DETAIL_BAND_PX, 0)
    top, left, bottom, right = band, band, h - band, w - band  # the detailed region
    coarse = fractal_noise((h, w), side / rng.uniform(2, 6), 3, rng).astype(np.float32)
    fine = np.zeros((h, w), np.float32)
    fine[top:bottom, left:right] = fractal_noise((bottom - top, right - left), rng.uniform(4, 16), 3, rng)
    image = _colour(rng).astype(np.float32)[:, None, None] * (1 + 0.4 * coarse + fine)  # float32 throughout
    y, x = np.arange(h, dtype=np.float32)[:, None], np.arange(w, dtype=np.float32)[None, :]
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
    kinds_cdf = np.cumsum(SHAPE_KINDS) / sum(SHAPE_KINDS)  # rng.choice(p=SHAPE_KINDS)'s draw, without its overhead
    for k in rng.permutation(len(shapes)):  # occlusion order independent of size
        r, cy, cx = shapes[k]
        kind = int(np.searchsorted(kinds_cdf, rng.random(), side="right"))
        reach = r * (3 if kind == 2 else 1.5)
        i0, i1, j0, j1 = (
            max(int(cy - reach), 0),
            min(int(cy + reach) + 1, h),
            max(int(cx - reach), 0),
            min(int(cx + reach) + 1, w),
        )
        if i0 >= i1 or j0 >= j1:
            continue
        angle = rng.uniform(0, np.pi)
        dy, dx = y[i0:i1] - cy, x[:, j0:j1] - cx
        along, across = dx * np.cos(angle) + dy * np.sin(angle), dy * np.cos(angle) - dx * np.sin(angle)
        if kind == 0:  # ellipse; inside distance ≈ pixels to the edge
            inside = r - np.sqrt(along**2 + (across / rng.uniform(0.4, 1.0)) ** 2)
        elif kind == 1:  # rectangle
            inside = np.minimum(r - np.abs(along), rng.uniform(0.3, 1.0) * r - np.abs(across))
        elif kind == 2:  # stroke
            inside = np.minimum(rng.uniform(0.5, 1.5) - np.abs(across), 3 * r - np.abs(along))
        else:  # grating patch
            bars = np.sin(2 * np.pi * along / rng.uniform(2.0, 10.0)) > 0
            inside = np.where(bars, r - np.hypot(along, across), -1.0)
        mask = np.clip(inside + 0.5, 0, 1)  # 1-pixel antialiased edge
        colour = _colour(rng).astype(np.float32)
        shade = mask * (1 + rng.uniform(0, TEXTURE) * fine[i0:i1, j0:j1] + rng.uniform(-0.3, 0.3) * along / max(r, 1.0))
        box = image[:, i0:i1, j0:j1]  # image ← (1 − mask)·image + mask·colour·(texture and ramp), in place
        box *= 1 - mask
        box += colour[:, None, None] * shade
    light = 10 ** (LIGHT_DECADES * fractal_noise((h, w), side / rng.uniform(1, 3), 2, rng))
    return np.clip(image * light, 0.002, 1.0).astype(np.float32)


def _colour(rng: np.random.Generator) -> np.ndarray:
    """A linear RGB colour: hue uniform, HSV saturation Beta(2, 1.5) × 0.95, value Beta(2, 2), sRGB-decoded."""
    import colorsys

    return srgb_to_linear(np.array(colorsys.hsv_to_rgb(rng.uniform(), 0.95 * rng.beta(2.0, 1.5), rng.beta(2.0, 2.0))))


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
    shape: tuple[int, int], seed: int, step: int, index: int, pool: list[np.ndarray] | None = None, margin: int = 0
) -> np.ndarray:
    """The clean scene number ``index`` of step ``step`` on a canvas of ``shape`` with ``margin``
    pixels around the sensor's field: the same (seed, step, index), the same scene."""
    rng = np.random.default_rng([seed, step, index, 11])
    if pool:
        return random_crop(pool[rng.integers(len(pool))], shape, rng)
    return procedural_scene(shape, rng, margin)
