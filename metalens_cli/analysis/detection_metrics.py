"""Scores of a user's detector and segmenter on images: COCO box mAP and dataset-level mIoU.

Boxes are (N, 4) arrays of x1, y1, x2, y2 in pixels, continuous coordinates of the box's edges
(area (x2 − x1)(y2 − y1), no +1), x2 ≥ x1 and y2 ≥ y1. Classes are integers. Detection follows
pycocotools' ``COCOeval`` for ``iouType="bbox"`` with area range "all" and no crowd truths:
per image and class the ``max_detections`` highest scores are kept, and each is matched, in
descending score order, to the unmatched truth of highest IoU ≥ the threshold (ties to the later
truth); precision is made monotone and read at the 101 recall points 0, 0.01, …, 1 (0 beyond the
highest recall reached), AP is their mean; classes without any truth are left out. The IoU
thresholds are COCOeval's ``np.linspace(0.5, 0.95, 10)``: ``np.arange(0.5, 0.96, 0.05)`` puts
0.6 and above a few ulp high, which decides an IoU of exactly 0.6.

Segmentation pools one confusion matrix over all images (the dataset-level mIoU of
mmsegmentation and Cityscapes, not a mean of per-image scores).
"""

from __future__ import annotations

import numpy as np

from metalens_cli.errors import InputError

IOU_THRESHOLDS = np.linspace(0.5, 0.95, 10)  # COCOeval's iouThrs
RECALL_POINTS = np.linspace(0.0, 1.0, 101)  # COCOeval's recThrs
MAX_DETECTIONS = 100  # per image and class, COCOeval's last maxDets


def _labels(values, field: str, ndim: int) -> np.ndarray:
    """``values`` as an int64 array of ``ndim`` dimensions (integers, bools or integral floats)."""
    x = np.asarray(values)
    if x.size == 0 and ndim == 1:
        x = x.reshape(0)
    if x.ndim != ndim:
        raise InputError(field, f"shape {x.shape}", f"a {ndim}-D array of integer classes")
    if x.dtype.kind == "f" and np.isfinite(x).all() and (x == np.round(x)).all():
        return x.astype(np.int64)
    if x.dtype.kind not in "biu":
        raise InputError(field, f"values of type {x.dtype}", "integer classes")
    return x.astype(np.int64)


def _boxes(values, field: str) -> np.ndarray:
    """``values`` as a checked (N, 4) float64 array of x1, y1, x2, y2."""
    b = np.asarray(values, dtype=np.float64)
    if b.size == 0:
        b = b.reshape(0, 4)
    if b.ndim != 2 or b.shape[1] != 4:
        raise InputError(field, f"shape {b.shape}", "an (N, 4) array of x1, y1, x2, y2 in pixels")
    if not np.isfinite(b).all():
        raise InputError(field, f"{np.count_nonzero(~np.isfinite(b).all(axis=1))} boxes not finite", "finite boxes")
    flipped = np.count_nonzero((b[:, 2] < b[:, 0]) | (b[:, 3] < b[:, 1]))
    if flipped:
        raise InputError(field, f"{flipped} boxes with x2 < x1 or y2 < y1", "x1, y1, x2, y2 with x2 ≥ x1, y2 ≥ y1")
    return b


def box_iou(a, b) -> np.ndarray:
    """(len(a), len(b)) intersection over union of two sets of x1, y1, x2, y2 boxes (pixels);
    0 where they do not overlap (and between two empty boxes). Same arithmetic as pycocotools'
    ``bbIou``: union = area a + area b − intersection."""
    return _iou(_boxes(a, "boxes a"), _boxes(b, "boxes b"))


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`box_iou` of checked boxes."""
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.where((w > 0) & (h > 0), w * h, 0.0)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=inter > 0)


def _interpolated(tp: np.ndarray, n_truths: int) -> tuple[np.ndarray, np.ndarray]:
    """(AP, recall) per row of ``tp`` (rows: thresholds; columns: detections by descending
    score, True for a match): COCOeval's 101-point interpolated precision, averaged."""
    tp_sum = np.cumsum(tp, axis=1, dtype=np.float64)
    fp_sum = np.cumsum(~tp, axis=1, dtype=np.float64)
    n = tp.shape[1]
    if n == 0:
        return np.zeros(tp.shape[0]), np.zeros(tp.shape[0])
    recall = tp_sum / n_truths
    precision = np.flip(np.maximum.accumulate(np.flip(tp_sum / (tp_sum + fp_sum), axis=1), axis=1), axis=1)
    ap = np.empty(tp.shape[0])
    for t in range(tp.shape[0]):
        at = np.searchsorted(recall[t], RECALL_POINTS, side="left")
        ap[t] = np.where(at < n, precision[t, np.minimum(at, n - 1)], 0.0).mean()
    return ap, recall[:, -1]


def average_precision(scores, matched, n_truths: int) -> float:
    """COCO AP of one ranking: detections with ``scores`` (any order; ties keep their order)
    that are true positives where ``matched`` is True, against ``n_truths`` (> 0) truths.
    Precision made monotone (the best at any higher recall), read at recall 0, 0.01, …, 1
    (0 past the highest recall reached), averaged."""
    s = np.asarray(scores, dtype=np.float64)
    m = np.asarray(matched, dtype=bool)
    if s.ndim != 1 or m.shape != s.shape or not np.isfinite(s).all():
        raise InputError("scores", f"shapes {s.shape} and {m.shape}", "finite scores, one match flag each")
    if int(n_truths) != n_truths or n_truths < 1 or n_truths < m.sum():
        raise InputError("n_truths", repr(n_truths), f"an integer ≥ 1 and ≥ the {m.sum()} matches")
    order = np.argsort(-s, kind="stable")
    return float(_interpolated(m[order][None, :], int(n_truths))[0][0])


def _match(iou: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """(T, D) True where detection d (rows of ``iou``, by descending score) matches a truth at
    threshold t: greedily, the unmatched truth of highest IoU ≥ t, the later one on a tie."""
    n_det, n_truth = iou.shape
    matched = np.zeros((len(thresholds), n_det), dtype=bool)
    if n_truth == 0:
        return matched
    taken = np.zeros((len(thresholds), n_truth), dtype=bool)
    rows = np.arange(len(thresholds))
    for d in range(n_det):
        candidate = np.where(~taken & (iou[d][None, :] >= thresholds[:, None]), iou[d][None, :], -np.inf)
        best = n_truth - 1 - np.argmax(candidate[:, ::-1], axis=1)  # the last of the highest
        hit = np.isfinite(candidate[rows, best])
        matched[hit, d] = True
        taken[rows[hit], best[hit]] = True
    return matched


def _detections(predictions, truths) -> tuple[list, list]:
    """Checked (boxes, scores, classes) and (boxes, classes) per image."""
    if len(predictions) != len(truths):
        raise InputError(
            "predictions", f"{len(predictions)} images, truths {len(truths)}", "one entry per image in both, same order"
        )
    preds, gts = [], []
    for i, (p, t) in enumerate(zip(predictions, truths)):
        if len(p) != 3:
            raise InputError(f"predictions[{i}]", f"{len(p)} items", "(boxes (N, 4), scores (N,), classes (N,))")
        if len(t) != 2:
            raise InputError(f"truths[{i}]", f"{len(t)} items", "(boxes (M, 4), classes (M,))")
        boxes, scores = _boxes(p[0], f"predictions[{i}] boxes"), np.asarray(p[1], dtype=np.float64)
        classes = _labels(p[2], f"predictions[{i}] classes", 1)
        if scores.size == 0:
            scores = scores.reshape(0)
        if scores.shape != (len(boxes),) or classes.shape != (len(boxes),):
            raise InputError(
                f"predictions[{i}]",
                f"{len(boxes)} boxes, scores {scores.shape}, classes {classes.shape}",
                "one score and one class per box",
            )
        if not np.isfinite(scores).all():
            raise InputError(f"predictions[{i}] scores", "a score not finite", "finite scores")
        t_boxes, t_classes = _boxes(t[0], f"truths[{i}] boxes"), _labels(t[1], f"truths[{i}] classes", 1)
        if t_classes.shape != (len(t_boxes),):
            raise InputError(f"truths[{i}]", f"{len(t_boxes)} boxes, classes {t_classes.shape}", "one class per box")
        preds.append((boxes, scores, classes))
        gts.append((t_boxes, t_classes))
    return preds, gts


def detection_scores(predictions, truths, iou_thresholds=IOU_THRESHOLDS, max_detections: int = MAX_DETECTIONS) -> dict:
    """COCO box scores of ``predictions`` (per image: boxes (N, 4) x1, y1, x2, y2 in pixels,
    scores (N,), classes (N,) integers) against ``truths`` (per image: boxes (M, 4), classes
    (M,)), the same images in the same order.

    Returns {"map50", "map50_95", "recall50", "recall50_95", "per_class": {class: {"ap50",
    "ap50_95", "recall50", "recall50_95", "truths"}}, "truths", "predictions"} (counts as given,
    before the cap of ``max_detections`` per image and class). AP per class
    and threshold as COCOeval (module docstring); map50 and recall50 at IoU 0.5 (None when 0.5
    is not among ``iou_thresholds``), map50_95 and recall50_95 averaged over the thresholds
    (recall50_95 is COCOeval's AR@max_detections); every mean is over the classes that have
    truths (predictions of other classes count nowhere). With no truth at all: all None.
    """
    thresholds = np.asarray(iou_thresholds, dtype=np.float64)
    if thresholds.ndim != 1 or thresholds.size == 0 or not ((thresholds > 0) & (thresholds <= 1)).all():
        raise InputError("iou_thresholds", repr(iou_thresholds), "a non-empty 1-D sequence in (0, 1]")
    if int(max_detections) != max_detections or max_detections < 1:
        raise InputError("max_detections", repr(max_detections), "a positive integer (per image and class)")
    preds, gts = _detections(predictions, truths)
    capped = np.minimum(thresholds, 1 - 1e-10)  # COCOeval's cap: an IoU of 1 still matches at 1
    at50 = np.flatnonzero(np.isclose(thresholds, 0.5, rtol=0, atol=1e-12))
    per_class = {}
    for c in np.unique(np.concatenate([t[1] for t in gts] + [np.zeros(0, np.int64)])):
        scores, matched, n_truths = [], [], 0
        for (boxes, s, classes), (t_boxes, t_classes) in zip(preds, gts):
            keep = np.flatnonzero(classes == c)
            keep = keep[np.argsort(-s[keep], kind="stable")][: int(max_detections)]
            truth = t_boxes[t_classes == c]
            n_truths += len(truth)
            scores.append(s[keep])
            matched.append(_match(_iou(boxes[keep], truth), capped))
        order = np.argsort(-np.concatenate(scores), kind="stable")
        ap, recall = _interpolated(np.concatenate(matched, axis=1)[:, order], n_truths)
        per_class[int(c)] = {
            "ap50": float(ap[at50[0]]) if at50.size else None,
            "ap50_95": float(ap.mean()),
            "recall50": float(recall[at50[0]]) if at50.size else None,
            "recall50_95": float(recall.mean()),
            "truths": n_truths,
        }

    def mean(key: str) -> float | None:
        """The mean of one per-class value over the classes, None without classes or value."""
        values = [row[key] for row in per_class.values()]
        return float(np.mean(values)) if values and values[0] is not None else None

    return {
        "map50": mean("ap50"),
        "map50_95": mean("ap50_95"),
        "recall50": mean("recall50"),
        "recall50_95": mean("recall50_95"),
        "per_class": per_class,
        "truths": sum(len(t[1]) for t in gts),
        "predictions": sum(len(p[1]) for p in preds),
    }


def segmentation_scores(predicted_maps, truth_maps, classes=None, ignore_index: int | None = None) -> dict:
    """Dataset-level IoU of integer class maps: ``predicted_maps`` and ``truth_maps`` are
    sequences of (H, W) maps (one pair per image, each pair the same shape), pooled into one
    confusion matrix over every pixel whose truth is not ``ignore_index``.

    ``classes``: the classes scored (default: every value in the scored truths and predictions,
    so none is absent); a scored map value outside them is an error. IoU_c = TP / (TP + FP + FN).
    A class with no pixel in the truths and none predicted is left out of the mean and listed in
    "absent"; one predicted but not in the truths has IoU 0 and counts. Foreground is class ≠ 0
    against class 0, binary (polyp segmentation's Kvasir-SEG scores): Dice 2TP / (2TP + FP + FN)
    and IoU pooled over the set, not averaged per image. Returns {"miou", "per_class_iou": {class: iou} (present
    classes), "absent": [class, ...], "dice_foreground", "iou_foreground", "pixels" (scored)};
    a mean with nothing to average (no class present, no foreground anywhere) is None.
    """
    if len(predicted_maps) != len(truth_maps) or len(truth_maps) == 0:
        raise InputError(
            "predicted_maps", f"{len(predicted_maps)} maps, truth_maps {len(truth_maps)}", "one map per image in both"
        )
    if ignore_index is not None and int(ignore_index) != ignore_index:
        raise InputError("ignore_index", repr(ignore_index), "an integer class value or None")
    pairs = []
    for i, (p, t) in enumerate(zip(predicted_maps, truth_maps)):
        p, t = _labels(p, f"predicted_maps[{i}]", 2), _labels(t, f"truth_maps[{i}]", 2)
        if p.shape != t.shape:
            raise InputError(f"predicted_maps[{i}]", f"shape {p.shape}, truth {t.shape}", "the truth map's shape")
        scored = t != ignore_index if ignore_index is not None else np.ones(t.shape, dtype=bool)
        pairs.append((p[scored], t[scored]))
    if classes is None:
        labels = np.unique(np.concatenate([np.concatenate(pair) for pair in pairs]))
        if ignore_index is not None and ignore_index in labels:
            raise InputError("predicted_maps", f"ignore_index {ignore_index} predicted", "predicted classes only")
    else:
        labels = np.unique(_labels(classes, "classes", 1))
        if labels.size == 0 or (ignore_index is not None and ignore_index in labels):
            raise InputError("classes", repr(classes), "a non-empty sequence of integer classes, not ignore_index")
    k = labels.size
    confusion = np.zeros(k * k, dtype=np.int64)  # rows: truth, columns: prediction
    for i, (p, t) in enumerate(pairs):
        for values, name in ((p, "predicted_maps"), (t, "truth_maps")):
            outside = ~np.isin(values, labels)
            if outside.any():
                raise InputError(
                    f"{name}[{i}]", f"class {values[outside][0]} not among classes", f"values in {labels.tolist()}"
                )
        confusion += np.bincount(np.searchsorted(labels, t) * k + np.searchsorted(labels, p), minlength=k * k)
    return segmentation_from_confusion(confusion.reshape(k, k), labels)


def segmentation_from_confusion(confusion, classes=None) -> dict:
    """:func:`segmentation_scores` of a pooled confusion matrix (K, K), rows the truth's class and
    columns the prediction's, of ``classes`` (K,) (default 0..K−1)."""
    confusion = np.asarray(confusion, dtype=np.int64)
    if confusion.ndim != 2 or confusion.shape[0] != confusion.shape[1] or (confusion < 0).any():
        raise InputError("confusion", f"shape {confusion.shape}", "a square matrix of counts ≥ 0")
    labels = np.arange(len(confusion)) if classes is None else np.asarray(classes)
    tp = np.diag(confusion)
    union = confusion.sum(axis=0) + confusion.sum(axis=1) - tp
    present = union > 0
    iou = {int(c): float(tp[j] / union[j]) for j, c in enumerate(labels) if present[j]}
    foreground = labels != 0
    fg_tp = int(confusion[np.ix_(foreground, foreground)].sum())
    fg_wrong = int(confusion[np.ix_(~foreground, foreground)].sum() + confusion[np.ix_(foreground, ~foreground)].sum())
    return {
        "miou": float(np.mean(list(iou.values()))) if iou else None,
        "per_class_iou": iou,
        "absent": [int(c) for c in labels[~present]],
        "dice_foreground": 2 * fg_tp / (2 * fg_tp + fg_wrong) if fg_tp + fg_wrong else None,
        "iou_foreground": fg_tp / (fg_tp + fg_wrong) if fg_tp + fg_wrong else None,
        "pixels": int(confusion.sum()),
    }
