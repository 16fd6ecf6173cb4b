"""Clean images: read a folder (PNG/JPEG/TIFF/EXR), fit to the sensor, sRGB ↔ linear.

Arrays are float (C, H, W) in 0..1 (EXR: linear, unclipped). 8/16-bit files are sRGB-encoded
and decoded to linear light with colour-science (imported lazily: it takes seconds).

Built-in sets (no download; ``--images photos|charts|all``):

- ``photos``: the photographs shipped inside the scikit-image and matplotlib wheels
  (:data:`PHOTOGRAPHS`, each with its source and licence): the set lenses are judged on.
- ``charts``: ``CHART_COUNT`` seeded colour dead-leaves charts (the texture chart of ISO 19567-2).
- ``all``: both, photographs first.

The named sets take precedence over a folder of the same name (write ``./photos`` for the folder).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.imaging.canvas import fit_to_canvas, sensor_crop
from metalens_cli.io.image_files import read_image_file, srgb_to_linear
from metalens_cli.io.input_files import IMAGE_SUFFIXES, image_files

SETS = ("photos", "charts", "all")
CHART_COUNT = 24
LUMA_709 = (0.2126, 0.7152, 0.0722)  # Rec. 709 luminance weights of linear R, G, B


@dataclass(frozen=True)
class Photograph:
    """A photograph shipped in an installed package: ``package`` (import name), ``path`` inside
    it, who made it and under which licence, its size as shipped (rows, columns) and whether it
    is in colour (else grey)."""

    name: str
    package: str
    path: str
    source: str
    licence: str
    shape: tuple[int, int]
    colour: bool = True


PHOTOGRAPHS = (
    Photograph(
        "astronaut",
        "skimage",
        "data/astronaut.png",
        "Eileen Collins, NASA portrait (scikit-image sample data)",
        "public domain",
        (512, 512),
    ),
    Photograph(
        "chelsea", "skimage", "data/chelsea.png", "Stéfan van der Walt, a cat (scikit-image)", "CC0", (300, 451)
    ),
    Photograph(
        "coffee", "skimage", "data/coffee.png", "Rachel Michetti, a cup of coffee (scikit-image)", "CC0", (400, 600)
    ),
    Photograph(
        "rocket",
        "skimage",
        "data/rocket.jpg",
        "SpaceX, DSCOVR launch on Falcon 9 (scikit-image)",
        "public domain",
        (427, 640),
    ),
    Photograph(
        "grace_hopper",
        "matplotlib",
        "mpl-data/sample_data/grace_hopper.jpg",
        "US Navy portrait (matplotlib sample data)",
        "public domain",
        (600, 512),
    ),
    Photograph(
        "camera",
        "skimage",
        "data/camera.png",
        "Lav Varshney, a photographer outdoors (scikit-image)",
        "CC0",
        (512, 512),
        colour=False,
    ),
    Photograph(
        "brick",
        "skimage",
        "data/brick.png",
        "CC0Textures Bricks25, a brick wall (scikit-image)",
        "CC0",
        (512, 512),
        colour=False,
    ),
    Photograph(
        "grass",
        "skimage",
        "data/grass.png",
        "linolafett on DeviantArt, grass (scikit-image)",
        "CC0",
        (512, 512),
        colour=False,
    ),
    Photograph(
        "gravel",
        "skimage",
        "data/gravel.png",
        "CC0Textures Gravel04, gravel (scikit-image)",
        "CC0",
        (512, 512),
        colour=False,
    ),
)


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


def photograph_path(photo: Photograph) -> Path:
    """Where ``photo`` lies in its installed package (found without importing the package)."""
    spec = importlib.util.find_spec(photo.package)
    path = Path(spec.submodule_search_locations[0]) / photo.path if spec and spec.submodule_search_locations else None
    if path is None or not path.is_file():
        raise InputError(
            "--images",
            f"photos: {photo.name} is not in the installed {photo.package}",
            f"an installed {photo.package} that ships {photo.path} (pip install metalens's dependencies), or a folder",
        )
    return path


def chart(index: int, shape: tuple[int, int], margin: int = 0) -> CleanImage:
    """Dead-leaves chart number ``index`` (seed ``index``) for an H × W sensor on a canvas of ``margin``."""
    from metalens_cli.imaging.dead_leaves import dead_leaves

    canvas = (shape[0] + 2 * margin, shape[1] + 2 * margin)
    return CleanImage(f"dead_leaves_{index:02d}", dead_leaves(canvas, index, sensor_shape=tuple(shape)), margin)


def _load(path: Path, shape, margin: int, name: str | None = None) -> CleanImage:
    image, _ = read_image(path)
    image = fit_to_canvas(image[:3], shape, margin)
    linear = image if path.suffix.lower() == ".exr" else srgb_to_linear(image)
    return CleanImage(name or path.stem, np.asarray(linear, dtype=np.float32), margin)


def load_images(
    source: str | Path, shape: tuple[int, int], limit: int | None = None, margin: int = 0
) -> list[CleanImage]:
    """Clean images for an H × W sensor on a canvas of ``margin`` pixels (``imaging.canvas``):
    a named set (:data:`SETS`), a folder (sorted by name) or one file; at most ``limit``."""
    return [_entry_image(entry, shape, margin) for entry in image_entries(source, limit)]


def _entry_image(entry: Path | Photograph | int, shape, margin: int) -> CleanImage:
    if isinstance(entry, Photograph):
        return _load(photograph_path(entry), shape, margin, entry.name)
    if isinstance(entry, Path):
        return _load(entry, shape, margin)
    return chart(entry, shape, margin)


def image_entries(source: str | Path, limit: int | None = None) -> list[Path | Photograph | int]:
    """What :func:`load_images` reads, in order: files, :class:`Photograph` entries, chart indices."""
    text = str(source).strip()
    if text in SETS:
        photos = list(PHOTOGRAPHS) if text in ("photos", "all") else []
        charts = list(range(CHART_COUNT)) if text in ("charts", "all") else []
        return (photos + charts)[: limit or None]
    form = f"photos, charts, all, a folder of {', '.join(IMAGE_SUFFIXES)} images, or one file"
    if not text:
        raise InputError("--images", "is empty", form)
    path = Path(source)
    if path.is_file():
        files = [path]
    elif path.is_dir():
        files = image_files(path)
    else:
        raise InputError("--images", f"no such folder {text!r}", form)
    if not files:
        raise InputError("--images", f"{text!r} holds no images", f"files ending in {', '.join(IMAGE_SUFFIXES)}")
    return files[: limit or None]


def image_count(source: str | Path, limit: int | None = None) -> int:
    """How many images :func:`load_images` will return."""
    return len(image_entries(source, limit))
