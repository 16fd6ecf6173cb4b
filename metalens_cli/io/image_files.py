"""Linear RGB images as EXR (float32, ZIP, atomic) and display images as 8-bit PNG (atomic).

Arrays are (3, H, W) or (1, H, W) float, channel order R, G, B.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write


def write_exr_rgb(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a (C, H, W) float image (C = 3: R, G, B; C = 1: Y) as a float32 EXR, atomically."""
    import OpenEXR

    image = np.asarray(image, dtype=np.float32)
    names = ("R", "G", "B") if image.shape[0] == 3 else ("Y",)
    if image.ndim != 3 or image.shape[0] not in (1, 3):
        raise InputError(str(path), f"image of shape {image.shape}", "(3, H, W) or (1, H, W)")
    channels = {name: np.ascontiguousarray(plane) for name, plane in zip(names, image)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_write(path) as temporary:
        OpenEXR.File(header, channels).write(str(temporary))


def read_exr_rgb(path: str | os.PathLike[str]) -> np.ndarray:
    """(3, H, W) float32 from an EXR's R, G, B channels (or Y repeated)."""
    import OpenEXR

    try:
        exr = OpenEXR.File(str(path), separate_channels=True)
    except RuntimeError as error:
        raise InputError(str(path), "not a readable OpenEXR file", "an RGB EXR image") from error
    channels = {name: channel.pixels for name, channel in exr.channels().items()}
    if all(c in channels for c in "RGB"):
        return np.stack([channels[c] for c in "RGB"]).astype(np.float32)
    if "Y" in channels:
        return np.repeat(channels["Y"][None], 3, axis=0).astype(np.float32)
    raise InputError(str(path), f"channels {sorted(channels)}", "R, G, B (or Y) channels")


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a (3 or 1, H, W) image already encoded for display (0..1, clipped) as 8-bit PNG."""
    import cv2

    image = np.clip(np.asarray(image, dtype=np.float32), 0.0, 1.0)
    hwc = np.transpose(image, (1, 2, 0))
    hwc = hwc[:, :, ::-1] if hwc.shape[2] == 3 else hwc[:, :, 0]
    with atomic_write(Path(path)) as temporary:
        if not cv2.imwrite(str(temporary), np.round(hwc * 255).astype(np.uint8)):
            raise InputError(str(path), "cannot write PNG", "a writable path ending in .png")
