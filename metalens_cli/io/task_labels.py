"""Read the labels of a user's images for ``evaluate --task-labels DIR``, in the images' own frame.

Boxes (``detect``), from either
- YOLO text files ``DIR/NAME.txt``, one line ``class cx cy w h`` per object, normalised to the
  image's width and height (an empty file: no objects), or
- one COCO JSON file in DIR: ``images`` (``id``, ``file_name``, ``width``, ``height``) and
  ``annotations`` (``image_id``, ``bbox`` x, y, w, h in pixels, ``category_id``);
returned as (M, 4) x1, y1, x2, y2 normalised to 0..1 and (M,) integer classes.

Masks (``segment``): ``DIR/NAME.png``, one channel of class indices (8 or 16 bit), returned as
an (H, W) int array at the file's size.

NAME is each image's file stem; an image without labels or a malformed file is an
``InputError`` naming ``--task-labels``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import read_text

FIELD = "--task-labels"
FORM = "DIR/NAME.txt (YOLO), one COCO .json in DIR, or DIR/NAME.png index masks, for every image's NAME"


def read_box_labels(folder: Path, names: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per image name: (boxes (M, 4) normalised x1, y1, x2, y2, classes (M,)) from DIR (module doc)."""
    folder = Path(folder)
    coco = sorted(folder.glob("*.json"))
    if len(coco) > 1:
        raise InputError(FIELD, f"{folder} holds {len(coco)} JSON files", "one COCO .json")
    if coco:
        labels = _coco(coco[0])
    else:
        labels = {name: _yolo(folder / f"{name}.txt") for name in names if (folder / f"{name}.txt").is_file()}
    missing = [name for name in names if name not in labels]
    if missing:
        raise InputError(FIELD, f"no labels for image {missing[0]!r} in {folder}", FORM)
    return {name: labels[name] for name in names}


def _yolo(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """One YOLO text file → (normalised x1, y1, x2, y2, classes)."""
    rows = []
    for number, line in enumerate(read_text(path, FIELD, FORM).splitlines(), 1):
        if not line.strip():
            continue
        try:
            c, cx, cy, w, h = line.split()
            rows.append((int(c), float(cx), float(cy), float(w), float(h)))
        except ValueError:
            raise InputError(FIELD, f"{path.name} line {number}: {line.strip()!r}", "class cx cy w h") from None
    table = np.array(rows, dtype=np.float64).reshape(-1, 5)
    cx, cy, w, h = table[:, 1:].T
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    _check(boxes, path.name)
    return boxes, table[:, 0].astype(np.int64)


def _coco(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """A COCO JSON file → per file stem (normalised x1, y1, x2, y2, classes)."""
    try:
        data = json.loads(read_text(path, FIELD, FORM))
        images = {item["id"]: (Path(item["file_name"]).stem, item["width"], item["height"]) for item in data["images"]}
        found: dict[str, list] = {stem: [] for stem, _, _ in images.values()}
        for item in data["annotations"]:
            stem, width, height = images[item["image_id"]]
            x, y, w, h = (float(v) for v in item["bbox"])
            found[stem].append((x / width, y / height, (x + w) / width, (y + h) / height, int(item["category_id"])))
    except (ValueError, KeyError, TypeError, ZeroDivisionError) as error:
        raise InputError(FIELD, f"{path.name} is not COCO JSON ({error!r})", FORM) from None
    out = {}
    for stem, rows in found.items():
        table = np.array(rows, dtype=np.float64).reshape(-1, 5)
        _check(table[:, :4], path.name)
        out[stem] = (table[:, :4], table[:, 4].astype(np.int64))
    return out


def _check(boxes: np.ndarray, name: str) -> None:
    if not np.isfinite(boxes).all() or (boxes[:, 2] < boxes[:, 0]).any() or (boxes[:, 3] < boxes[:, 1]).any():
        raise InputError(FIELD, f"{name}: a box that is not finite or has negative size", FORM)


def read_mask_labels(folder: Path, names: list[str]) -> dict[str, np.ndarray]:
    """Per image name: its (H, W) class-index mask ``DIR/NAME.png``."""
    import cv2

    out = {}
    for name in names:
        path = Path(folder) / f"{name}.png"
        if not path.is_file():
            raise InputError(FIELD, f"no mask {path.name} for image {name!r}", FORM)
        mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if mask is None or mask.ndim != 2:
            raise InputError(FIELD, f"{path.name} is not a one-channel PNG", "8- or 16-bit class indices")
        out[name] = mask.astype(np.int64)
    return out
