"""Run the offline detectors on a capture and score them against the drawn targets.

A capture reaches a detector as a camera's image would: its linear RGB auto-levelled (the
``LEVELS`` percentiles of luminance to black and white, one gain for every channel), encoded
as sRGB and quantised to 8 bits, in grey. Markers: ``cv2.aruco`` (dictionary
``targets.MARKER_DICTIONARY``, sub-pixel corner refinement); QR codes: ``cv2.QRCodeDetector``
(detect and decode, several per image) on the image upsampled ``QR_UPSAMPLE`` × (bicubic). On the
photographs' clean targets at 512² (18 units), the decoder reads the codes of 1.97 px modules
0/18 times at the sensor's own sampling, 12/18 at 2 ×, 18/18 at 2.5 × (and 3 ×, at 1.6 × its time).

A target is **found** when a detection carries its key and its corners lie within
``max(MIN_TOLERANCE_PX, TOLERANCE × side)`` of the truth (mean over the four corners, at the
best cyclic order of the detection's corners). Every other detection is **wrong**: a key drawn
nowhere, a second detection of a key, or a right key in the wrong place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metalens_cli.imaging.images import luminance
from metalens_cli.imaging.targets import MARKER_DICTIONARY, Target
from metalens_cli.io.image_files import linear_to_srgb

LEVELS = (0.5, 99.5)  # auto-levels: these luminance percentiles map to black and white
TOLERANCE = 0.1  # corner tolerance, a fraction of the code's side
MIN_TOLERANCE_PX = 2.0
QR_UPSAMPLE = 2.5
# seconds to score one capture per megapixel on 2 CPU cores (benchmarks/bench_tasks.py, docs/benchmarks.md)
SECONDS_PER_MEGAPIXEL = {"markers": 0.06, "qr": 0.6}


@dataclass(frozen=True)
class Detection:
    """One detector output: ``task``, ``key`` (marker ID as text or decoded payload) and ``corners``
    (4, 2) in sensor pixels."""

    task: str
    key: str
    corners: np.ndarray


@dataclass(frozen=True)
class Outcome:
    """One capture scored on one task: per target (in the layout's order) ``found`` and
    ``corner_error_px`` (NaN where not found), and ``wrong`` detections."""

    found: np.ndarray
    corner_error_px: np.ndarray
    wrong: int


def _levelled8(values: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``values`` auto-levelled by the ``LEVELS`` percentiles of luminance ``y``, sRGB, 8 bits."""
    lo, hi = np.percentile(y, LEVELS)
    scaled = (values - lo) / (hi - lo) if hi > lo else np.zeros_like(values)
    return np.round(255.0 * linear_to_srgb(np.clip(scaled, 0.0, 1.0))).astype(np.uint8)


def to_grey8(linear: np.ndarray) -> np.ndarray:
    """A linear (3, H, W) capture as the 8-bit sRGB grey image (H, W) a detector sees (module doc)."""
    y = luminance(np.asarray(linear, dtype=np.float64))
    return _levelled8(y, y)


def to_rgb8(linear: np.ndarray) -> np.ndarray:
    """A linear (3, H, W) capture as the 8-bit sRGB colour image (H, W, 3) a user's model sees:
    the same levels as :func:`to_grey8`, one gain for every channel."""
    x = np.asarray(linear, dtype=np.float64)
    return np.ascontiguousarray(_levelled8(x, luminance(x)).transpose(1, 2, 0))


def detect(task: str, grey: np.ndarray) -> list[Detection]:
    """The detections of ``task`` ("markers" or "qr") in an 8-bit grey image."""
    import cv2

    if task == "markers":
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICTIONARY))
        corners, ids, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(grey)
        if ids is None:
            return []
        return [Detection(task, str(int(i)), c.reshape(4, 2).astype(float)) for c, i in zip(corners, ids.ravel())]
    fine = cv2.resize(grey, None, fx=QR_UPSAMPLE, fy=QR_UPSAMPLE, interpolation=cv2.INTER_CUBIC)
    ok, texts, points, _ = cv2.QRCodeDetector().detectAndDecodeMulti(fine)
    if not ok or points is None:
        return []
    return [
        Detection(task, text, (p.reshape(4, 2).astype(float) + 0.5) / QR_UPSAMPLE - 0.5)  # pixel centres at integers
        for text, p in zip(texts, points)
        if text
    ]


def corner_error(detected: np.ndarray, truth: np.ndarray) -> float:
    """Mean distance (px) between four detected corners and the truth, at the detection's best
    cyclic order (a detector may start from another corner)."""
    return min(float(np.linalg.norm(np.roll(detected, k, axis=0) - truth, axis=1).mean()) for k in range(4))


def tolerance_px(target: Target) -> float:
    """The corner tolerance (px) of ``target``."""
    return max(MIN_TOLERANCE_PX, TOLERANCE * target.side_px)


def score_detections(targets: list[Target], detections: list[Detection]) -> Outcome:
    """``detections`` of one task matched to that task's ``targets`` (module doc)."""
    found = np.zeros(len(targets), dtype=bool)
    error = np.full(len(targets), np.nan)
    index = {t.key: k for k, t in enumerate(targets)}
    wrong = 0
    for detection in detections:
        k = index.get(detection.key)
        if k is None or found[k]:
            wrong += 1
            continue
        e = corner_error(detection.corners, targets[k].corners)
        if e <= tolerance_px(targets[k]):
            found[k], error[k] = True, e
        else:
            wrong += 1
    return Outcome(found, error, wrong)


def score_tasks(linear: np.ndarray, targets: list[Target], tasks) -> dict[str, Outcome]:
    """Each task's :class:`Outcome` on one linear (3, H, W) capture of a scene holding ``targets``."""
    grey = to_grey8(linear)
    return {task: score_detections([t for t in targets if t.task == task], detect(task, grey)) for task in tasks}


def scoring_seconds(tasks, pixels: int, captures: int) -> float:
    """The estimated seconds of scoring ``captures`` captures of ``pixels``² on ``tasks``."""
    return captures * pixels**2 / 1e6 * sum(SECONDS_PER_MEGAPIXEL[task] for task in tasks)
