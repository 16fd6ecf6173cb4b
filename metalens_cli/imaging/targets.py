"""Vision-task targets drawn into clean scenes: ArUco markers, QR codes and text lines with exact
ground truth.

A target is printed matte (linear reflectance ``PAPER`` white, ``INK`` black) on the far plane and
drawn into the clean image before imaging, so every design images the same targets. Its
footprint is the code and its quiet zone (one cell for a marker, four modules for a QR code, half
the text's size around a line), an integer rectangle of sensor pixels; the target inside it is
rendered ``RENDER`` times finer and area-averaged onto the pixels in linear light, so its corners
are exact to a fraction of a pixel at any size.

Coordinates: sensor pixels (x right, y down) with pixel centres at integers (OpenCV's), so the
code's outer corner at pixel boundary b lies at b − 0.5. Corners run clockwise from the code's
top-left (a text line's: its ink box). A target's ``size_px`` is the quantity its detection limit
is stated in: the marker's side (outer black border), the QR code's module, or the text's size
(the font's em, DejaVu Sans as matplotlib ships it, so the rendering is the same everywhere).

Sizes are log-spaced over ``SIZES_PX`` (one target of each size per unit, those whose footprint
fits a third of the sensor's side; a text line may be two thirds wide), placed without overlap
at positions drawn from the unit's seed; the markers' IDs, the QR payloads and the text strings
are drawn the same way.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.imaging.images import CleanImage

TASKS = ("markers", "qr", "text")
SIZE_MEANING = {"markers": "marker side (px)", "qr": "QR module (px)", "text": "text size, em (px)"}
SIZES_PX = {"markers": (24.0, 160.0), "qr": (1.5, 6.0), "text": (10.0, 40.0)}  # log-spaced, smallest to largest
PER_UNIT = 6  # targets of each task per unit, one of each size
PAPER, INK = 0.8, 0.03  # linear reflectance of matte white paper and black ink
RENDER = 24  # render sub-samples per cell, module or text pixel before area averaging
MARKER_DICTIONARY = "DICT_4X4_250"  # cv2.aruco: 4 × 4 data bits, 1-cell black border, 250 IDs
MARKER_CELLS, MARKER_QUIET = 6, 1  # cells across the marker (data and border) and in its quiet zone
QR_MODULES, QR_QUIET = 21, 4  # version 1, and the standard's quiet zone
TEXT_ALPHABET = "ABCDEFGHJKLMNPQRSTUVWXYZ23456789"  # no 0/O, 1/I: a reading error is an error
TEXT_GROUPS, TEXT_GROUP = 2, 4  # a line: two groups of four characters, e.g. "QX7K M2PA"
TEXT_MARGIN = 0.5  # the paper around a text line, in its size
TEXT_WIDTH = 0.72  # upper bound of a character's advance (em): sizes the footprint before rendering
PLACEMENT_TRIES = 400


@dataclass(frozen=True)
class Target:
    """One drawn target: ``task``, ``key`` (marker ID as text, QR payload or the text line),
    ``size_px`` (see the module), ``corners`` (4, 2) x, y of the code's outer corners (or the text's
    ink box) in sensor pixels, clockwise from top-left, and ``footprint`` (x0, y0, width, height):
    the pixels it covers with its quiet zone."""

    task: str
    key: str
    size_px: float
    corners: np.ndarray
    footprint: tuple[int, int, int, int]

    @property
    def side_px(self) -> float:
        """The code's side, or the text line's height (px): what a corner tolerance is stated in."""
        return float(np.linalg.norm(self.corners[3] - self.corners[0]))


def check_tasks(tasks) -> tuple[str, ...]:
    """``tasks`` as a tuple of known task names, each once (``InputError`` naming ``--task``)."""
    out = tuple(dict.fromkeys(tasks))
    for task in out:
        if task not in TASKS:
            raise InputError("--task", f"unknown task {task!r}", ", ".join(TASKS))
    return out


def task_sizes(task: str, sensor_hw: tuple[int, int]) -> np.ndarray:
    """The ``PER_UNIT`` log-spaced sizes of ``task`` (px, :data:`SIZE_MEANING`) whose footprint fits a
    third of the sensor's shorter side (a text line's width: two thirds)."""
    lo, hi = SIZES_PX[task]
    sizes = np.geomspace(lo, hi, PER_UNIT)
    side = min(sensor_hw)
    return sizes[
        [
            h <= side // 3 and w <= (2 if task == "text" else 1) * side // 3
            for h, w in (_footprint_hw(task, s) for s in sizes)
        ]
    ]


def _footprint_hw(task: str, size_px: float) -> tuple[int, int]:
    """The footprint's (height, width) (px, integers) of a target of ``size_px``."""
    if task == "markers":
        side = round(size_px * (MARKER_CELLS + 2 * MARKER_QUIET) / MARKER_CELLS)
    elif task == "qr":
        side = round(size_px * (QR_MODULES + 2 * QR_QUIET))
    else:
        characters = TEXT_GROUPS * TEXT_GROUP + TEXT_GROUPS - 1
        return round(size_px * (1.2 + 2 * TEXT_MARGIN)), round(size_px * (characters * TEXT_WIDTH + 2 * TEXT_MARGIN))
    return side, side


def layout(tasks, sensor_hw: tuple[int, int], seed: int, index: int) -> list[Target]:
    """The targets of one unit (``seed``, image ``index``) on an H × W sensor: each task's sizes
    (:func:`task_sizes`), largest first, at non-overlapping random places (a target that finds
    no place in ``PLACEMENT_TRIES`` draws is left out), keys drawn from the same generator."""
    rng = np.random.default_rng([seed, index, 0x7A5C])
    h, w = sensor_hw
    wanted = [(task, size) for task in check_tasks(tasks) for size in task_sizes(task, sensor_hw)]
    wanted.sort(key=lambda ts: -np.prod(_footprint_hw(*ts)))
    marker_ids = iter(rng.choice(250, size=PER_UNIT, replace=False))
    taken: list[tuple[int, int, int, int]] = []
    targets = []
    for k, (task, size) in enumerate(wanted):
        fh, fw = _footprint_hw(task, size)
        for _ in range(PLACEMENT_TRIES):
            x0, y0 = int(rng.integers(0, w - fw + 1)), int(rng.integers(0, h - fh + 1))
            if all(x0 >= a + aw or a >= x0 + fw or y0 >= b + bh or b >= y0 + fh for a, b, aw, bh in taken):
                break
        else:
            continue
        taken.append((x0, y0, fw, fh))
        if task == "markers":
            key = str(int(next(marker_ids)))
        elif task == "qr":
            key = f"ML-{k:02d}-{int(rng.integers(10**5)):05d}"
        else:
            letters = rng.choice(list(TEXT_ALPHABET), TEXT_GROUPS * TEXT_GROUP)
            key = " ".join("".join(letters[g * TEXT_GROUP : (g + 1) * TEXT_GROUP]) for g in range(TEXT_GROUPS))
        targets.append(_target(task, key, size, (x0, y0, fw, fh)))
    return targets


def _target(task: str, key: str, size_px: float, footprint: tuple[int, int, int, int]) -> Target:
    """A target of ``task`` with its exact corners in the footprint (x0, y0, width, height)."""
    x0, y0, fw, fh = footprint
    if task == "text":
        ink, _ = _text_ink(key, size_px, fw, fh)
        left, top, right, bottom = (v / RENDER - 0.5 for v in ink)
        corners = np.array([[left, top], [right, top], [right, bottom], [left, bottom]]) + [x0, y0]
        return Target(task, key, size_px, corners, footprint)
    cells, quiet = (MARKER_CELLS, MARKER_QUIET) if task == "markers" else (QR_MODULES, QR_QUIET)
    unit = fw / (cells + 2 * quiet)  # a cell or module (px)
    a, b = quiet * unit - 0.5, (quiet + cells) * unit - 0.5
    corners = np.array([[a, a], [b, a], [b, b], [a, b]]) + [x0, y0]
    return Target(task, key, unit * cells if task == "markers" else unit, corners, footprint)


@lru_cache(maxsize=4096)
def _text_ink(text: str, size_px: float, fw: int, fh: int) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """((left, top, right, bottom) of the ink in the footprint's fine pixels, ``RENDER`` to a
    pixel (edges); the ink's coverage 0..1 of each of the footprint's (fh, fw) pixels): ``text``
    in DejaVu Sans at ``size_px`` em, centred, rendered fine and area-averaged. Cached: a unit's
    lines are drawn once per design and obstruction kind."""
    import cv2
    from matplotlib import font_manager, ft2font

    font = ft2font.FT2Font(font_manager.findfont("DejaVu Sans", fallback_to_default=False))
    font.set_size(size_px * RENDER, 72)  # at 72 dpi a point is a pixel: the em is size_px · RENDER fine pixels
    font.set_text(text, 0.0)
    font.draw_glyphs_to_bitmap()
    glyphs = np.asarray(font.get_image(), dtype=np.float32) / 255.0
    rows, cols = np.nonzero(glyphs > 0)
    glyphs = glyphs[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]
    fine = np.zeros((fh * RENDER, fw * RENDER), dtype=np.float32)
    top, left = (fine.shape[0] - glyphs.shape[0]) // 2, (fine.shape[1] - glyphs.shape[1]) // 2
    if top < 0 or left < 0:
        raise ValueError(f"text {text!r} at {size_px:g} px outgrows its footprint {fw} × {fh}")
    fine[top : top + glyphs.shape[0], left : left + glyphs.shape[1]] = glyphs
    coverage = cv2.resize(fine, (fw, fh), interpolation=cv2.INTER_AREA)
    return (left, top, left + glyphs.shape[1], top + glyphs.shape[0]), coverage


def _code_cells(task: str, key: str) -> np.ndarray:
    """A code (``task`` "markers" or "qr", ``key``) with its quiet zone, one uint8 value per cell or
    module (0 ink, 255 paper)."""
    import cv2

    if task == "markers":
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICTIONARY))
        code = cv2.aruco.generateImageMarker(dictionary, int(key), MARKER_CELLS, borderBits=1)
        quiet = MARKER_QUIET
    else:
        params = cv2.QRCodeEncoder.Params()
        params.version, params.correction_level = 1, cv2.QRCodeEncoder_CORRECT_LEVEL_M
        encoded = cv2.QRCodeEncoder.create(params).encode(key)
        ys, xs = np.nonzero(encoded < 128)
        code = encoded[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
        quiet = QR_QUIET
    return np.pad(code, quiet, constant_values=255)


def render(target: Target) -> np.ndarray:
    """The target's footprint (height, width) as linear reflectance in [``INK``, ``PAPER``]: the
    target rendered ``RENDER`` × finer, area-averaged onto the footprint's pixels."""
    _, _, fw, fh = target.footprint
    if target.task == "text":
        paper = 1.0 - _text_ink(target.key, target.size_px, fw, fh)[1]
    else:
        paper = _code_paper(target.task, target.key, fw, fh)
    return INK + (PAPER - INK) * paper


@lru_cache(maxsize=4096)
def _code_paper(task: str, key: str, fw: int, fh: int) -> np.ndarray:
    """The paper's share 0..1 of each of a code's footprint pixels (fh, fw), cached as text's."""
    import cv2

    cells = _code_cells(task, key)
    fine = np.repeat(np.repeat(cells, RENDER, axis=0), RENDER, axis=1).astype(np.float32) / 255.0
    return cv2.resize(fine, (fw, fh), interpolation=cv2.INTER_AREA)


def draw_targets(image: CleanImage, targets: list[Target]) -> CleanImage:
    """A copy of ``image`` with ``targets`` printed on it (grey: the same reflectance in R, G, B);
    ``image`` itself when there are none."""
    if not targets:
        return image
    linear = image.linear.copy()
    m = image.margin
    for target in targets:
        x0, y0, fw, fh = target.footprint
        linear[:, m + y0 : m + y0 + fh, m + x0 : m + x0 + fw] = render(target)
    return dataclasses.replace(image, linear=linear)


def to_records(targets: list[Target]) -> list[dict]:
    """``targets`` as the records of a layout file (``io.target_files``)."""
    return [
        {
            "task": t.task,
            "key": t.key,
            "size_px": t.size_px,
            "corners": t.corners.tolist(),
            "footprint": list(t.footprint),
        }
        for t in targets
    ]


def from_records(records: list[dict], field: str) -> list[Target]:
    """The targets of a layout file's records; a task this version does not know is an
    ``InputError`` naming ``field``."""
    out = []
    for r in records:
        if r["task"] not in TASKS:
            raise InputError(field, f"target of unknown task {r['task']!r}", ", ".join(TASKS))
        out.append(Target(r["task"], r["key"], r["size_px"], np.asarray(r["corners"]), tuple(r["footprint"])))
    return out


def board(tasks, pixels_hw: tuple[int, int], seed: int = 0) -> tuple[np.ndarray, list[Target]]:
    """A printable board: (linear (3, H, W) in 0..1, white paper and black ink, and its targets),
    the layout of unit (``seed``, 0) (:func:`layout`)."""
    targets = layout(tasks, pixels_hw, seed, 0)
    paper = CleanImage("board", np.full((3, *pixels_hw), PAPER, dtype=np.float32))
    printed = draw_targets(paper, targets).linear
    return np.clip((printed - INK) / (PAPER - INK), 0.0, 1.0), targets
