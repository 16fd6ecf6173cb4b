"""Detection and segmentation scores: hand-computed cases, pycocotools' COCOeval on a seeded
problem (data/coco_reference.json, written by data/make_coco_reference.py in a throwaway venv),
and a per-class loop for the pooled IoU."""

import json
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.analysis.detection_metrics import average_precision, box_iou, detection_scores, segmentation_scores
from metalens_cli.errors import InputError

SQUARE = [0.0, 0.0, 10.0, 10.0]


def _one(truth_boxes, boxes, scores, truth_classes=None, classes=None):
    """One image's (predictions, truths) lists."""
    truth_classes = [0] * len(truth_boxes) if truth_classes is None else truth_classes
    classes = [0] * len(boxes) if classes is None else classes
    return [(np.array(boxes), np.array(scores), np.array(classes))], [(np.array(truth_boxes), np.array(truth_classes))]


def test_box_iou_by_hand():
    a = [SQUARE, [0, 0, 0, 0]]
    b = [[5, 0, 15, 10], [10, 0, 20, 10], [2, 2, 4, 4]]
    # half overlap: 50 / (100 + 100 − 50); edges touching: 0; inside: 4 / 100; an empty box: 0
    np.testing.assert_allclose(box_iou(a, b), [[1 / 3, 0, 0.04], [0, 0, 0]], rtol=1e-15, atol=0)
    assert box_iou(np.zeros((0, 4)), b).shape == (0, 3)
    assert box_iou([[1.5, 2.5, 7.25, 9.0]], [[1.5, 2.5, 7.25, 9.0]])[0, 0] == 1.0


def test_perfect_detector_scores_one():
    rng = np.random.default_rng(3)
    predictions, truths = [], []
    for _ in range(3):
        corner = rng.uniform(0, 100, (5, 2))
        boxes = np.concatenate([corner, corner + rng.uniform(5, 50, (5, 2))], axis=1)
        classes = rng.integers(0, 2, 5)
        predictions.append((boxes, rng.random(5), classes))
        truths.append((boxes, classes))
    result = detection_scores(predictions, truths)
    assert result["map50"] == result["map50_95"] == result["recall50"] == result["recall50_95"] == 1.0
    assert result["truths"] == result["predictions"] == 15
    assert set(result["per_class"]) == {0, 1}


def test_one_detection_at_iou_between_thresholds():
    """IoU 0.58 matches at 0.5 and 0.55 only: AP 1, 1, then 0 at 0.6 … 0.95, so mAP50-95 = 2/10."""
    predictions, truths = _one([SQUARE], [[0, 0, 10, 5.8]], [0.9])
    result = detection_scores(predictions, truths)
    assert result["map50"] == 1.0 and result["recall50"] == 1.0
    assert result["map50_95"] == pytest.approx(0.2, abs=1e-15)
    assert result["recall50_95"] == pytest.approx(0.2, abs=1e-15)
    assert result["per_class"][0]["ap50"] == 1.0


def test_iou_of_exactly_a_threshold_matches_at_it():
    """IoU 60/100 = 0.6 exactly matches at 0.5, 0.55 and 0.6 (IoU ≥ threshold): 3/10. With
    np.arange(0.5, 0.96, 0.05) the third threshold is 0.6000000000000001 and it would be 2/10,
    which is why the default is COCOeval's linspace."""
    predictions, truths = _one([SQUARE], [[0, 0, 10, 6]], [0.9])
    assert detection_scores(predictions, truths)["map50_95"] == pytest.approx(0.3, abs=1e-15)
    arange = detection_scores(predictions, truths, iou_thresholds=np.arange(0.5, 0.96, 0.05))
    assert arange["map50_95"] == pytest.approx(0.2, abs=1e-15)


def test_a_second_detection_of_one_truth_is_a_false_positive():
    """A (IoU 0.72, score 0.9) takes the truth first wherever it can: at 0.5 … 0.7 the ranking is
    TP, FP (AP 1); at 0.75 … 0.95 A misses and B (the exact box, score 0.8) matches: FP, TP,
    precision 0, 1/2 made monotone 1/2, 1/2 at recall 1 (AP 1/2). mAP50-95 = (5 + 2.5) / 10."""
    predictions, truths = _one([SQUARE], [[0, 0, 10, 7.2], SQUARE], [0.9, 0.8])
    result = detection_scores(predictions, truths)
    assert result["map50"] == 1.0
    assert result["map50_95"] == pytest.approx(0.75, abs=1e-15)
    # the same boxes with the exact one ranked first: TP then FP at every threshold, AP 1
    predictions, truths = _one([SQUARE], [[0, 0, 10, 7.2], SQUARE], [0.8, 0.9])
    assert detection_scores(predictions, truths)["map50_95"] == 1.0


def test_greedy_match_goes_to_the_highest_iou():
    """Truths A = [0, 0, 10, 10] and B = [4, 0, 14, 10]; the first detection [2, 0, 12, 10] has
    IoU 80/120 with A and 80/120 with B too (a tie: COCOeval keeps the later, B), the second
    [0, 0, 10, 10] then finds A free: both match, AP 1 at 0.5 and 0.55 (IoU 2/3 < 0.7)."""
    predictions, truths = _one([SQUARE, [4, 0, 14, 10]], [[2, 0, 12, 10], SQUARE], [0.9, 0.8])
    result = detection_scores(predictions, truths, iou_thresholds=[0.5, 0.55])
    assert result["map50_95"] == 1.0 and result["recall50"] == 1.0
    # detection [3, 0, 13, 10]: IoU 70/130 with A, 90/110 with B, so B; [0, 0, 10, 10] takes A
    predictions, truths = _one([SQUARE, [4, 0, 14, 10]], [[3, 0, 13, 10], SQUARE], [0.9, 0.8])
    assert detection_scores(predictions, truths, iou_thresholds=[0.5])["map50"] == 1.0


def test_equal_scores_rank_in_image_order():
    """COCOeval sorts with a stable sort over the images in order: a false positive in the first
    image and a true positive in the second, both 0.5, rank FP, TP (precision 0, 1/2: AP 1/2);
    the images swapped, TP, FP (AP 1)."""
    fp = ([[50, 50, 60, 60]], [0.5], [0])
    tp = ([SQUARE], [0.5], [0])
    truths = [(np.zeros((0, 4)), []), ([SQUARE], [0])]
    assert detection_scores([fp, tp], truths)["map50"] == 0.5
    assert detection_scores([tp, fp], truths[::-1])["map50"] == 1.0


def test_101_point_interpolation_of_a_hand_built_ranking():
    """Ranking TP FP TP FP FP TP against 7 truths: recall 1/7, 1/7, 2/7, 2/7, 2/7, 3/7; precision
    1, 1/2, 2/3, 1/2, 2/5, 1/2, made monotone 1, 2/3, 2/3, 1/2, 1/2, 1/2. Recall points 0 … 0.14
    (15 of them) read 1, 0.15 … 0.28 (14) read 2/3, 0.29 … 0.42 (14) read 1/2, the 58 above 3/7
    read 0: AP = (15 + 14·2/3 + 14/2) / 101 = 94/303."""
    matched = np.array([True, False, True, False, False, True])
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.4])
    assert average_precision(scores, matched, 7) == pytest.approx(94 / 303, abs=1e-15)
    shuffle = np.random.default_rng(0).permutation(6)
    assert average_precision(scores[shuffle], matched[shuffle], 7) == pytest.approx(94 / 303, abs=1e-15)
    assert average_precision([0.5], [True], 2) == pytest.approx(51 / 101, abs=1e-15)  # recall 0, …, 0.5
    assert average_precision([], [], 3) == 0.0


def test_classes_and_the_detection_cap():
    # class 1's truth is missed (AP 0, counted); class 9 has no truth (left out)
    predictions, truths = _one([SQUARE, [20, 20, 30, 30]], [SQUARE, [50, 50, 60, 60]], [0.9, 0.95], [0, 1], [0, 9])
    result = detection_scores(predictions, truths)
    assert result["map50_95"] == 0.5 and set(result["per_class"]) == {0, 1}
    assert result["per_class"][1] == {"ap50": 0.0, "ap50_95": 0.0, "recall50": 0.0, "recall50_95": 0.0, "truths": 1}
    # the cap is per image and class, as COCOeval's maxDets: one detection of each class stays
    predictions, truths = _one([SQUARE, [20, 20, 30, 30]], [SQUARE, [20, 20, 30, 30]], [0.9, 0.8], [0, 1], [0, 1])
    assert detection_scores(predictions, truths, max_detections=1)["map50_95"] == 1.0
    # two truths of one class, the lower-scored detection dropped: recall 1/2, AP 51/101
    predictions, truths = _one([SQUARE, [20, 20, 30, 30]], [SQUARE, [20, 20, 30, 30]], [0.9, 0.8])
    capped = detection_scores(predictions, truths, max_detections=1)
    assert capped["recall50"] == 0.5 and capped["map50"] == pytest.approx(51 / 101, abs=1e-15)


def test_no_truths_and_no_predictions():
    predictions, truths = _one(np.zeros((0, 4)), [SQUARE], [0.5])
    result = detection_scores(predictions, truths)
    assert result["map50"] is None and result["map50_95"] is None and result["recall50_95"] is None
    assert result["per_class"] == {} and result["truths"] == 0 and result["predictions"] == 1
    predictions, truths = _one([SQUARE], [], [])
    assert detection_scores(predictions, truths)["map50"] == 0.0
    assert detection_scores(*_one([SQUARE], [SQUARE], [0.5]), iou_thresholds=[0.7])["map50"] is None


def _fixture() -> dict:
    return json.loads((Path(__file__).parent / "data" / "coco_reference.json").read_text(encoding="utf-8"))


@pytest.mark.parametrize("max_detections", [1, 3, 100])
def test_matches_cocoeval(max_detections):
    """pycocotools 2.0.11's COCOeval (bbox, area "all") on 6 images, 37 truths of 3 classes and 76
    detections (ties in score, duplicates, wrong classes, a class without truths, an image without
    truths), at maxDets 1, 3 and 100 per image and class: every mean and per-class value."""
    reference = _fixture()
    images = reference["images"]
    predictions = [(image["boxes"], image["scores"], image["classes"]) for image in images]
    truths = [(image["truth_boxes"], image["truth_classes"]) for image in images]
    result = detection_scores(predictions, truths, max_detections=max_detections)
    expected = reference["expected"][str(max_detections)]
    for key in ("map50", "map50_95", "recall50", "recall50_95"):
        assert result[key] == pytest.approx(expected[key], abs=1e-9), key
    assert sorted(result["per_class"]) == sorted(int(c) for c in expected["per_class"])
    for c, row in expected["per_class"].items():
        for key, value in row.items():
            assert result["per_class"][int(c)][key] == pytest.approx(value, abs=1e-9), (c, key)
    stats = reference["expected"]["stats"]  # summarize(): AP, AP50 at maxDets 100; AR at 1, 3, 100
    ar = {1: stats[6], 3: stats[7], 100: stats[8]}[max_detections]
    assert result["recall50_95"] == pytest.approx(ar, abs=1e-9)
    if max_detections == 100:
        assert result["map50_95"] == pytest.approx(stats[0], abs=1e-9)
        assert result["map50"] == pytest.approx(stats[1], abs=1e-9)
        assert (result["truths"], result["predictions"]) == (37, 76)


def test_bad_detection_input_is_refused():
    good_p, good_t = _one([SQUARE], [SQUARE], [0.5])
    with pytest.raises(InputError, match="predictions"):
        detection_scores(good_p * 2, good_t)
    with pytest.raises(InputError, match=r"predictions\[0\] boxes"):
        detection_scores(*_one([SQUARE], [[0, 0, np.nan, 1]], [0.5]))
    with pytest.raises(InputError, match=r"truths\[0\] boxes: 1 boxes with x2 < x1"):
        detection_scores(*_one([[5, 0, 1, 1]], [SQUARE], [0.5]))
    with pytest.raises(InputError, match=r"predictions\[0\] boxes: shape"):
        detection_scores(*_one([SQUARE], [[0, 0, 1]], [0.5]))
    with pytest.raises(InputError, match=r"predictions\[0\]: 1 boxes, scores \(2,\)"):
        detection_scores(*_one([SQUARE], [SQUARE], [0.5, 0.4]))
    with pytest.raises(InputError, match=r"predictions\[0\] scores"):
        detection_scores(*_one([SQUARE], [SQUARE], [np.inf]))
    with pytest.raises(InputError, match=r"truths\[0\] classes"):
        detection_scores(*_one([SQUARE], [SQUARE], [0.5], [0.5]))
    with pytest.raises(InputError, match="iou_thresholds"):
        detection_scores(good_p, good_t, iou_thresholds=[0.0, 0.5])
    with pytest.raises(InputError, match="max_detections"):
        detection_scores(good_p, good_t, max_detections=0)
    with pytest.raises(InputError, match="boxes a"):
        box_iou([[0, 0, 1]], [SQUARE])
    with pytest.raises(InputError, match="n_truths"):
        average_precision([0.5, 0.4], [True, True], 1)


def test_segmentation_by_hand():
    """Truth 0 0 / 1 1, prediction 0 1 / 1 1: class 0 TP 1, FN 1 (IoU 1/2); class 1 TP 2, FP 1
    (IoU 2/3); mIoU 7/12. Foreground (≠ 0): TP 2, FP 1, FN 0: Dice 4/5, IoU 2/3."""
    result = segmentation_scores([np.array([[0, 1], [1, 1]])], [np.array([[0, 0], [1, 1]])])
    assert result["per_class_iou"] == {0: 0.5, 1: pytest.approx(2 / 3, abs=1e-15)}
    assert result["miou"] == pytest.approx(7 / 12, abs=1e-15)
    assert result["dice_foreground"] == pytest.approx(0.8, abs=1e-15)
    assert result["iou_foreground"] == pytest.approx(2 / 3, abs=1e-15)
    assert result["absent"] == [] and result["pixels"] == 4
    # boolean polyp masks: the same foreground numbers
    binary = segmentation_scores([np.array([[0, 1], [1, 1]], bool)], [np.array([[0, 0], [1, 1]], bool)])
    assert binary["dice_foreground"] == pytest.approx(0.8, abs=1e-15)


def test_segmentation_absent_classes():
    """Classes 0–3; prediction 0 2 / 1 1 against 0 0 / 1 1: class 0 IoU 1/2, class 1 IoU 1, class
    2 predicted but not in the truth IoU 0 (counted), class 3 nowhere (absent): mIoU 1.5/3."""
    result = segmentation_scores([[[0, 2], [1, 1]]], [[[0, 0], [1, 1]]], classes=range(4))
    assert result["per_class_iou"] == {0: 0.5, 1: 1.0, 2: 0.0}
    assert result["absent"] == [3] and result["miou"] == 0.5
    assert result["dice_foreground"] == pytest.approx(0.8, abs=1e-15)  # TP 2, FP 1 (the 2), FN 0


def test_segmentation_pools_the_images():
    """Image A all 1 and predicted 1; image B all 1 and predicted 0. Pooled: class 1 TP 4, FN 4
    (IoU 1/2), class 0 FP 4 (IoU 0): mIoU 1/4, where a mean of per-image mIoUs would be 1/2."""
    ones, zeros = np.ones((2, 2), int), np.zeros((2, 2), int)
    result = segmentation_scores([ones, zeros], [ones, ones])
    assert result["per_class_iou"] == {0: 0.0, 1: 0.5} and result["miou"] == 0.25
    assert result["dice_foreground"] == pytest.approx(8 / 12, abs=1e-15)  # 2·4 / (2·4 + 0 + 4)


def test_segmentation_ignore_index():
    """255 in the truth is not scored, whatever is predicted there (even a value that is no class)."""
    truth = np.array([[0, 255, 1], [255, 1, 1]])
    prediction = np.array([[0, 7, 1], [0, 1, 0]])
    result = segmentation_scores([prediction], [truth], classes=[0, 1], ignore_index=255)
    # scored: (0, 0), (1, 1), (1, 1), (1, 0): class 0 TP 1, FP 1 → 1/2; class 1 TP 2, FN 1 → 2/3
    assert result["pixels"] == 4
    assert result["per_class_iou"] == {0: 0.5, 1: pytest.approx(2 / 3, abs=1e-15)}
    with pytest.raises(InputError, match="classes"):
        segmentation_scores([prediction], [truth], classes=[0, 1, 255], ignore_index=255)
    with pytest.raises(InputError, match=r"predicted_maps\[0\]: class 7"):
        segmentation_scores([prediction], [np.where(truth == 255, 0, truth)], classes=[0, 1], ignore_index=255)


def test_segmentation_matches_a_per_class_loop():
    """Random maps of several sizes, class 4 only ever predicted, class 5 nowhere, 255 ignored:
    IoU per class by counting pixels class by class and image by image."""
    rng = np.random.default_rng(7)
    shapes = [(13, 17), (8, 8), (21, 5), (1, 30)]
    truths = [rng.choice([0, 1, 2, 3, 255], size=s, p=[0.4, 0.2, 0.2, 0.1, 0.1]) for s in shapes]
    predictions = [
        np.where(rng.random(t.shape) < 0.6, np.where(t == 255, 0, t), rng.integers(0, 5, t.shape)) for t in truths
    ]
    result = segmentation_scores(predictions, truths, classes=range(6), ignore_index=255)
    expected = {}
    for c in range(6):
        tp = fp = fn = 0
        for p, t in zip(predictions, truths):
            scored = t != 255
            tp += int(np.sum((p == c) & (t == c) & scored))
            fp += int(np.sum((p == c) & (t != c) & scored))
            fn += int(np.sum((p != c) & (t == c) & scored))
        if tp + fp + fn:
            expected[c] = tp / (tp + fp + fn)
    assert result["absent"] == [5] and sorted(result["per_class_iou"]) == [0, 1, 2, 3, 4]
    for c, iou in expected.items():
        assert result["per_class_iou"][c] == pytest.approx(iou, abs=1e-15)
    assert result["miou"] == pytest.approx(np.mean(list(expected.values())), abs=1e-15)
    fg_tp = sum(int(np.sum((p != 0) & (t != 0) & (t != 255))) for p, t in zip(predictions, truths))
    fg_fp = sum(int(np.sum((p != 0) & (t == 0))) for p, t in zip(predictions, truths))
    fg_fn = sum(int(np.sum((p == 0) & (t != 0) & (t != 255))) for p, t in zip(predictions, truths))
    assert result["dice_foreground"] == pytest.approx(2 * fg_tp / (2 * fg_tp + fg_fp + fg_fn), abs=1e-15)
    assert result["iou_foreground"] == pytest.approx(fg_tp / (fg_tp + fg_fp + fg_fn), abs=1e-15)
    assert result["pixels"] == sum(int(np.sum(t != 255)) for t in truths)


def test_bad_segmentation_input_is_refused():
    two = np.zeros((2, 2), int)
    with pytest.raises(InputError, match="predicted_maps"):
        segmentation_scores([two, two], [two])
    with pytest.raises(InputError, match=r"predicted_maps\[0\]: shape"):
        segmentation_scores([np.zeros((2, 3), int)], [two])
    with pytest.raises(InputError, match=r"truth_maps\[0\]: values of type"):
        segmentation_scores([two], [np.full((2, 2), 0.5)])
    with pytest.raises(InputError, match=r"truth_maps\[0\]: shape"):
        segmentation_scores([two], [np.zeros(4, int)])
    with pytest.raises(InputError, match=r"truth_maps\[0\]: class 3"):
        segmentation_scores([two], [two + 3], classes=[0, 1])
    with pytest.raises(InputError, match="predicted_maps: ignore_index"):
        segmentation_scores([two + 9], [two], ignore_index=9)
