"""Clean images: read a folder (PNG/JPEG/TIFF/EXR), fit to the sensor, sRGB ↔ linear.

Arrays are float (C, H, W) in 0..1 (EXR: linear, unclipped). 8/16-bit files are sRGB-encoded
and decoded to linear light with colour-science (imported lazily: it takes seconds).

Built-in source (``builtin``, no download): the photographs shipped in matplotlib's sample data,
when the installed matplotlib has them, then seeded colour dead-leaves charts (the texture chart
of ISO 19567-2, with natural-image statistics) up to ``BUILTIN_COUNT`` images.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.imaging.canvas import fit_to_canvas, sensor_crop
from metalens_cli.io.image_files import read_image_file
from metalens_cli.io.input_files import IMAGE_SUFFIXES

BUILTIN = "builtin"
BUILTIN_COUNT = 24                                            # photographs + dead-leaves charts
LUMA_709 = (0.2126, 0.7152, 0.0722)  # Rec. 709 luminance weights of linear R, G, B
PHOTOGRAPHS = ("grace_hopper.jpg",)  # the photograph in matplotlib's sample data (its other images are drawings)


@dataclass(frozen=True)
class CleanImage:
    """A clean scene: ``name`` (file stem), ``linear`` (3, H + 2M, W + 2M) float32 linear RGB on
    a canvas of ``margin`` M pixels around the sensor's field."""

    name: str
    linear: np.ndarray
    margin: int = 0

    @property
    def sensor(self) -> np.ndarray:
        """The sensor's field (3, H, W)."""
        return sensor_crop(self.linear, self.margin)


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded 0..1 → linear (colour-science's ``cctf_decoding``)."""
    import colour

    return np.asarray(colour.cctf_decoding(np.clip(values, 0.0, 1.0), function="sRGB"), dtype=np.float32)


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """Linear → sRGB-encoded 0..1, clipped (colour-science's ``cctf_encoding``), for display."""
    import colour

    return np.asarray(colour.cctf_encoding(np.clip(values, 0.0, 1.0), function="sRGB"), dtype=np.float32)


def luminance(image: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance Y (H, W) of a (3, H, W) linear RGB image."""
    return np.tensordot(np.asarray(LUMA_709, dtype=image.dtype), image, axes=1)


def read_image(path: Path, keep_alpha: bool = False, field: str | None = None) -> tuple[np.ndarray, bool]:
    """(C, H, W) float in 0..1 as stored (sRGB-encoded for 8/16-bit, linear for EXR), RGB[A]
    order; returns (array, has_alpha). Greyscale is repeated to 3 channels. Errors name
    ``field`` (default: the path)."""
    path = Path(path)
    pixels, names, _ = read_image_file(path, field or str(path))
    rgb = pixels[:, :, [0, 0, 0]] if names[0] == "Y" else pixels[:, :, :3]
    has_alpha = keep_alpha and names[-1] == "A"
    image = np.concatenate([rgb, pixels[:, :, 3:]], axis=2) if has_alpha else rgb
    return np.transpose(image, (2, 0, 1)), has_alpha


def read_linear(path: Path, field: str = "INPUT") -> np.ndarray:
    """(3, H, W) float32 linear RGB of an image file (8/16-bit taken as sRGB-encoded, EXR as
    linear); NaN, infinite or negative pixels are an :class:`InputError` naming ``field``."""
    path = Path(path)
    image = read_image(path, field=field)[0]
    return image.astype(np.float32) if path.suffix.lower() == ".exr" else srgb_to_linear(image)


def builtin_images(shape: tuple[int, int], margin: int = 0, count: int = BUILTIN_COUNT) -> list[CleanImage]:
    """``count`` evaluation scenes: the photographs matplotlib ships (see ``PHOTOGRAPHS``), then
    seeded colour dead-leaves charts (``dead_leaves_NN``, seed NN), on the canvas of ``margin``."""
    from metalens_cli.imaging.dead_leaves import dead_leaves

    images = []
    for name in PHOTOGRAPHS:
        try:
            from matplotlib import cbook

            path = Path(cbook.get_sample_data(name, asfileobj=False))
        except (ImportError, OSError, ValueError):
            continue
        if path.is_file():
            images.append(_load(path, shape, margin))
    canvas = (shape[0] + 2 * margin, shape[1] + 2 * margin)
    for k in range(max(count - len(images), 0)):
        images.append(CleanImage(f"dead_leaves_{k:02d}", dead_leaves(canvas, k, sensor_shape=tuple(shape)), margin))
    return images[:count]


def _load(path: Path, shape, margin: int) -> CleanImage:
    image, _ = read_image(path)
    image = fit_to_canvas(image[:3], shape, margin)
    linear = image if path.suffix.lower() == ".exr" else srgb_to_linear(image)
    return CleanImage(path.stem, np.asarray(linear, dtype=np.float32), margin)


def load_images(source: str | Path | None, shape: tuple[int, int], limit: int | None = None, margin: int = 0) -> list[CleanImage]:
    """Clean images for an H × W sensor on a canvas of ``margin`` pixels (``imaging.canvas``):
    a folder (sorted by name), one file, or ``builtin``/None (:func:`builtin_images`)."""
    files = image_paths(source, limit)
    if files is None:
        return builtin_images(shape, margin)[: limit or None]
    return [_load(p, shape, margin) for p in files]


def image_paths(source: str | Path | None, limit: int | None = None) -> list[Path] | None:
    """The files :func:`load_images` reads (at most ``limit``), or None for the built-in scenes."""
    if source is None or str(source) == BUILTIN:
        return None
    if not str(source).strip():
        raise InputError("--images", "is empty", f"a folder of {', '.join(IMAGE_SUFFIXES)} images, one file, or builtin")
    path = Path(source)
    if path.is_file():
        files = [path]
    elif path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
    else:
        raise InputError("--images", f"no such folder {str(source)!r}", f"a folder of {', '.join(IMAGE_SUFFIXES)} images, or builtin")
    if not files:
        raise InputError("--images", f"{str(source)!r} holds no images", f"files ending in {', '.join(IMAGE_SUFFIXES)}")
    return files[: limit or None]


def image_count(source: str | Path | None, limit: int | None = None) -> int:
    """How many images :func:`load_images` will return."""
    files = image_paths(source, limit)
    return min(limit or BUILTIN_COUNT, BUILTIN_COUNT) if files is None else len(files)
