"""Run the offline detectors on a capture and score them against the drawn targets.

A capture reaches a detector as a camera's image would: its linear RGB auto-levelled (the
``LEVELS`` percentiles of luminance to black and white, one gain for every channel), encoded
as sRGB and quantised to 8 bits, in grey. Markers: ``cv2.aruco`` (dictionary
``targets.MARKER_DICTIONARY``, sub-pixel corner refinement). QR codes: zxing-cpp (several per
image) on the image upsampled ``QR_UPSAMPLE`` × (bicubic). On the photographs' targets at 512²
(18 units) it reads every code of 1.5-4.6 px modules in the clean scenes at 1.5 × (only 2 of the 18
1.5 px ones at 1 ×), in 3-5 ms a capture; OpenCV's ``QRCodeDetector`` needed 2.5 × for the 2 px
ones, took 40-75 × as long, and lost most codes under a blur of σ = 1 px that zxing-cpp reads
(benchmarks/bench_tasks.py). Its corners lie within about a module of the truth (it places the
fourth from the alignment of the other three), inside the tolerance below.

Text: RapidOCR (PP-OCR's detector and recogniser as ONNX files in its wheel, run by onnxruntime;
installed without its own ``opencv-python-headless``, ``OCR_INSTALL``), upright lines, no angle
classifier.

A marker or QR code is **found** when a detection carries its key and its corners lie within
``max(MIN_TOLERANCE_PX, TOLERANCE × side)`` of the truth (mean over the four corners, at the
best cyclic order of the detection's corners). Every other detection is **wrong**: a key drawn
nowhere, a second detection of a key, or a right key in the wrong place. A text line is
**detected** when a recognised line's box overlaps its box at IoU ≥ ``TEXT_IOU`` (the best
unused one; its box is the ink box grown by ``TEXT_PAD`` of the text's size on every side, as
line annotations are drawn: the detector's boxes hold that margin, and a tight box would fail
lines read right), and **found** when that line also reads exactly (spaces and case aside); its
character error rate is the edit distance over its length (1 when not detected). Lines that
match no target are wrong.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.imaging.images import luminance
from metalens_cli.imaging.targets import MARKER_DICTIONARY, Target
from metalens_cli.io.image_files import linear_to_srgb

LEVELS = (0.5, 99.5)  # auto-levels: these luminance percentiles map to black and white
SRGB_STEPS = 65536
TOLERANCE = 0.1  # corner tolerance, a fraction of the code's side
MIN_TOLERANCE_PX = 2.0
QR_UPSAMPLE = 1.5
TEXT_IOU = 0.5
TEXT_PAD = 0.25
OCR_INSTALL = "pip install 'metalens-cli[text]' && pip install --no-deps rapidocr"
# seconds to score one capture per megapixel on 2 CPU cores (benchmarks/bench_tasks.py, docs/benchmarks.md)
SECONDS_PER_MEGAPIXEL = {"markers": 0.033, "qr": 0.016, "text": 1.075}


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
    ``corner_error_px`` (NaN where not found), and ``wrong`` detections; for text also per line
    ``detected`` and ``cer`` (None for the other tasks)."""

    found: np.ndarray
    corner_error_px: np.ndarray
    wrong: int
    detected: np.ndarray | None = None
    cer: np.ndarray | None = None


@lru_cache(maxsize=1)
def _srgb8() -> np.ndarray:
    """8-bit sRGB codes of ``SRGB_STEPS`` linear values evenly over 0..1 (a table: the exact curve
    per pixel cost a third of a marker search; the steps are 0.05 code apart at black)."""
    return np.round(255.0 * linear_to_srgb(np.linspace(0.0, 1.0, SRGB_STEPS))).astype(np.uint8)


def _levelled8(values: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``values`` auto-levelled by the ``LEVELS`` percentiles of luminance ``y``, sRGB, 8 bits."""
    lo, hi = np.percentile(y, LEVELS)
    scaled = (values - lo) * np.float32((SRGB_STEPS - 1) / (hi - lo)) if hi > lo else np.zeros_like(values)
    return _srgb8()[np.clip(scaled + 0.5, 0, SRGB_STEPS - 1).astype(np.int32)]


def to_grey8(linear: np.ndarray) -> np.ndarray:
    """A linear (3, H, W) capture as the 8-bit sRGB grey image (H, W) a detector sees (module doc)."""
    y = luminance(np.asarray(linear, dtype=np.float32))
    return _levelled8(y, y)


def to_rgb8(linear: np.ndarray) -> np.ndarray:
    """A linear (3, H, W) capture as the 8-bit sRGB colour image (H, W, 3) a user's model sees:
    the same levels as :func:`to_grey8`, one gain for every channel."""
    x = np.asarray(linear, dtype=np.float32)
    return np.ascontiguousarray(_levelled8(x, luminance(x)).transpose(1, 2, 0))


def check_dependencies(tasks) -> None:
    """Refuse (``InputError`` naming ``--task``) a task whose detector is not installed."""
    if "text" in tasks:
        _ocr()


@lru_cache(maxsize=1)
def _ocr():
    """The RapidOCR engine, made once (quiet, no angle classifier)."""
    try:
        from rapidocr import RapidOCR
    except ImportError:
        raise InputError("--task", "text needs RapidOCR, which is not installed", OCR_INSTALL) from None
    return RapidOCR(params={"Global.log_level": "error", "Global.use_cls": False})


def detect(task: str, grey: np.ndarray) -> list[Detection]:
    """The detections of ``task`` ("markers", "qr" or "text") in an 8-bit grey image."""
    import cv2

    if task == "text":
        result = _ocr()(np.repeat(grey[:, :, None], 3, axis=2))
        if result.boxes is None:
            return []
        return [Detection(task, text, np.asarray(box, dtype=float)) for box, text in zip(result.boxes, result.txts)]
    if task == "markers":
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICTIONARY))
        corners, ids, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(grey)
        if ids is None:
            return []
        return [Detection(task, str(int(i)), c.reshape(4, 2).astype(float)) for c, i in zip(corners, ids.ravel())]
    import zxingcpp

    fine = cv2.resize(grey, None, fx=QR_UPSAMPLE, fy=QR_UPSAMPLE, interpolation=cv2.INTER_CUBIC)
    found = []
    for code in zxingcpp.read_barcodes(fine, formats=zxingcpp.BarcodeFormat.QRCode):
        p = code.position
        corners = np.array([[c.x, c.y] for c in (p.top_left, p.top_right, p.bottom_right, p.bottom_left)], float)
        found.append(Detection(task, code.text, (corners + 0.5) / QR_UPSAMPLE - 0.5))  # pixel centres at integers
    return found


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


def _box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of the axis-aligned boxes around two sets of corners (4, 2)."""
    (ax0, ay0), (ax1, ay1) = a.min(0), a.max(0)
    (bx0, by0), (bx1, by1) = b.min(0), b.max(0)
    w, h = max(0.0, min(ax1, bx1) - max(ax0, bx0)), max(0.0, min(ay1, by1) - max(ay0, by0))
    union = (ax1 - ax0) * (ay1 - ay0) + (bx1 - bx0) * (by1 - by0) - w * h
    return w * h / union if union > 0 else 0.0


def edit_distance(a: str, b: str) -> int:
    """Levenshtein distance: the fewest insertions, deletions and substitutions from ``a`` to ``b``."""
    row = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        previous, row[0] = row[0], i
        for j, cb in enumerate(b, 1):
            previous, row[j] = row[j], min(row[j] + 1, row[j - 1] + 1, previous + (ca != cb))
    return row[-1]


def score_lines(targets: list[Target], detections: list[Detection]) -> Outcome:
    """Text ``detections`` matched to the text ``targets`` (module doc)."""
    n = len(targets)
    found, detected = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    error, cer = np.full(n, np.nan), np.ones(n)
    unused = set(range(len(detections)))
    for k, target in enumerate(targets):
        box = target.corners + TEXT_PAD * target.size_px * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
        overlaps = [(_box_iou(detections[j].corners, box), j) for j in unused]
        iou, j = max(overlaps, default=(0.0, -1))
        if iou < TEXT_IOU:
            continue
        unused.discard(j)
        truth, read = (s.replace(" ", "").upper() for s in (target.key, detections[j].key))
        detected[k], cer[k] = True, min(1.0, edit_distance(read, truth) / len(truth))
        if read == truth:
            found[k], error[k] = True, corner_error(detections[j].corners, target.corners)
    return Outcome(found, error, len(unused), detected, cer)


def score_tasks(linear: np.ndarray, targets: list[Target], tasks) -> dict[str, Outcome]:
    """Each task's :class:`Outcome` on one linear (3, H, W) capture of a scene holding ``targets``."""
    grey = to_grey8(linear)
    out = {}
    for task in tasks:
        drawn = [t for t in targets if t.task == task]
        score = score_lines if task == "text" else score_detections
        out[task] = score(drawn, detect(task, grey))
    return out


def scoring_seconds(tasks, pixels: int, captures: int) -> float:
    """The estimated seconds of scoring ``captures`` captures of ``pixels``² on ``tasks``."""
    return captures * pixels**2 / 1e6 * sum(SECONDS_PER_MEGAPIXEL[task] for task in tasks)
