"""A step's procedural scenes and dirt drawn with torch on the run's device (``[optimize]
scene_generator``; issue 56: nothing on the host in the step).

The same statistics as ``design.scenes.procedural_scene`` (``structure=False``) and
``imaging.obstructions.dirt``/``fence``, in another draw: every random number is drawn up front on
the host from the entry's (seed, step, index) streams (the shapes' parameters and the noise
lattices: a few thousand numbers, no pixels), then every pixel is computed on the device, nothing
read back. The noise fields use :func:`imaging.noise.perlin`'s lattice draws; dirt and fences draw
what the host draws (their pixels within float32 rounding and the resize's half-pixel convention).

The occluding shapes are composited in layers: each pixel keeps the ``LAYERS`` topmost shapes that
cover it (none below one that covers it whole), painted over each other and over the background in
occlusion order. Painting every
shape in turn (``design.scenes``, and :func:`paint_every_shape` here, the slow exact path) differs
only where a pixel's top ``LAYERS`` shapes are all partly transparent there, at their antialiased
edges (tests/design/test_device_scenes.py measures it). Canvases are drawn at every pixel:
``[optimize] scene_blocks`` is a saving of the host generator's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from metalens_cli.design.scenes import (
    DETAIL_BAND_PX,
    FINE_RADIUS_PX,
    LIGHT_DECADES,
    RADIUS_EXPONENT,
    RADIUS_PX,
    SHAPE_KINDS,
    SHAPES_PER_256_SQUARE,
    TEXTURE,
    colours,
)
from metalens_cli.imaging.noise import SAMPLES_PER_CELL
from metalens_cli.imaging.obstructions import DIRT_RGB, feature_px, smoothstep
from metalens_cli.io.presets import DEVICE_OBSTRUCTIONS

LAYERS = 4  # shapes kept per pixel, topmost first (tests/design/test_device_scenes.py: 4 paint as every shape would)
CHUNK_SAMPLES = 2**21  # shapes' boxes are evaluated this many box pixels at a time
BOX_SIDES = np.unique(np.ceil(2 ** np.arange(2, 16, 0.5) / 2).astype(int) * 2)  # 4, 6, 8, 12, 16, 24, 32, 46, …


def to_device(array, device, dtype=torch.float32) -> torch.Tensor:
    """A host array on ``device`` without a host wait: on CUDA copied from pinned memory,
    asynchronously (a blocking copy would wait for the device's queue)."""
    tensor = torch.as_tensor(np.asarray(array), dtype=dtype)
    if torch.device(device).type == "cuda":
        return tensor.pin_memory().to(device, non_blocking=True)
    return tensor.to(device)


def perlin(shape: tuple[int, int], cell_px: float, rng: np.random.Generator, device) -> torch.Tensor:
    """:func:`imaging.noise.perlin` (its lattice and offset draws) at every pixel of ``shape``,
    float32 on ``device``."""
    h, w = shape
    cell = max(float(cell_px), 1.0)
    gh, gw = int(math.ceil(h / cell)) + 2, int(math.ceil(w / cell)) + 2
    angles = rng.uniform(0, 2 * math.pi, size=(gh, gw))
    offset = rng.uniform(0, 1, size=2)
    gx, gy = to_device(np.stack([np.cos(angles), np.sin(angles)]), device)
    y = torch.arange(h, device=device, dtype=torch.float32) / cell + float(offset[0])
    x = torch.arange(w, device=device, dtype=torch.float32) / cell + float(offset[1])
    y0, x0 = y.floor().long(), x.floor().long()
    fy, fx = y - y0, x - x0

    def fade(t):
        return t * t * t * (t * (t * 6 - 15) + 10)

    u, v = fade(fx), fade(fy)  # the sum over the columns on the lattice's rows first, then the rows' gather
    gx0, gx1, gy0, gy1 = (g.index_select(1, x0 + d) for g in (gx, gy) for d in (0, 1))
    along, across = gx0 * ((1 - u) * fx) + gx1 * (u * (fx - 1)), gy0 * (1 - u) + gy1 * u
    v, fy = v[:, None], fy[:, None]
    a0, a1, c0, c1 = (g.index_select(0, y0 + d) for g in (along, across) for d in (0, 1))
    total = a0 * (1 - v) + c0 * ((1 - v) * fy) + a1 * v + c1 * (v * (fy - 1))
    return total * math.sqrt(2)


def fractal(shape: tuple[int, int], cell_px: float, octaves: int, rng: np.random.Generator, device) -> torch.Tensor:
    """:func:`imaging.noise.fractal_noise` on ``device``: octaves of half the cell and amplitude,
    evaluated on a grid ``SAMPLES_PER_CELL`` samples per finest cell, resized bilinearly with
    coarse sample i at pixel i·step, normalised to max |·| 1 (float32 (H, W))."""
    h, w = shape
    step = max(int(cell_px / 2 ** (octaves - 1) / SAMPLES_PER_CELL), 1)
    coarse = (-(-h // step) + 1, -(-w // step) + 1)
    total = sum(0.5**k * perlin(coarse, cell_px / 2**k / step, rng, device) for k in range(octaves))
    if step > 1:
        size = ((coarse[0] - 1) * step + 1, (coarse[1] - 1) * step + 1)
        total = F.interpolate(total[None, None], size=size, mode="bilinear", align_corners=True)[0, 0]
    total = total[:h, :w]
    return total / total.abs().amax().clamp_min(1e-12)


@dataclass(frozen=True)
class Shapes:
    """A scene's occluding shapes, in occlusion order (the last on top), on the host: radius,
    centre row and column (pixels), kind (0 ellipse, 1 rectangle, 2 stroke, 3 grating patch),
    orientation (rad), aspect (ellipse 0.4-1, rectangle 0.3-1 of r across), size (a stroke's
    half-width, a grating's period, px), colour (n, 3) linear RGB, texture amplitude, shading slope."""

    r: np.ndarray
    cy: np.ndarray
    cx: np.ndarray
    kind: np.ndarray
    angle: np.ndarray
    aspect: np.ndarray
    size: np.ndarray
    colour: np.ndarray
    texture: np.ndarray
    slope: np.ndarray

    def boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each shape's square box: its first row and column and its side (px), holding every
        pixel it covers: the rotated shape's half-extents along the rows and columns, the larger
        of the two, plus a pixel for the antialiased edge (half a pixel past the outline)."""
        c, s = np.abs(np.cos(self.angle)), np.abs(np.sin(self.angle))
        r, a, w = self.r, self.aspect, self.size
        extents = [  # (along the columns, along the rows) per kind
            (np.hypot(r * c, a * r * s), np.hypot(r * s, a * r * c)),  # ellipse
            (r * c + a * r * s, r * s + a * r * c),  # rectangle
            (3 * r * c + w * s, 3 * r * s + w * c),  # stroke
            (r, r),  # grating patch: its disc
        ]
        half = np.choose(self.kind, [np.maximum(*e) for e in extents]) + 1
        return np.floor(self.cy - half), np.floor(self.cx - half), np.floor(2 * half).astype(int) + 2


def draw_shapes(shape: tuple[int, int], side: float, detailed: tuple[int, int, int, int], rng) -> Shapes:
    """``design.scenes.procedural_scene``'s shapes, drawn as arrays: radii p(r) ∝ r^-(1 + a) from
    2 px to 0.4 × the field's ``side``, those under ``FINE_RADIUS_PX`` only in the ``detailed``
    region (top, left, bottom, right), the rest over the canvas; in random occlusion order."""
    h, w = shape
    top, left, bottom, right = detailed
    r_min, r_max, a = RADIUS_PX[0], RADIUS_PX[1] * side, RADIUS_EXPONENT
    split = min(max(FINE_RADIUS_PX, r_min), r_max)
    density = SHAPES_PER_256_SQUARE / 256**2 * rng.uniform(0.6, 1.4) / (r_min**-a - r_max**-a)
    r, cy, cx = [], [], []
    for lo, hi, (y0, x0, y1, x1) in ((r_min, split, (top, left, bottom, right)), (split, r_max, (0, 0, h, w))):
        count = int(density * (lo**-a - hi**-a) * (y1 - y0) * (x1 - x0))
        radii = (lo**-a - rng.uniform(size=count) * (lo**-a - hi**-a)) ** (-1 / a)
        r.append(radii)
        cy.append(rng.uniform(y0 - radii, y1 + radii))
        cx.append(rng.uniform(x0 - radii, x1 + radii))
    order = rng.permutation(sum(len(x) for x in r))  # occlusion order independent of size
    n = len(order)
    kind = np.searchsorted(np.cumsum(SHAPE_KINDS) / sum(SHAPE_KINDS), rng.random(n), side="right")
    aspect = np.where(kind == 0, rng.uniform(0.4, 1.0, n), rng.uniform(0.3, 1.0, n))
    size = np.where(kind == 2, rng.uniform(0.5, 1.5, n), rng.uniform(2.0, 10.0, n))
    return Shapes(
        *(np.concatenate(x)[order] for x in (r, cy, cx)),
        kind,
        rng.uniform(0, np.pi, n),
        aspect,
        size,
        colours(rng, n),
        rng.uniform(0, TEXTURE, n),
        rng.uniform(-0.3, 0.3, n),
    )


def _coverage(shapes: Shapes, index: np.ndarray, origin: np.ndarray, box: int, shape: tuple[int, int], device):
    """The boxes (len(index), box, box) of shapes ``index`` (one kind) from their first rows and
    columns ``origin`` (2, len(index)): their canvas pixel (H·W where outside the canvas or
    uncovered), coverage in 0..1 (1-px antialiased edges) and distance along the shape's axis (px;
    its shading ramp)."""
    h, w = shape
    params = np.stack(
        [
            shapes.r[index],
            shapes.cy[index],
            shapes.cx[index],
            shapes.angle[index],
            shapes.aspect[index],
            shapes.size[index],
        ]
    )
    r, cy, cx, angle, aspect, size = to_device(params, device)[:, :, None, None]
    i0, j0 = to_device(origin, device, torch.int64)[:, :, None, None]
    o = torch.arange(box, device=device)
    rows, cols = i0 + o[:, None], j0 + o
    dy, dx = rows - cy, cols - cx
    c, s = torch.cos(angle), torch.sin(angle)
    along, across = dx * c + dy * s, dy * c - dx * s
    kind = int(shapes.kind[index[0]])
    if kind == 0:  # ellipse; inside distance ≈ pixels to the edge
        inside = r - torch.sqrt(along**2 + (across / aspect) ** 2)
    elif kind == 1:  # rectangle
        inside = torch.minimum(r - along.abs(), aspect * r - across.abs())
    elif kind == 2:  # stroke of half-width size
        inside = torch.minimum(size - across.abs(), 3 * r - along.abs())
    else:  # grating patch of period size
        inside = torch.where(torch.sin(2 * math.pi * along / size) > 0, r - torch.hypot(along, across), -1.0)
    mask = (inside + 0.5).clamp(0, 1)
    on = (mask > 0) & (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    return torch.where(on, rows * w + cols, h * w), mask, along


def _samples(shapes: Shapes, shape: tuple[int, int], device):
    """Every shape's box pixels, flat: canvas pixel (H·W: none), occlusion rank, coverage and
    distance along its axis. Boxes are grouped by kind and by side, rounded up to one of
    ``BOX_SIDES`` (at most √2 larger), and evaluated ``CHUNK_SAMPLES`` box pixels at a time."""
    h, w = shape
    rows0, cols0, side = shapes.boxes()
    seen = (rows0 + side > 0) & (rows0 < h) & (cols0 + side > 0) & (cols0 < w)
    box = BOX_SIDES[np.searchsorted(BOX_SIDES, side)]
    parts = []
    for kind in range(4):
        for b in np.unique(box[seen & (shapes.kind == kind)]):
            members = np.flatnonzero(seen & (shapes.kind == kind) & (box == b))
            for chunk in np.array_split(members, min(len(members), -(-len(members) * b * b // CHUNK_SAMPLES))):
                pixel, mask, along = _coverage(
                    shapes, chunk, np.stack([rows0[chunk], cols0[chunk]]), int(b), shape, device
                )
                rank = to_device(chunk, device, torch.int64)[:, None, None].expand_as(pixel)
                parts.append((pixel.reshape(-1), rank.reshape(-1), mask.reshape(-1), along.reshape(-1)))
    if not parts:
        empty = torch.zeros(0, device=device)
        return empty.long(), empty.long(), empty, empty
    return tuple(torch.cat(x) for x in zip(*parts))


def composite(
    background: torch.Tensor, fine: torch.Tensor, shapes: Shapes, layers: int = LAYERS, drop: bool | None = None
) -> torch.Tensor:
    """The shapes painted over ``background`` (3, H, W) on its device, each pixel by its ``layers``
    topmost shapes down to the first that covers it whole (module docstring): shape k paints
    colour_k × coverage × (1 + texture_k × ``fine`` + slope_k × along / r_k) over what lies below,
    weighted by 1 − its coverage. ``drop`` (default: on a CPU) drops the samples no further layer
    can use as the layers are taken (boolean indexing, which reads a count back); else they stay,
    marked unused: the same image, nothing read back."""
    _, h, w = background.shape
    device, n = background.device, h * w
    pixel, rank, mask, along = _samples(shapes, (h, w), device)
    below = torch.where(pixel < n, rank, -1)
    drop = device.type == "cpu" if drop is None else drop

    def kept(keep, pixel, below, mask, along):
        if drop:
            return pixel[keep], below[keep], mask[keep], along[keep]
        return pixel, torch.where(keep, below, -1), mask, along

    pixel, below, mask, along = kept(below >= 0, pixel, below, mask, along)
    tops = []
    for _ in range(layers):
        top = torch.full((n + 1,), -1, dtype=torch.int64, device=device).scatter_reduce(0, pixel, below, "amax")
        over = top.index_select(0, pixel)  # the topmost shape left at each sample's pixel
        chosen = (below >= 0) & (below == over)
        at = torch.where(chosen, pixel, n)  # each pixel's chosen sample is unique; the rest land on the spare slot
        cover = torch.zeros(n + 1, device=device).scatter(0, at, torch.where(chosen, mask, 0.0))
        axis = torch.zeros(n + 1, device=device).scatter(0, at, torch.where(chosen, along, 0.0))
        tops.append((top[:n], cover[:n], axis[:n]))
        # below the chosen shape, unless it covers its pixel whole (then nothing below shows)
        pixel, below, mask, along = kept((below < over) & (cover.index_select(0, pixel) < 1), pixel, below, mask, along)
    table = to_device(np.column_stack([shapes.colour, shapes.texture, shapes.slope, np.maximum(shapes.r, 1.0)]), device)
    image, fine = background.reshape(3, n), fine.reshape(n)
    for top, cover, axis in reversed(tops):
        k = table.index_select(0, top.clamp_min(0))  # (n, 6): colour, texture, slope, max(r, 1)
        shade = 1 + k[:, 3] * fine + k[:, 4] * axis / k[:, 5]
        painted = k[:, :3].T * (cover * shade) + (1 - cover) * image
        image = torch.where(top >= 0, painted, image)
    return image.reshape(3, h, w)


def paint_every_shape(background: torch.Tensor, fine: torch.Tensor, shapes: Shapes) -> torch.Tensor:
    """:func:`composite` painting every shape in turn, bottom to top (one shape at a time: the slow
    exact path the layers are measured against)."""
    _, h, w = background.shape
    image, fine = background.reshape(3, h * w).clone(), fine.reshape(h * w)
    rows0, cols0, box = shapes.boxes()
    for k in range(len(shapes.r)):
        origin = np.array([[rows0[k]], [cols0[k]]])
        pixel, mask, along = (
            x.reshape(-1) for x in _coverage(shapes, np.array([k]), origin, int(box[k]), (h, w), image.device)
        )
        on = pixel < h * w
        pixel, mask, along = pixel[on], mask[on], along[on]
        colour = to_device(shapes.colour[k], image.device)[:, None]
        shade = (
            1 + float(shapes.texture[k]) * fine[pixel] + float(shapes.slope[k]) * along / max(float(shapes.r[k]), 1.0)
        )
        image[:, pixel] = colour * (mask * shade) + (1 - mask) * image[:, pixel]
    return image.reshape(3, h, w)


def procedural_scene(shape: tuple[int, int], rng: np.random.Generator, margin: int, device) -> torch.Tensor:
    """A scene (3, H, W) in 0.002..1 with ``design.scenes.procedural_scene``'s statistics, on
    ``device``: a textured background under the occluding shapes of :func:`draw_shapes`, lit by a
    smooth illumination field spanning about a decade; detail finer than ``FINE_RADIUS_PX`` only
    within ``DETAIL_BAND_PX`` of the field (a canvas of ``margin`` pixels, ``imaging.canvas``)."""
    h, w = shape
    side = max(max(h, w) - 2 * int(margin), 1)
    band = max(int(margin) - DETAIL_BAND_PX, 0)
    detailed = (band, band, h - band, w - band)
    coarse = fractal((h, w), side / rng.uniform(2, 6), 3, rng, device)
    fine = F.pad(fractal((h - 2 * band, w - 2 * band), rng.uniform(4, 16), 3, rng, device), (band,) * 4)
    base = to_device(colours(rng, 1)[0], device)
    image = composite(base[:, None, None] * (1 + 0.4 * coarse + fine), fine, draw_shapes(shape, side, detailed, rng))
    light = 10 ** (LIGHT_DECADES * fractal((h, w), side / rng.uniform(1, 3), 2, rng, device))
    return (image * light).clamp(0.002, 1.0)


def soft_threshold(noise: torch.Tensor, coverage: float, edge: float) -> torch.Tensor:
    """:func:`imaging.obstructions._soft_threshold` on the device: smoothstep((noise − t)/edge + ½)
    with t bisected so that its mean over every 4th pixel per axis is ``coverage`` (no host read)."""
    sample = noise[::4, ::4]
    lo, hi = sample.amin() - edge, sample.amax() + edge
    for _ in range(30):
        t = 0.5 * (lo + hi)
        above = smoothstep((sample - t) / edge + 0.5).mean() > coverage
        lo, hi = torch.where(above, t, lo), torch.where(above, hi, t)
    return smoothstep((noise - 0.5 * (lo + hi)) / edge + 0.5)


def obstruction(
    kind: str,
    shape: tuple[int, int],
    margin: int,
    depth_m: float,
    focal_length_m: float,
    pitch_m: float,
    rng,
    params,
    device,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Dirt or a fence (``DEVICE_OBSTRUCTIONS``) on the canvas of ``margin`` around an H × W
    sensor, as ``imaging.obstructions.make_obstruction`` draws them from ``rng``, on ``device``:
    the radiance (3, H + 2M, W + 2M), 0 where nothing obstructs, and the coverage (1, H + 2M, W + 2M)."""
    canvas = (shape[0] + 2 * margin, shape[1] + 2 * margin)

    def px(size_m):
        return feature_px(kind, size_m, focal_length_m, depth_m, pitch_m, canvas)

    if kind == "dirt":
        target = rng.uniform(*params.dirt_coverage)
        mask = soft_threshold(
            fractal(canvas, px(params.dirt_scale_m), params.dirt_octaves, rng, device), target, params.dirt_edge
        )
        shade = 0.7 + 0.3 * fractal(canvas, px(params.dirt_scale_m) / 4, 3, rng, device)  # mottled
        rgb = to_device(DIRT_RGB, device)[:, None, None] * shade
    elif kind == "fence":
        pitch, width = px(params.fence_pitch_m), px(params.fence_width_m)
        y = torch.arange(canvas[0], device=device, dtype=torch.float32)[:, None]
        x = torch.arange(canvas[1], device=device, dtype=torch.float32)
        mask = torch.zeros(canvas, device=device)
        for sign in (1, -1):
            a = math.radians(sign * params.fence_angle_deg)
            s = x * math.cos(a) + y * math.sin(a) + float(rng.uniform(0, pitch))
            wire = (width / 2 - ((s % pitch) - pitch / 2).abs() + 0.5).clamp(0, 1)
            mask = 1 - (1 - mask) * (1 - wire)
        grey = 0.12 + 0.04 * torch.cos(torch.linspace(0, 2 * math.pi, canvas[1], device=device))  # metallic shading
        rgb = grey.expand(3, *canvas)
    else:
        raise ValueError(f"{kind!r} is drawn on the host (device kinds: {', '.join(DEVICE_OBSTRUCTIONS)})")
    mask = mask.clamp(0, 1)
    return torch.where(mask > 0, rgb, 0.0), mask[None]


def device_batch(preset, seed: int, step: int, indices: list[int], z_near_m: float, margin: int, device) -> tuple:
    """Clean scenes, obstruction colours and masks (B, C, H + 2M, W + 2M) of batch entries
    ``indices`` of ``step``, drawn on ``device`` from the entries' (seed, step, index) streams
    (those ``design.step.step_batch`` draws the host's from)."""
    n, kinds = preset.sensor.pixels, preset.optimize.obstructions
    canvas = (n + 2 * margin, n + 2 * margin)
    clean, colour, mask = [], [], []
    for i in indices:
        kind = kinds[np.random.default_rng([seed, step, i, 13]).integers(len(kinds))]
        clean.append(procedural_scene(canvas, np.random.default_rng([seed, step, i, 11]), margin, device))
        rgb, m = obstruction(
            kind,
            (n, n),
            margin,
            z_near_m,
            preset.lens.focal_length_m,
            preset.sensor.pixel_pitch_m,
            np.random.default_rng([seed, step, i, 17]),
            preset.obstruction,
            device,
        )
        colour.append(rgb)
        mask.append(m)
    return tuple(torch.stack(x) for x in (clean, colour, mask))
