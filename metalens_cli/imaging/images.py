"""Clean images: read a folder (PNG/JPEG/TIFF/EXR), fit to the sensor, sRGB ↔ linear.

Arrays are float (C, H, W) in 0..1 (EXR: linear, unclipped). 8/16-bit files are sRGB-encoded
and decoded to linear light with colour-science (imported lazily: it takes seconds).

Built-in source (``builtin``, no download): the photograph ``grace_hopper.jpg`` shipped in
matplotlib's sample data, when the installed matplotlib has it, followed by two procedural
textures generated here (a colour checker with fine bars, and smooth colour noise with edges).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError

SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")
BUILTIN = "builtin"


@dataclass(frozen=True)
class CleanImage:
    """A clean scene: ``name`` (file stem), ``linear`` (3, H, W) float32 linear RGB."""

    name: str
    linear: np.ndarray


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded 0..1 → linear (colour-science's ``cctf_decoding``)."""
    import colour

    return np.asarray(colour.cctf_decoding(np.clip(values, 0.0, 1.0), function="sRGB"), dtype=np.float32)


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """Linear → sRGB-encoded 0..1, clipped (colour-science's ``cctf_encoding``), for display."""
    import colour

    return np.asarray(colour.cctf_encoding(np.clip(values, 0.0, 1.0), function="sRGB"), dtype=np.float32)


def read_image(path: Path, keep_alpha: bool = False) -> tuple[np.ndarray, bool]:
    """(C, H, W) float in 0..1 as stored (sRGB-encoded for 8/16-bit, linear for EXR), RGB[A]
    order; returns (array, has_alpha). Greyscale is repeated to 3 channels."""
    path = Path(path)
    if path.suffix.lower() == ".exr":
        from metalens_cli.io.image_files import read_exr_rgb

        return read_exr_rgb(path), False
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError(str(path), "not a readable image", "PNG, JPEG, TIFF or EXR")
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(raw.dtype, 1.0)
    image = raw.astype(np.float32) / scale
    if image.ndim == 2:
        image = image[:, :, None].repeat(3, axis=2)
    has_alpha = image.shape[2] == 4
    channels = [2, 1, 0] + ([3] if has_alpha and keep_alpha else [])
    return np.transpose(image[:, :, channels], (2, 0, 1)), has_alpha and keep_alpha


def fit_to_sensor(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Scale (C, H, W) so it covers ``shape`` (area resampling), then centre-crop to it."""
    import cv2

    h, w = shape
    _, ih, iw = image.shape
    scale = max(h / ih, w / iw)
    nh, nw = max(h, round(ih * scale)), max(w, round(iw * scale))
    hwc = np.ascontiguousarray(np.transpose(image, (1, 2, 0)))
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
    resized = cv2.resize(hwc, (nw, nh), interpolation=interpolation)
    if resized.ndim == 2:
        resized = resized[:, :, None]
    top, left = (nh - h) // 2, (nw - w) // 2
    return np.transpose(resized[top : top + h, left : left + w], (2, 0, 1)).astype(np.float32)


def procedural_images(shape: tuple[int, int]) -> list[CleanImage]:
    """Two deterministic test scenes in linear RGB: colour patches with fine bars, and colour noise."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    patches = np.stack([(np.floor(x * 6) % 3) / 2, (np.floor(y * 6) % 3) / 2, ((np.floor(x * 6) + np.floor(y * 6)) % 4) / 3])
    bars = 0.5 + 0.5 * np.sign(np.sin(2 * np.pi * x * (4 + 60 * y)))
    checker = 0.05 + 0.85 * np.where(y > 0.75, bars[None].repeat(3, 0), patches)
    rng = np.random.default_rng(2024)
    from metalens_cli.imaging.obstructions import fractal_noise

    cell = max(h, w) / 4
    noise = np.stack([fractal_noise((h, w), cell, 4, rng) for _ in range(3)])
    disk = (np.hypot(x - 0.5, y - 0.5) < 0.25).astype(float)
    smooth = np.clip(0.45 + 0.35 * noise + 0.25 * disk[None] * np.array([1.0, -0.3, -0.5])[:, None, None], 0.02, 1.0)
    return [CleanImage("checker", checker.astype(np.float32)), CleanImage("noise", smooth.astype(np.float32))]


def builtin_images(shape: tuple[int, int]) -> list[CleanImage]:
    """matplotlib's grace_hopper.jpg (if shipped), then the procedural scenes; see the module docstring."""
    images = []
    try:
        from matplotlib import cbook

        path = Path(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))
    except (ImportError, OSError, ValueError):
        path = None
    if path is not None and path.is_file():
        images.append(_load(path, shape))
    return images + procedural_images(shape)


def _load(path: Path, shape) -> CleanImage:
    image, _ = read_image(path)
    image = fit_to_sensor(image[:3], shape)
    linear = image if path.suffix.lower() == ".exr" else srgb_to_linear(image)
    return CleanImage(path.stem, np.asarray(linear, dtype=np.float32))


def load_images(source: str | Path | None, shape: tuple[int, int], limit: int | None = None) -> list[CleanImage]:
    """Clean images for an H × W sensor from a folder (sorted by name), one file, or ``builtin``/None."""
    if source is None or str(source) == BUILTIN:
        images = builtin_images(shape)
    else:
        path = Path(source)
        if path.is_file():
            files = [path]
        elif path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in SUFFIXES and not p.name.startswith("."))
        else:
            raise InputError("--images", f"no such folder {str(source)!r}", f"a folder of {', '.join(SUFFIXES)} images, or builtin")
        if not files:
            raise InputError("--images", f"{str(source)!r} holds no images", f"files ending in {', '.join(SUFFIXES)}")
        images = [_load(p, shape) for p in files[: limit or None]]
    return images[: limit or None]
