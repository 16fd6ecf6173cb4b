"""The canvas: the sensor's field plus a margin of scene on every side (see ``imaging.formation``).

Arrays are (C, H + 2M, W + 2M) with the sensor's H × W field in the middle, M the margin in
pixels. Images from files are scaled so that the sensor's field is covered (as a camera would
frame them) and the canvas is the larger crop around it; only where the source is smaller than
the canvas is it extended by reflection.
"""

from __future__ import annotations

import numpy as np


def sensor_crop(canvas: np.ndarray, margin: int) -> np.ndarray:
    """The central sensor field of a (..., H + 2M, W + 2M) canvas."""
    if margin == 0:
        return canvas
    return canvas[..., margin:-margin, margin:-margin]


def narrow_margin(canvas, margin: int, to: int):
    """The central (..., H + 2m, W + 2m) of a (..., H + 2M, W + 2M) canvas of ``margin`` M:
    the canvas of margin m = ``to`` ≤ M around the same sensor field (numpy or torch; a view)."""
    if not 0 <= to <= margin:
        raise ValueError(f"a canvas of margin {margin} holds margins 0..{margin}, not {to}")
    cut = margin - to
    return canvas if cut == 0 else canvas[..., cut:-cut, cut:-cut]


def fit_to_canvas(image: np.ndarray, shape: tuple[int, int], margin: int = 0) -> np.ndarray:
    """(C, H0, W0) scaled so it covers ``shape`` = (H, W) (area resampling when shrinking, cubic
    when enlarging), then the (H + 2M, W + 2M) crop centred on it; reflected where too small."""
    import cv2

    h, w = shape
    _, ih, iw = image.shape
    nh, nw, top, left = fit_geometry((ih, iw), shape)
    scale = max(h / ih, w / iw)
    hwc = np.ascontiguousarray(np.transpose(image, (1, 2, 0)))
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC
    resized = cv2.resize(hwc, (nw, nh), interpolation=interpolation)
    if resized.ndim == 2:
        resized = resized[:, :, None]
    resized = np.transpose(resized, (2, 0, 1))
    top, left = top - margin, left - margin  # canvas corner in the resized image
    pad = [
        (0, 0),
        (max(-top, 0), max(top + h + 2 * margin - nh, 0)),
        (max(-left, 0), max(left + w + 2 * margin - nw, 0)),
    ]
    resized = np.pad(resized, pad, mode="symmetric")
    top, left = max(top, 0), max(left, 0)
    return np.ascontiguousarray(resized[:, top : top + h + 2 * margin, left : left + w + 2 * margin], dtype=np.float32)


def fit_geometry(source_hw: tuple[int, int], shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """How :func:`fit_to_canvas` frames an image of ``source_hw`` on a sensor of ``shape``: (nh, nw)
    the size it is resized to, and (top, left) the sensor's corner in the resized image (pixels)."""
    (ih, iw), (h, w) = source_hw, shape
    scale = max(h / ih, w / iw)
    nh, nw = max(h, round(ih * scale)), max(w, round(iw * scale))
    return nh, nw, (nh - h) // 2, (nw - w) // 2
