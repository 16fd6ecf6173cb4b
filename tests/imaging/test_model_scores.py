"""A user's model's scores over units: the paper's mIoU rule by hand, intervals that hold the
point estimate, and paired differences of identical cells at 0."""

import numpy as np
import pytest

from metalens_cli.imaging.model_scores import confusion_counts, model_difference, model_row, paper_exclusions


def _unit(truth, predicted):
    return confusion_counts(np.asarray(predicted), np.asarray(truth))


def test_paper_rule_by_hand():
    """Classes 0, 1, 2 over two cells. Cell A gets every pixel right. Cell B misses class 2: its
    pixel is called 1, so IoU_2 = 0 there. The paper's rule drops class 2 from both cells; the
    benchmarks' mIoU keeps it where it is defined."""
    truth = [0, 0, 1, 1, 2]
    a = [_unit(truth, [0, 0, 1, 1, 2])]
    b = [_unit(truth, [0, 0, 1, 1, 1])]
    assert paper_exclusions([a, b], 3) == frozenset({2})
    row_a = model_row("segment", a, [], {}, 3, frozenset({2}))
    row_b = model_row("segment", b, [], {}, 3, frozenset({2}))
    assert row_a["miou"] == pytest.approx(1.0) and row_a["miou_paper"] == pytest.approx(1.0)
    # B: IoU_0 = 1, IoU_1 = 2/3 (TP 2, FP 1), IoU_2 = 0: mIoU 5/9; the paper's rule: (1 + 2/3) / 2
    assert row_b["miou"] == pytest.approx(5 / 9) and row_b["miou_paper"] == pytest.approx(5 / 6)
    assert row_b["excluded_classes"] == [2]
    # foreground (class ≠ 0): TP 3 of 3 truth pixels, all called foreground: IoU and Dice 1
    assert row_b["iou_foreground"] == pytest.approx(1.0) and row_b["dice_foreground"] == pytest.approx(1.0)


def test_intervals_hold_the_estimate_and_identical_cells_differ_by_zero():
    rng = np.random.default_rng(0)
    units = [_unit(rng.integers(0, 3, 64), rng.integers(0, 3, 64)) for _ in range(12)]
    row = model_row("segment", units, [], {}, 3)
    assert row["miou_ci"][0] <= row["miou"] <= row["miou_ci"][1] and row["miou_ci"][0] < row["miou_ci"][1]
    same = model_difference("segment", units, units, [], "miou")
    assert same["difference"] == 0.0 and same["ci"] == [0.0, 0.0]
