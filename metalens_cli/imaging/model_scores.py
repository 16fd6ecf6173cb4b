"""Scores of a user's model (``evaluate --task-model``) over an evaluation's units.

Detection and segmentation are scored over the set, as their benchmarks are (COCO mAP,
dataset-level mIoU: ``analysis.detection_metrics``), not per unit; the 95 % intervals resample the
units (image × seed) ``RESAMPLES`` times, and a paired difference between two cells resamples the
same units for both. A segmentation unit is kept as its confusion counts (sparse), so resampling
never touches the maps again.

Segmentation reports two means of the per-class IoU: ``miou``, over every class present in the
truth or the prediction of that cell (the benchmarks' rule), and ``miou_paper``, the paper's
rule (Suppl. Note 12): a class whose IoU is undefined or 0 in any cell of the table is left out
of every cell, so that all designs are averaged over the same classes; the classes left out are
listed with each row (``excluded_classes``). The paper's rule drops the classes a design fails
on entirely, so it flatters every design; the paired differences use ``miou``.
"""

from __future__ import annotations

import numpy as np

from metalens_cli.analysis.detection_metrics import detection_scores, segmentation_from_confusion
from metalens_cli.imaging.task_models import Detections

RESAMPLES = 200
CONFIDENCE = 0.95
METRICS = {
    "detect": ("map50", "map50_95", "recall50"),
    "segment": ("miou", "miou_paper", "iou_foreground", "dice_foreground"),
}
COMPARED = {"detect": "map50_95", "segment": "miou"}  # the metric of the paired differences


def confusion_counts(predicted: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One unit's confusion as sparse (pairs (P, 2) of truth, predicted class; counts (P,))."""
    pairs, counts = np.unique(np.stack([truth.ravel(), predicted.ravel()], axis=1), axis=0, return_counts=True)
    return pairs, counts


def _dense(units: list, classes: int) -> np.ndarray:
    """The summed confusion matrix (classes, classes) of sparse units."""
    matrix = np.zeros((classes, classes), dtype=np.int64)
    for pairs, counts in units:
        np.add.at(matrix, (pairs[:, 0], pairs[:, 1]), counts)
    return matrix


def _score(kind: str, outputs: list, truths: list, classes: int, exclude=frozenset()) -> dict:
    """The set's scores: {metric: value or None}; ``exclude``: the classes ``miou_paper`` leaves out."""
    if kind == "detect":
        s = detection_scores([(d.boxes, d.scores, d.classes) for d in outputs], [(t.boxes, t.classes) for t in truths])
    else:
        s = segmentation_from_confusion(_dense(outputs, classes))
        kept = [iou for c, iou in s["per_class_iou"].items() if c not in exclude]
        s["miou_paper"] = float(np.mean(kept)) if kept else None
    return {m: s.get(m) for m in METRICS[kind]}


def paper_exclusions(cells: list[list], classes: int) -> frozenset:
    """The classes the paper's mIoU rule leaves out of a table whose cells hold these per-unit
    sparse confusions: those of IoU undefined or 0 in any cell."""
    out = set()
    for units in cells:
        iou = segmentation_from_confusion(_dense(units, classes))["per_class_iou"]
        out |= {c for c in range(classes) if iou.get(c, 0.0) == 0.0}
    return frozenset(out)


def _classes(kind: str, outputs: list) -> int:
    """The number of classes a segmentation's sparse units span (0 for detection)."""
    return 1 + max((int(pairs.max()) for pairs, _ in outputs if pairs.size), default=0) if kind == "segment" else 0


def model_row(
    kind: str, outputs: list, truths: list, labels: dict, classes: int = 0, exclude=frozenset(), seed: int = 0
) -> dict:
    """``labels`` and the scores of per-unit ``outputs`` (:class:`Detections`, or sparse confusions
    for "segment" over ``classes`` classes, ``exclude`` left out of ``miou_paper``) against
    ``truths`` (:class:`Detections`; unused for "segment"), with intervals."""
    classes = max(classes, _classes(kind, outputs))
    point = _score(kind, outputs, truths, classes, exclude)
    rng = np.random.default_rng(seed)
    n = len(outputs)
    draws = {m: [] for m in point}
    for _ in range(RESAMPLES if n > 1 else 0):
        take = rng.integers(0, n, n)
        for m, v in _score(
            kind, [outputs[i] for i in take], [truths[i] for i in take] if truths else [], classes, exclude
        ).items():
            if v is not None:
                draws[m].append(v)
    row = {**labels, "n": n, **({"excluded_classes": sorted(exclude)} if kind == "segment" else {})}
    for m, v in point.items():
        row[m], row[f"{m}_ci"] = v, None if v is None else _interval(draws[m], v)
    return row


def _interval(draws: list[float], value: float) -> list[float]:
    """The percentile interval of bootstrap ``draws`` at ``CONFIDENCE`` ([value, value] without any)."""
    tail = 100 * (1 - CONFIDENCE) / 2
    return [float(x) for x in np.percentile(draws, [tail, 100 - tail])] if draws else [value, value]


def model_difference(kind: str, first: list, second: list, truths: list, metric: str, seed: int = 0) -> dict:
    """{"difference", "ci", "n"} of ``metric`` between two cells' per-unit outputs on the same
    units, resampling the units jointly."""
    classes = max(_classes(kind, first), _classes(kind, second))
    a, b = _score(kind, first, truths, classes)[metric], _score(kind, second, truths, classes)[metric]
    if a is None or b is None:
        return {"difference": None, "ci": None, "n": len(first)}
    rng = np.random.default_rng(seed)
    n = len(first)
    draws = []
    for _ in range(RESAMPLES if n > 1 else 0):
        take = rng.integers(0, n, n)
        t = [truths[i] for i in take] if truths else []
        x = _score(kind, [first[i] for i in take], t, classes)[metric]
        y = _score(kind, [second[i] for i in take], t, classes)[metric]
        if x is not None and y is not None:
            draws.append(x - y)
    return {"difference": a - b, "ci": _interval(draws, a - b), "n": n}


def unit_output(kind: str, output, truth) -> Detections | tuple:
    """What a unit keeps of a model's output: its :class:`Detections`, or its sparse confusion
    against the truth map for "segment"."""
    return output if kind == "detect" else confusion_counts(output, truth)


def summarise_model(
    kind: str, specs, captures_of, kinds, units, outputs: dict, clean: dict, truths: dict, light: str | None = None
) -> tuple[list[dict], list[dict]]:
    """(rows, comparisons) of one camera, as ``task_scores.summarise_tasks`` lays them out.

    Args:
        kind: "detect" or "segment".
        specs: the designs' specs; ``captures_of[d]`` the captures design d was scored on.
        kinds: obstruction kinds.
        units: the (seed, image index) units, in order.
        outputs: ``outputs[capture, d, kind or "unobstructed", seed, index]``: what each unit keeps
            (:func:`unit_output`).
        clean: ``clean[seed, index]``: the same of the clean scene (the ceiling).
        truths: ``truths[seed, index]``: the unit's truth :class:`Detections` (detection).
        light: the camera's label (added to every entry), None for none.
    """
    from metalens_cli.imaging.task_scores import CONDITIONS, compared_pairs

    extra = {} if light is None else {"light": light}
    truth = [truths[u] for u in units] if kind == "detect" else []
    cells = [(capture, d) for d in range(len(specs)) for capture in captures_of[d]]

    def unit_outputs(capture, d, obstruction, condition):
        return [outputs[capture, d, "unobstructed" if condition == "unobstructed" else obstruction, *u] for u in units]

    table = [[clean[u] for u in units]] + [
        unit_outputs(capture, d, obstruction, condition)
        for obstruction in kinds
        for capture, d in cells
        for condition in CONDITIONS
    ]
    classes = max(_classes(kind, units) for units in table)
    exclude = paper_exclusions(table, classes) if kind == "segment" else frozenset()
    ceiling = {"design": "clean", "capture": "clean", "obstruction": None, "condition": "clean", **extra}
    rows = [model_row(kind, table[0], truth, ceiling, classes, exclude)]
    comparisons = []
    for obstruction in kinds:
        for capture, d in cells:
            for condition in CONDITIONS:
                labels = {"design": specs[d], "capture": capture, "obstruction": obstruction, "condition": condition}
                cell = unit_outputs(capture, d, obstruction, condition)
                rows.append(model_row(kind, cell, truth, {**labels, **extra}, classes, exclude))
        for first, second in compared_pairs(cells):
            for condition in CONDITIONS:
                metric = COMPARED[kind]
                stats = model_difference(
                    kind,
                    unit_outputs(*first, obstruction, condition),
                    unit_outputs(*second, obstruction, condition),
                    truth,
                    metric,
                )
                comparisons.append(
                    {
                        "design": specs[first[1]],
                        "capture": first[0],
                        "versus": specs[second[1]],
                        "versus_capture": second[0],
                        "obstruction": obstruction,
                        "condition": condition,
                        "metric": metric,
                        **stats,
                        **extra,
                    }
                )
    return rows, comparisons
