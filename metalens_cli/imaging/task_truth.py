"""The truth a user's model is scored against, on the sensor.

``--task-labels DIR``: the images' own labels (``io.task_labels``) framed as the images are
(``imaging.canvas.fit_geometry``: resized to cover the sensor, centre crop). Boxes keep their
class and are clipped to the sensor; a box with less than ``MIN_INSIDE`` of its area on the
sensor is dropped. Masks are resized by nearest neighbour and cropped.

``--task-labels clean``: the model's own output on the clean scene is the truth (no annotation
needed): detections scoring at least ``CLEAN_SCORE``, or the class map.
"""

from __future__ import annotations

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.imaging.canvas import fit_geometry
from metalens_cli.imaging.images import Photograph, image_entries, photograph_path
from metalens_cli.imaging.task_models import Detections
from metalens_cli.io.input_files import check_image_size
from metalens_cli.io.task_labels import read_box_labels, read_mask_labels

MIN_INSIDE = 0.5
CLEAN_SCORE = 0.25  # the confidence a deployed detector reports at (YOLO's default)


def boxes_on_sensor(boxes: np.ndarray, classes: np.ndarray, source_hw, sensor_hw) -> Detections:
    """Normalised x1, y1, x2, y2 boxes of an image of ``source_hw`` → the sensor's pixels (edges),
    as :class:`Detections` of score 1."""
    nh, nw, top, left = fit_geometry(source_hw, sensor_hw)
    h, w = sensor_hw
    resized = np.asarray(boxes, dtype=np.float64).reshape(-1, 4) * [nw, nh, nw, nh]
    labels = Detections(resized, np.ones(len(resized)), np.asarray(classes, dtype=np.int64))
    return cropped(labels, (top, top + h, left, left + w))


def mask_on_sensor(mask: np.ndarray, source_hw, sensor_hw, name: str) -> np.ndarray:
    """An (H0, W0) class mask of an image of ``source_hw`` → the sensor's (H, W) by nearest neighbour."""
    import cv2

    if tuple(mask.shape) != tuple(source_hw):
        raise InputError(
            "--task-labels",
            f"mask of {name!r} is {mask.shape[1]} × {mask.shape[0]}",
            f"its image's size, {source_hw[1]} × {source_hw[0]}",
        )
    nh, nw, top, left = fit_geometry(source_hw, sensor_hw)
    resized = cv2.resize(mask.astype(np.int32), (nw, nh), interpolation=cv2.INTER_NEAREST)
    return resized[top : top + sensor_hw[0], left : left + sensor_hw[1]].astype(np.int64)


def label_truths(folder, images, limit, kind: str, sensor_hw) -> dict:
    """Per image name of ``--images`` (``images``, ``limit``): its labels from ``folder`` on the
    sensor, :class:`Detections` (``kind`` "detect") or an (H, W) class map ("segment")."""
    sources = {}
    for entry in image_entries(images, limit):
        if isinstance(entry, int):
            raise InputError("--task-labels", "a folder of labels for the dead-leaves charts", "--task-labels clean")
        path = photograph_path(entry) if isinstance(entry, Photograph) else entry
        sources[entry.name if isinstance(entry, Photograph) else entry.stem] = check_image_size(path, "--images")
    return framed_labels(folder, sources, kind, sensor_hw)


def framed_labels(folder, sources: dict, kind: str, sensor_hw=None) -> dict:
    """Per image name of ``sources`` (name → its (H, W)): its labels from ``folder`` framed on an
    H × W sensor (``sensor_hw``; None: on the image itself, as a captured pair's reference)."""
    names = list(sources)

    def frame(name):
        return sources[name] if sensor_hw is None else sensor_hw

    if kind == "detect":
        return {n: boxes_on_sensor(*b, sources[n], frame(n)) for n, b in read_box_labels(folder, names).items()}
    return {n: mask_on_sensor(m, sources[n], frame(n), n) for n, m in read_mask_labels(folder, names).items()}


def cropped(truth, box: tuple[int, int, int, int]):
    """A truth on an image's frame cut to ``box`` (top, bottom, left, right): boxes shifted and
    clipped (less than ``MIN_INSIDE`` of a box's area inside: dropped), or the map sliced."""
    top, bottom, left, right = box
    if not isinstance(truth, Detections):
        return truth[top:bottom, left:right]
    b = truth.boxes - [left, top, left, top]
    clipped = np.clip(b, 0, [right - left, bottom - top, right - left, bottom - top])
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    inside = (clipped[:, 2] - clipped[:, 0]) * (clipped[:, 3] - clipped[:, 1])
    keep = inside >= MIN_INSIDE * np.maximum(area, 1e-12)
    return Detections(clipped[keep], truth.scores[keep], truth.classes[keep])


def truth_of(model, on_clean, truth, name: str):
    """A unit's truth: ``truth[name]`` (labels on the sensor), or with ``truth`` "clean" the model's
    output on the clean scene, ``on_clean`` (detections scoring at least ``CLEAN_SCORE``)."""
    if isinstance(truth, str):
        return on_clean.above(CLEAN_SCORE) if model.kind == "detect" else on_clean
    return truth[name]
