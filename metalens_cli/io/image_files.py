"""Image files: linear RGB written as EXR (float32, ZIP, atomic) and display images as 8-bit PNG
(atomic); :func:`read_image_file`, the one reader of every image the tool takes as input; the
sRGB transfer functions (colour-science's) between encoded files and linear light.

Written arrays are (3, H, W) or (1, H, W) float, channel order R, G, B.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io.atomic import atomic_write
from metalens_cli.io.input_files import check_image_size, library_output, open_exr, regular_file


def srgb_to_linear(values: np.ndarray, dtype=np.float32) -> np.ndarray:
    """sRGB-encoded 0..1 (clipped) → linear, IEC 61966-2-1's piecewise curve in float64 (the
    values of colour-science's ``cctf_decoding``, tests/io/test_image_files.py, without its
    per-call overhead: procedural scenes decode hundreds of single colours a step)."""
    x = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 12.92 * 0.0031308, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(
        dtype
    )  # the curves meet there


def linear_to_srgb(values: np.ndarray, dtype=np.float32) -> np.ndarray:
    """Linear 0..1 (clipped) → sRGB-encoded, for display (IEC 61966-2-1, as colour-science's
    ``cctf_encoding``)."""
    x = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055).astype(dtype)


def srgb_encode_tensor(x):
    """The sRGB encoding of a torch tensor of linear values, differentiable, unclipped (the
    linear toe continues below 0): for losses on displayed values, where colour-science's
    numpy ``cctf_encoding`` cannot carry gradients. Same formula (IEC 61966-2-1)."""
    return (12.92 * x).where(x <= 0.0031308, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)


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
    """(3, H, W) float32 from an EXR's R, G, B channels (or its one channel repeated), values as
    stored (this tool's own outputs; inputs go through :func:`read_image_file`). C-contiguous: numpy
    sums a strided float32 view without pairwise summation (a 512² plane's mean 1e-3 off)."""
    pixels, _ = _exr_pixels(regular_file(path, str(path), "an EXR image"), str(path))
    rgb = pixels[:, :, :3] if pixels.shape[2] >= 3 else pixels[:, :, [0, 0, 0]]
    return np.ascontiguousarray(np.transpose(rgb, (2, 0, 1)))


def read_image_file(path: Path, field: str) -> tuple[np.ndarray, list[str], bool]:
    """The one reader of image files: (H, W, C) float32 pixels, their channel names and whether
    they are linear.

    PNG, JPEG, TIFF: 8- or 16-bit, scaled to 0..1 as encoded (not linear); C = 1 ("Y"), 3
    ("R", "G", "B") or 4 (with "A"). EXR: float channels R, G, B (and A) or a single channel,
    linear. The header is checked against the pixel limit before decoding; NaN, infinite or
    negative pixels, other depths and channel counts are an :class:`InputError` naming ``field``.
    """
    pixels, names, full_scale = read_image_codes(path, field)
    if full_scale is None:
        return pixels, names, True
    return pixels / np.float32(full_scale), names, False


def check_image_file(path: Path, field: str) -> None:
    """Refuse an image file that is not one, or is over the pixel limit, reading only its header
    where the header says so (the pixels are decoded only when the header cannot be parsed)."""
    path = regular_file(path, field, "an image file")
    if check_image_size(path, field) == (0, 0):
        read_image_codes(path, field)


def read_image_codes(path: Path, field: str) -> tuple[np.ndarray, list[str], float | None]:
    """:func:`read_image_file` without the scaling: (H, W, C) float32 pixels as stored (the
    integer codes 0..255 or 0..65535 of PNG, JPEG, TIFF; EXR floats), the channel names and the
    full-scale code (255.0, 65535.0; None for EXR), e.g. to find saturated pixels of a frame."""
    path = regular_file(path, field, "an image file")
    check_image_size(path, field)
    if path.suffix.lower() == ".exr":
        pixels, names = _exr_pixels(path, field)
        if not np.all(np.isfinite(pixels)) or pixels.min() < 0:
            raise InputError(
                field, f"{path.name} holds NaN, infinite or negative pixels", "finite, non-negative pixel values"
            )
        return pixels, names, None
    import cv2

    with library_output() as said:  # OpenCV and libpng report to stderr: quote them instead
        try:
            raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            raw, said.text = None, str(exc)
    if raw is None:
        reason = next((line.strip() for line in reversed(said.text.splitlines()) if line.strip()), "")
        raise InputError(
            field,
            f"{path.name} is not a readable image" + (f" ({reason[:120]})" if reason else ""),
            "a PNG, JPEG, TIFF or EXR image",
        )
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(raw.dtype)
    if scale is None:
        raise InputError(
            field, f"{path.name} has {raw.dtype} pixels", "8- or 16-bit integer pixels (or an EXR for floats)"
        )
    if raw.ndim == 2:
        return raw[:, :, None].astype(np.float32), ["Y"], scale
    if raw.ndim != 3 or raw.shape[2] not in (3, 4):
        raise InputError(
            field,
            f"{path.name} has {raw.shape[2] if raw.ndim == 3 else raw.ndim} channels",
            "1 or 3 channels (or 4 with alpha)",
        )
    order = [2, 1, 0, 3][: raw.shape[2]]  # OpenCV's BGR(A) → RGB(A)
    return raw[:, :, order].astype(np.float32), ["R", "G", "B", "A"][: raw.shape[2]], scale


def _exr_pixels(path: Path, field: str) -> tuple[np.ndarray, list[str]]:
    channels = {name: channel.pixels for name, channel in open_exr(path, field, "an RGB EXR image").channels().items()}
    names = ["R", "G", "B"] + (["A"] if "A" in channels else [])
    if not all(c in channels for c in "RGB"):
        if len(channels) != 1:
            raise InputError(
                field, f"{path.name} has channels {sorted(channels)[:6]}", "R, G, B channels or a single channel"
            )
        names = ["Y"]
        channels = {"Y": next(iter(channels.values()))}
    return np.stack([channels[name] for name in names], axis=-1).astype(np.float32), names


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a (3 or 1, H, W) image already encoded for display (0..1, clipped) as 8-bit PNG."""
    image = np.clip(np.asarray(image, dtype=np.float32), 0.0, 1.0)
    write_encoded(path, np.round(np.transpose(image, (1, 2, 0)) * 255).astype(np.uint8))


def write_encoded(path: str | os.PathLike[str], pixels: np.ndarray) -> None:
    """Write (H, W, 3) RGB or (H, W, 1) pixels, uint8 or uint16, as the PNG or TIFF that
    ``path``'s suffix names, atomically. Encoded in memory and written by Python: OpenCV's own
    file writer reports a full disk or the file-size limit as a failed encoding and deletes the
    evidence."""
    import cv2

    bgr = pixels[:, :, ::-1] if pixels.shape[2] == 3 else pixels[:, :, 0]
    encoded, data = cv2.imencode(Path(path).suffix, np.ascontiguousarray(bgr))
    if not encoded:
        raise InputError(str(path), "cannot encode the image", "a path ending in .png or .tif")
    with atomic_write(Path(path)) as temporary:
        temporary.write_bytes(data.tobytes())
