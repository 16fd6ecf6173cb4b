"""Near obstructions on the cover glass: dirt, fences, blood drops, raindrops, or an RGBA file.

Every generator returns an :class:`Obstruction` on the canvas (``imaging.canvas``): ``rgb``
(3, H + 2M, W + 2M) linear radiance (0 where nothing is), ``mask`` (1, H + 2M, W + 2M) coverage m
in 0..1 (soft edges, semi-opaque drops), float32 numpy. Generators are seeded (the same seed gives the same obstruction)
and depth-aware: a feature of ``s`` metres on the cover glass at depth ``z`` spans s·f/z/pitch pixels on the
sensor (:func:`pixels_from_metres`). Rain needs the clean image, which its drops refract.

Parameters come from a preset's ``[obstruction]`` section (:class:`ObstructionConfig`, whose defaults are for the
paper's camera (f = 4 mm, 1.85 µm pixels, z ≈ 45 mm: 1 mm on the glass ≈ 48 pixels, the 512-pixel sensor sees ≈ 10.7 mm
of glass)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.constants import OBSTRUCTION_KINDS
from metalens_cli.errors import InputError
from metalens_cli.imaging.canvas import fit_to_canvas, sensor_crop
from metalens_cli.imaging.noise import fractal_noise, sampled_fractal_noise
from metalens_cli.imaging.sample_grid import SampleGrid
from metalens_cli.io.presets import ObstructionConfig

FORM = "dirt, fence, drops, rain or file:PATH.png"


@dataclass(frozen=True)
class Obstruction:
    """An obstruction on a canvas of ``margin`` pixels (``imaging.canvas``): ``rgb``
    (3, H + 2M, W + 2M), ``mask`` (1, H + 2M, W + 2M), both float32 in 0..1."""

    kind: str
    rgb: np.ndarray
    mask: np.ndarray
    depth_m: float
    settings: dict
    margin: int = 0

    @property
    def sensor_rgb(self) -> np.ndarray:
        """``rgb`` cropped to the sensor's field: (3, H, W)."""
        return sensor_crop(self.rgb, self.margin)

    @property
    def sensor_mask(self) -> np.ndarray:
        """``mask`` cropped to the sensor's field: (1, H, W)."""
        return sensor_crop(self.mask, self.margin)

    @property
    def coverage(self) -> float:
        """Mean coverage over the sensor's field."""
        return float(self.sensor_mask.mean())


MIN_FEATURE_PX = 0.05  # finer obstruction features than this alias into noise
MAX_FEATURE_CANVASES = 100  # coarser than this many canvas widths: uniform, and costly to draw


def pixels_from_metres(size_m: float, focal_length_m: float, depth_m: float, pixel_pitch_m: float) -> float:
    """Sensor pixels spanned by a feature of ``size_m`` metres at depth ``depth_m``: s·f/z/pitch."""
    return size_m * focal_length_m / depth_m / pixel_pitch_m


def feature_px(
    spec: str, size_m: float, focal_length_m: float, depth_m: float, pixel_pitch_m: float, canvas: tuple[int, int]
) -> float:
    """Sensor pixels spanned by a ``size_m`` feature of obstruction ``spec`` at ``depth_m``
    (:func:`pixels_from_metres`); an error unless ``MIN_FEATURE_PX`` to ``MAX_FEATURE_CANVASES``
    of the ``canvas``'s longer side."""
    size = pixels_from_metres(size_m, focal_length_m, depth_m, pixel_pitch_m)
    if not MIN_FEATURE_PX <= size <= MAX_FEATURE_CANVASES * max(canvas):
        raise InputError(
            "--z-near",
            f"a {size_m * 1e3:g} mm {spec} feature at {depth_m * 1e3:g} mm spans {size:.3g} pixels "
            f"(f {focal_length_m * 1e3:g} mm, pitch {pixel_pitch_m * 1e6:g} µm)",
            f"a geometry where obstruction features span {MIN_FEATURE_PX}-{MAX_FEATURE_CANVASES} canvases of pixels",
        )
    return size


DIRT_RGB = (0.20, 0.12, 0.05)  # linear RGB of dry soil


def smoothstep(t):
    """3t² − 2t³ of ``t`` clipped to 0..1 (a numpy array or a torch tensor)."""
    t = t.clip(0.0, 1.0)
    return t * t * (3 - 2 * t)


def _soft_threshold(noise: np.ndarray, coverage: float, edge: float, sample: np.ndarray | None = None) -> np.ndarray:
    """Soft mask smoothstep((noise − t)/edge + ½) with t chosen by bisection so that its mean over
    ``sample`` (a uniform sample of the canvas's noise; default every 4th pixel per axis: within
    ~1 % of the full mean for noise smooth over several pixels, 16× cheaper) is ``coverage``."""
    if sample is None:
        sample, lo, hi = noise[::4, ::4], float(noise.min()), float(noise.max())
    else:
        lo, hi = float(sample.min()), float(sample.max())
    lo, hi = lo - edge, hi + edge
    for _ in range(30):
        t = 0.5 * (lo + hi)
        mean = smoothstep((sample - t) / edge + 0.5).mean()
        lo, hi = (t, hi) if mean > coverage else (lo, t)
    return smoothstep((noise - 0.5 * (lo + hi)) / edge + 0.5)


def dirt(
    shape, scale_px: float, rng: np.random.Generator, p: ObstructionConfig, grid: SampleGrid | None = None
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Brownish dirt: fractal Perlin noise thresholded to a coverage drawn in ``p.dirt_coverage``;
    at ``grid``'s samples (``imaging.sample_grid``) when given, else at every pixel."""
    target = rng.uniform(*p.dirt_coverage)
    if grid is None:
        noise, sample = fractal_noise(shape, scale_px, p.dirt_octaves, rng), None
    else:
        noise, sample = sampled_fractal_noise(shape, scale_px, p.dirt_octaves, rng, grid.at)
    mask = _soft_threshold(noise, target, p.dirt_edge, sample)
    shade = 0.7 + 0.3 * fractal_noise(shape, scale_px / 4, 3, rng, at=None if grid is None else grid.at)  # mottled
    brown = np.array(DIRT_RGB)[:, None, None]
    return brown * shade[None], mask, {"target_coverage": target, "cell_px": scale_px}


def fence(
    shape, pitch_px: float, width_px: float, angle_deg: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Two families of periodic wires at ±angle, random phase; anti-aliased (1-pixel soft) edges."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w].astype(float)
    mask = np.zeros(shape)
    for sign in (1, -1):
        a = math.radians(sign * angle_deg)
        s = x * math.cos(a) + y * math.sin(a) + rng.uniform(0, pitch_px)
        distance = np.abs((s % pitch_px) - pitch_px / 2)  # distance to the wire centre line
        wire = np.clip(width_px / 2 - distance + 0.5, 0, 1)
        mask = 1 - (1 - mask) * (1 - wire)
    grey = 0.12 + 0.04 * np.cos(np.linspace(0, 2 * math.pi, w))[None, :]  # slight metallic shading
    return (
        np.broadcast_to(grey, shape)[None].repeat(3, 0),
        mask,
        {"pitch_px": pitch_px, "width_px": width_px, "angle_deg": angle_deg},
    )


def _disks(shape, radius_px: tuple[float, float], coverage: float, rng: np.random.Generator):
    """Add random soft disks until the union covers ``coverage``; yields the disk list and mask."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w].astype(float)
    mask = np.zeros(shape)
    disks = []
    for _ in range(10_000):
        if mask.mean() >= coverage:
            break
        r = rng.uniform(*radius_px)
        cy, cx = rng.uniform(-r, h + r), rng.uniform(-r, w + r)
        d = np.hypot(y - cy, x - cx)
        disk = np.clip(r - d + 0.5, 0, 1)
        mask = np.maximum(mask, disk)
        disks.append((cy, cx, r))
    return disks, mask


def drops(shape, radius_px, rng, p: ObstructionConfig):
    """Semi-opaque red blood drops, darker at the centre, covering a fraction in ``p.drop_coverage``."""
    target = rng.uniform(*p.drop_coverage)
    disks, mask = _disks(shape, radius_px, target, rng)
    rgb = np.broadcast_to(np.array([0.30, 0.015, 0.012])[:, None, None], (3, *shape)).copy()
    return rgb, mask * p.drop_opacity, {"target_coverage": target, "drops": len(disks), "opacity": p.drop_opacity}


def rain(shape, radius_px, clean: np.ndarray, rng, p: ObstructionConfig):
    """Clear raindrops: each drop shows the background refracted (inverted and minified, as a
    ball lens does) and slightly brightened at the rim; mask = the drops' footprint."""
    target = rng.uniform(*p.rain_coverage)
    disks, mask = _disks(shape, radius_px, target, rng)
    h, w = shape
    rgb = np.zeros((3, h, w))
    y, x = np.mgrid[0:h, 0:w].astype(float)
    for cy, cx, r in disks:
        inside = np.hypot(y - cy, x - cx) <= r + 1
        if not inside.any():
            continue
        # inverted view of a region 4 radii wide around the drop
        sy = np.clip(cy - (y[inside] - cy) * 4, 0, h - 1).astype(int)
        sx = np.clip(cx - (x[inside] - cx) * 4, 0, w - 1).astype(int)
        rim = np.hypot(y[inside] - cy, x[inside] - cx) / r
        rgb[:, inside] = clean[:, sy, sx] * (0.9 + 0.3 * np.clip(rim, 0, 1) ** 4)
    return rgb, mask, {"target_coverage": target, "drops": len(disks)}


def from_file(path: str, shape, margin: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """An RGBA PNG as the obstruction: sRGB colour decoded to linear, alpha as the mask
    (no alpha channel: mask = 1 wherever a pixel is not black); scaled to cover the sensor, on
    the canvas as a scene file is (``imaging.canvas.fit_to_canvas``)."""
    from metalens_cli.imaging.images import read_image
    from metalens_cli.io.image_files import srgb_to_linear

    image, has_alpha = read_image(Path(path), keep_alpha=True)
    image = fit_to_canvas(image, shape, margin)
    rgb = srgb_to_linear(image[:3])
    mask = image[3:4] if has_alpha else (image[:3].max(axis=0, keepdims=True) > 0).astype(float)
    return rgb, mask[0], {"file": str(path)}


def make_obstruction(
    spec: str,
    shape: tuple[int, int],
    depth_m: float,
    focal_length_m: float,
    pixel_pitch_m: float,
    seed: int | np.random.Generator,
    *,
    params: ObstructionConfig | None = None,
    clean: np.ndarray | None = None,
    margin: int = 0,
    grid: SampleGrid | None = None,
) -> Obstruction:
    """Generate obstruction ``spec`` (``dirt``, ``fence``, ``drops``, ``rain`` or ``file:PATH``) for
    an H × W sensor on a canvas of ``margin`` pixels, at ``depth_m`` in front of a lens of focal
    length ``focal_length_m``; generators fill the whole canvas. ``grid``: where dirt is evaluated
    on the canvas (``imaging.sample_grid``; the other kinds are drawn at every pixel).

    ``clean`` (3, H + 2M, W + 2M) linear is needed by ``rain``. Same seed → the same obstruction.
    """
    p = params or ObstructionConfig()
    rng = np.random.default_rng(seed)
    if not (depth_m > 0 and math.isfinite(depth_m)):
        raise InputError("--z-near", f"{depth_m!r}", "a finite positive depth")

    sensor = tuple(int(v) for v in shape)
    shape = (sensor[0] + 2 * margin, sensor[1] + 2 * margin)

    def px(size_m):
        return feature_px(spec, size_m, focal_length_m, depth_m, pixel_pitch_m, shape)

    grid = grid if spec == "dirt" and grid is not None and not grid.whole else None
    if spec == "dirt":
        rgb, mask, info = dirt(shape, px(p.dirt_scale_m), rng, p, grid)
    elif spec == "fence":
        rgb, mask, info = fence(shape, px(p.fence_pitch_m), px(p.fence_width_m), p.fence_angle_deg, rng)
    elif spec == "drops":
        rgb, mask, info = drops(shape, tuple(px(r) for r in p.drop_radius_m), rng, p)
    elif spec == "rain":
        if clean is None:
            raise InputError("--obstruction", "rain needs the clean image it refracts", "a clean image")
        rgb, mask, info = rain(shape, tuple(px(r) for r in p.rain_radius_m), np.asarray(clean), rng, p)
    elif spec.startswith("file:"):
        rgb, mask, info = from_file(spec[5:], sensor, margin)
    else:
        raise InputError("--obstruction", f"unknown obstruction {spec!r}", FORM)
    mask = np.clip(mask, 0.0, 1.0)
    rgb = np.where(mask[None] > 0, rgb, 0.0).astype(np.float32)  # I_obs = 0 where nothing obstructs
    mask = mask[None].astype(np.float32)
    if grid is not None:
        rgb, mask = grid.canvas(rgb), grid.canvas(mask)
    return Obstruction(spec, rgb, mask, depth_m, info, margin)


def parse_obstructions(text: str) -> list[str]:
    """``dirt,fence`` → ["dirt", "fence"]; each checked (files must exist)."""
    specs = [part.strip() for part in str(text).split(",") if part.strip()]
    if not specs:
        raise InputError("--obstruction", "empty", FORM)
    for spec in specs:
        if spec.startswith("file:"):
            if not Path(spec[5:]).is_file():
                raise InputError(
                    "--obstruction", f"no such file {spec[5:]!r}", "file:PATH.png with an existing RGBA image"
                )
        elif spec not in OBSTRUCTION_KINDS:
            raise InputError("--obstruction", f"unknown obstruction {spec!r}", FORM)
    return specs


__all__ = ["Obstruction", "make_obstruction", "parse_obstructions", "pixels_from_metres"]
