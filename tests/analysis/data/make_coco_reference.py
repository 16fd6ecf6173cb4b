"""Write coco_reference.json: pycocotools' COCOeval (iouType "bbox") of a small seeded detection
problem, the reference that tests/analysis/test_detection_metrics.py checks
metalens_cli.analysis.detection_metrics against without needing pycocotools (not a project
dependency, and not part of the test suite).

The problem (numpy seed ``SEED``): 6 images of 640 × 480 pixels, truths of classes 1–3 (the last
image has none), boxes x1, y1, x2, y2 on a 1/8-pixel grid so that pycocotools' x + w gives back x2
exactly. Detections: per truth, with probability 0.85 a copy jittered by ~10 % of its size (IoU
spread over about 0.4–1), sometimes of the wrong class, sometimes a second, looser duplicate;
plus 3–7 false positives per image, some of class 4 that no truth has. Scores rounded to two
decimals, so that some tie (COCOeval breaks ties by a stable sort). Evaluated with area range
"all" and ``maxDets = [1, 3, 100]`` (per image and class); stored per maxDets: the mean and
per-class AP at IoU 0.5 and over 0.5:0.95 (``eval["precision"]`` averaged over the 101 recall
points), recall at 0.5 and over the thresholds (AR), and ``stats`` as ``summarize()`` prints it.

Rerun in a throwaway venv (pycocotools goes nowhere near the project's environment)::

    python3 -m venv /tmp/cocoref && /tmp/cocoref/bin/pip install numpy pycocotools
    /tmp/cocoref/bin/python tests/analysis/data/make_coco_reference.py
"""

import contextlib
import datetime
import importlib.metadata
import io
import json
from pathlib import Path

import numpy as np
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

JSON_OUT = Path(__file__).resolve().parent / "coco_reference.json"
SEED = 20261201
N_IMAGES, WIDTH, HEIGHT = 6, 640, 480
MAX_DETS = [1, 3, 100]


def grid(x) -> np.ndarray:
    """Rounded to 1/8 pixel (exact in binary)."""
    return np.round(np.asarray(x) * 8) / 8


def problem(rng: np.random.Generator) -> list[dict]:
    """Per image: truth boxes and classes, predicted boxes, scores and classes."""
    images = []
    for i in range(N_IMAGES):
        n = 0 if i == N_IMAGES - 1 else int(rng.integers(6, 13))
        size = rng.uniform(12, 180, (n, 2))
        corner = rng.uniform(0, 1, (n, 2)) * ([WIDTH, HEIGHT] - size)
        truth = grid(np.concatenate([corner, corner + size], axis=1))
        truth_classes = rng.integers(1, 4, n)
        boxes, scores, classes = [], [], []
        for box, c in zip(truth, truth_classes):
            w, h = box[2] - box[0], box[3] - box[1]
            for copy, jitter in ((0, 0.08), (1, 0.25)):
                if rng.random() > (0.85 if copy == 0 else 0.35):
                    continue
                moved = box + rng.normal(0, jitter, 4) * [w, h, w, h]
                moved[2:] = np.maximum(moved[2:], moved[:2] + 1)
                boxes.append(grid(moved))
                classes.append(int(c) if rng.random() > 0.1 else int(rng.integers(1, 4)))
                scores.append(float(np.clip(rng.normal(0.7 - 0.3 * copy, 0.2), 0.01, 0.99)))
        for _ in range(int(rng.integers(3, 8))):
            size = rng.uniform(12, 120, 2)
            corner = rng.uniform(0, 1, 2) * ([WIDTH, HEIGHT] - size)
            boxes.append(grid(np.concatenate([corner, corner + size])))
            classes.append(int(rng.integers(1, 5)))
            scores.append(float(np.clip(rng.normal(0.4, 0.2), 0.01, 0.99)))
        order = rng.permutation(len(boxes))  # not sorted by score
        images.append(
            {
                "truth_boxes": truth.tolist(),
                "truth_classes": truth_classes.tolist(),
                "boxes": [boxes[j].tolist() for j in order],
                "scores": [round(scores[j], 2) for j in order],
                "classes": [classes[j] for j in order],
            }
        )
    return images


def xywh(box) -> list[float]:
    """x1, y1, x2, y2 → COCO's x, y, w, h."""
    return [box[0], box[1], box[2] - box[0], box[3] - box[1]]


def evaluate(images: list[dict]) -> dict:
    """COCOeval's scores, per maxDets."""
    gt = {"images": [], "annotations": [], "categories": [{"id": c, "name": str(c)} for c in (1, 2, 3, 4)]}
    results = []
    for i, image in enumerate(images, start=1):
        gt["images"].append({"id": i, "width": WIDTH, "height": HEIGHT})
        for box, c in zip(image["truth_boxes"], image["truth_classes"]):
            b = xywh(box)
            gt["annotations"].append(
                {"id": len(gt["annotations"]) + 1, "image_id": i, "category_id": c, "bbox": b, "area": b[2] * b[3]}
            )
            gt["annotations"][-1]["iscrowd"] = 0
        for box, score, c in zip(image["boxes"], image["scores"], image["classes"]):
            results.append({"image_id": i, "category_id": c, "bbox": xywh(box), "score": score})
    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO()
        coco.dataset = gt
        coco.createIndex()
        evaluation = COCOeval(coco, coco.loadRes(results), iouType="bbox")
        evaluation.params.maxDets = MAX_DETS
        evaluation.evaluate()
        evaluation.accumulate()
        evaluation.summarize()
    thresholds = evaluation.params.iouThrs
    assert np.array_equal(thresholds, np.linspace(0.5, 0.95, 10)) and evaluation.params.areaRngLbl[0] == "all"
    out = {}
    for m, max_dets in enumerate(MAX_DETS):
        precision = evaluation.eval["precision"][:, :, :, 0, m]  # (T, R, K): area "all"
        recall = evaluation.eval["recall"][:, :, 0, m]  # (T, K)
        per_class = {}
        for k, c in enumerate(evaluation.params.catIds):
            if (precision[:, :, k] == -1).all():
                continue  # no truth: COCOeval leaves the class out
            per_class[str(c)] = {
                "ap50": float(precision[0, :, k].mean()),
                "ap50_95": float(precision[:, :, k].mean()),
                "recall50": float(recall[0, k]),
                "recall50_95": float(recall[:, k].mean()),
            }
        kept = precision > -1
        out[str(max_dets)] = {
            "map50_95": float(precision[kept].mean()),
            "map50": float(precision[0][kept[0]].mean()),
            "recall50": float(recall[0][recall[0] > -1].mean()),
            "recall50_95": float(recall[recall > -1].mean()),
            "per_class": per_class,
        }
    out["stats"] = [float(v) for v in evaluation.stats]
    return out


def main():
    images = problem(np.random.default_rng(SEED))
    reference = {
        "about": (
            "pycocotools COCOeval(iouType='bbox') of the seeded problem of make_coco_reference.py: boxes "
            "x1, y1, x2, y2 in pixels (given to pycocotools as x, y, w, h), area range 'all', maxDets "
            f"{MAX_DETS} per image and class; per maxDets the mean and per-class AP at IoU 0.5 and over "
            "0.5:0.95 and recall (AR) at 0.5 and over 0.5:0.95, classes without truths left out; 'stats' "
            "as summarize() gives them (0: AP, 1: AP50, 6-8: AR at each maxDets)."
        ),
        "date": datetime.date.today().isoformat(),
        "versions": {name: importlib.metadata.version(name) for name in ("pycocotools", "numpy")},
        "seed": SEED,
        "expected": evaluate(images),
        "images": images,
    }
    head = json.dumps({k: v for k, v in reference.items() if k != "images"}, indent=1)[:-2]
    body = ",\n  ".join(json.dumps(image) for image in images)
    JSON_OUT.write_text(f'{head},\n "images": [\n  {body}\n ]\n}}\n')
    truths = sum(len(image["truth_classes"]) for image in images)
    predictions = sum(len(image["classes"]) for image in images)
    print(f"wrote {JSON_OUT}: {truths} truths, {predictions} predictions; stats {reference['expected']['stats']}")


if __name__ == "__main__":
    main()
