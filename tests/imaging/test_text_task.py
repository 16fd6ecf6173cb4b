"""The text task: lines in matplotlib's DejaVu Sans read by RapidOCR (skipped where RapidOCR is not
installed; CI installs it as README says); the edit distance by hand; a missing RapidOCR refused."""

import sys

import numpy as np
import pytest

from metalens_cli.analysis.size50 import size50
from metalens_cli.errors import InputError
from metalens_cli.imaging import task_detection
from metalens_cli.imaging.images import load_images
from metalens_cli.imaging.targets import draw_targets, layout, render
from metalens_cli.imaging.task_detection import edit_distance, score_tasks

SENSOR = (512, 512)


def test_edit_distance_by_hand():
    assert edit_distance("QX7K", "QX7K") == 0
    assert edit_distance("QX7K", "QXK") == 1  # one deletion
    assert edit_distance("QX7K", "QY7KM") == 2  # a substitution and an insertion
    assert edit_distance("", "ABC") == 3 and edit_distance("KITTEN", "SITTING") == 3


def test_text_lines_are_drawn_in_their_footprints():
    for t in layout(("text",), SENSOR, 0, 0):
        x0, y0, w, h = t.footprint
        ink = render(t)
        assert ink.shape == (h, w) and ink.min() < 0.3 and ink.max() == pytest.approx(0.8)
        height = t.corners[3, 1] - t.corners[0, 1]
        assert 0.6 * t.size_px < height < 1.0 * t.size_px  # capitals and digits: the cap height, 0.73 em


def test_missing_rapidocr_is_refused_naming_the_task(monkeypatch):
    monkeypatch.setitem(sys.modules, "rapidocr", None)
    task_detection._ocr.cache_clear()
    with pytest.raises(InputError) as error:
        task_detection.check_dependencies(("markers", "text"))
    assert error.value.field == "--task" and "--no-deps rapidocr" in str(error.value)
    task_detection._ocr.cache_clear()


@pytest.fixture(scope="module")
def photos():
    pytest.importorskip("rapidocr")
    return load_images("photos", SENSOR, 3)


def test_sharp_lines_are_read_and_blur_raises_size50(photos):
    """Sharp: every line of 17 px and more is read exactly (the smaller ones mostly); Gaussian blurs
    of σ = 1, 2, 3 px: size50 never falls and ends above the sharp one."""
    import cv2

    fits = []
    for sigma in (0, 1, 2, 3):
        sizes, found, units = [], [], []
        for index, image in enumerate(photos):
            targets = layout(("text",), SENSOR, 0, index)
            scene = draw_targets(image, targets).sensor
            if sigma:
                scene = np.stack([cv2.GaussianBlur(c, (0, 0), sigma) for c in scene])
            outcome = score_tasks(scene, targets, ("text",))["text"]
            if sigma == 0:
                assert all(f for f, t in zip(outcome.found, targets) if t.size_px > 17), outcome
                assert outcome.found.mean() >= 4 / 6
                assert np.nanmax(outcome.corner_error_px) < 0.5 * max(t.size_px for t in targets)
            assert (outcome.cer[outcome.found] == 0).all() and (outcome.detected >= outcome.found).all()
            sizes += [t.size_px for t in targets]
            found += outcome.found.tolist()
            units += [index] * len(targets)
        fits.append(size50(sizes, found, units))
    values = [f["size50"] for f in fits]
    assert all(b >= a for a, b in zip(values, values[1:])), values
    assert values[-1] > 1.5 * values[0], values


def test_grey_wall_reads_no_text(photos):
    wall = np.full((3, *SENSOR), 0.18, dtype=np.float32)
    outcome = score_tasks(wall, layout(("text",), SENSOR, 0, 0), ("text",))["text"]
    assert not outcome.detected.any() and outcome.wrong == 0 and (outcome.cer == 1).all()
